//! `apfn run`: runs a scene headless under a schedule, records every robot's trajectory and
//! reports the simulation speed and, when the schedule measures it, the localization error.

use crate::act::Collided;
use crate::agent::Action;
use crate::cli::progress::progress_bar;
use crate::cli::{count, set_threads};
use crate::compose::{
    ComposeError, LoadedScene, MapName, Pipeline, Scene, relative_to_file, standard_registry,
};
use crate::episode::{
    CellMetrics, CompletedEpisodes, Episode, EpisodeRecord, SUCCESS_RADIUS_M, succeeded, summarize,
};
use crate::particles::{ParticleSet, PoseEstimate};
use crate::plugin::headless_app;
use crate::sweep::Proportion;
use crate::world::map::write_atomically;
use crate::world::{OnMap, TruePose};
use anyhow::Context;
use bevy::prelude::*;
use rayon::prelude::*;
use serde::Serialize;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// The scene `apfn run` uses when none is given: procedural apartments (no files needed).
pub const DEFAULT_SCENE: (&str, &str) = ("scenes/apartment.ron", include_str!("../../scenes/apartment.ron"));

/// The schedule used when neither the command line nor the scene names one.
pub const DEFAULT_SYSTEMS: (&str, &str) = ("systems/random.ron", include_str!("../../systems/random.ron"));

#[derive(clap::Args, Clone, Debug, PartialEq)]
pub struct RunArgs {
    #[command(flatten)]
    pub input: SceneArgs,
    /// Agent steps to simulate (each robot moves once per step).
    #[arg(long, default_value_t = 200)]
    pub steps: u64,
    /// Folder for trajectories.jsonl and run.json (created if missing); without it nothing is
    /// written.
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Independent copies of the scene (seeds seed, seed+1, …), run in parallel on rayon threads.
    #[arg(long, default_value_t = 1)]
    pub worlds: u64,
    /// Worker threads (default: all cores); results do not depend on it.
    #[arg(long)]
    pub threads: Option<usize>,
}

/// Which scene and schedule to simulate; shared by the subcommands that simulate.
#[derive(clap::Args, Clone, Debug, PartialEq)]
pub struct SceneArgs {
    /// Scene file (scenes/*.ron). Default: the embedded procedural-apartment scene.
    #[arg(long)]
    pub scene: Option<PathBuf>,
    /// Schedule file (systems/*.ron). Default: the scene's `systems`, else the embedded
    /// random-policy schedule.
    #[arg(long)]
    pub systems: Option<PathBuf>,
}

impl SceneArgs {
    /// The scene and its schedule, loaded and validated.
    pub fn load(&self) -> anyhow::Result<(LoadedScene, Pipeline)> {
        let loaded = load_scene(self.scene.as_deref())?;
        let pipeline = load_pipeline(self.systems.as_deref(), &loaded)?;
        Ok((loaded, pipeline))
    }
}

/// One robot at one step, as written to trajectories.jsonl.
#[derive(Serialize, Debug, Clone, PartialEq)]
pub struct TrajectoryRow {
    pub world: u64,
    pub step: u64,
    pub robot: usize,
    pub map: String,
    pub episode: u32,
    pub episode_step: u32,
    /// True pose [x m, y m, yaw rad] after the step's motion.
    pub pose: [f32; 3],
    /// The filter's estimate used for this step's action; `None` when the schedule runs no filter.
    pub estimate: Option<[f32; 3]>,
    /// Normalised action [linear, angular] in [−1, 1].
    pub action: [f32; 2],
    pub collided: bool,
}

/// What run.json holds: the inputs, the measured speed and the localization error.
#[derive(Serialize, Debug)]
pub struct RunSummary {
    pub scene: String,
    pub systems: String,
    pub systems_in_order: Vec<&'static str>,
    pub worlds: u64,
    pub maps: usize,
    /// Robots per world.
    pub robots: usize,
    pub steps: u64,
    pub threads: usize,
    pub seconds: f64,
    pub steps_per_s: f64,
    pub robot_steps_per_s: f64,
    /// Over the episodes that ran to their end; `None` without `step_metrics` or such episodes.
    pub localization: Option<CellMetrics>,
}

pub fn run(args: RunArgs) -> anyhow::Result<()> {
    set_threads(args.threads)?;
    crate::limits::WORLDS.check("--worlds", args.worlds).map_err(anyhow::Error::msg)?;
    crate::limits::RUN_STEPS.check("--steps", args.steps).map_err(anyhow::Error::msg)?;
    let (loaded, pipeline) = args.input.load()?;
    let robots_per_world = loaded.maps.len() * loaded.scene.robots_per_map;

    let bar =
        progress_bar(args.steps * args.worlds, "{bar:40} {pos}/{len} world-steps, {per_sec}, eta {eta}");
    let started = Instant::now();
    let worlds = (0..args.worlds)
        .into_par_iter()
        .map(|world| {
            let mut copy = loaded.clone();
            copy.scene.seed += world;
            simulate(&copy, pipeline.clone(), world, args.steps, || bar.inc(1))
        })
        .collect::<Result<Vec<_>, _>>()?;
    let (worlds, episodes): (Vec<_>, Vec<_>) = worlds.into_iter().unzip();
    let episodes: Vec<EpisodeRecord> = episodes.into_iter().flatten().collect();
    bar.finish_and_clear();
    let seconds = started.elapsed().as_secs_f64();

    let summary = RunSummary {
        scene: loaded.path.display().to_string(),
        systems: pipeline.source.display().to_string(),
        systems_in_order: pipeline.names(),
        worlds: args.worlds,
        maps: loaded.maps.len(),
        robots: robots_per_world,
        steps: args.steps,
        threads: rayon::current_num_threads(),
        seconds,
        steps_per_s: (args.steps * args.worlds) as f64 / seconds,
        robot_steps_per_s: (args.steps * args.worlds) as f64 * robots_per_world as f64 / seconds,
        localization: summarize(&episodes),
    };
    let robots = match summary.maps {
        1 => format!("{} on 1 map", count(summary.robots as u64, "robot")),
        maps => format!(
            "{} ({} on each of {maps} maps)",
            count(summary.robots as u64, "robot"),
            loaded.scene.robots_per_map
        ),
    };
    println!(
        "{} × {} × {robots} in {:.2} s: {:.1} world-steps/s, {:.0} robot-steps/s ({})",
        count(summary.steps, "step"),
        count(summary.worlds, "world"),
        seconds,
        summary.steps_per_s,
        summary.robot_steps_per_s,
        count(summary.threads as u64, "thread")
    );
    println!("{}", accuracy_line(&pipeline, &episodes, loaded.scene.episode.steps, args.steps));
    match &args.out {
        Some(out) => {
            let rows: Vec<TrajectoryRow> = worlds.into_iter().flatten().collect();
            write_outputs(out, &rows, &summary)?;
            println!(
                "wrote {} and {}",
                out.join("trajectories.jsonl").display(),
                out.join("run.json").display()
            );
        }
        None => println!("wrote nothing: add --out DIR to save trajectories.jsonl and run.json"),
    }
    Ok(())
}

/// One line on how well the filter localized in the episodes that ran to their end, or why
/// there is nothing to say.
fn accuracy_line(pipeline: &Pipeline, episodes: &[EpisodeRecord], episode_steps: u32, steps: u64) -> String {
    if !pipeline.names().contains(&"step_metrics") {
        return "localization error: not measured (the schedule has no `step_metrics` step)".into();
    }
    let Some(m) = summarize(episodes) else {
        return format!(
            "localization error: no episode finished ({} per episode, {} run); add --steps",
            count(episode_steps, "step"),
            steps
        );
    };
    let successes = episodes.iter().filter(|r| succeeded(&r.log.errors)).count();
    let success = Proportion::wilson(successes, episodes.len()).map_or_else(String::new, |p| p.percent());
    format!(
        "localization error over {} of {}: mean {:.1} cm / {:.3} rad, final {:.1} cm / {:.3} rad; \
         success (< {SUCCESS_RADIUS_M} m over the last quarter) {successes} of {}: {success}",
        count(m.episodes as u64, "finished episode"),
        count(episode_steps, "step"),
        m.mean_pos_err_m * 100.0,
        m.mean_orient_err_rad,
        m.final_pos_err_m * 100.0,
        m.final_orient_err_rad,
        m.episodes
    )
}

/// Runs one independent world for `steps` agent steps; returns every robot's rows and the
/// episodes that ran to their end (logged when the schedule has `step_metrics`).
fn simulate(
    scene: &LoadedScene,
    pipeline: Pipeline,
    world: u64,
    steps: u64,
    on_step: impl Fn(),
) -> Result<(Vec<TrajectoryRow>, Vec<EpisodeRecord>), ComposeError> {
    let (mut app, robots) = headless_app(scene, pipeline)?;
    let mut rows = Vec::new();
    for step in 0..steps {
        app.update();
        rows.extend(snapshot(app.world_mut(), &robots, world, step));
        on_step();
    }
    let episodes = std::mem::take(&mut app.world_mut().resource_mut::<CompletedEpisodes>().0);
    Ok((rows, episodes))
}

/// The scene from `path`, or the embedded default.
pub fn load_scene(path: Option<&Path>) -> anyhow::Result<LoadedScene> {
    Ok(match path {
        Some(path) => Scene::load(path)?,
        None => {
            let (label, text) = DEFAULT_SCENE;
            let scene: Scene = ron::Options::default()
                .from_str(text)
                .with_context(|| format!("embedded default scene {label}"))?;
            scene.into_loaded(Path::new(label))?
        }
    })
}

/// The schedule from `path`, else the scene's own (relative to the scene file), else the default.
pub fn load_pipeline(path: Option<&Path>, scene: &LoadedScene) -> anyhow::Result<Pipeline> {
    let registry = standard_registry();
    Ok(match (path, &scene.scene.systems) {
        (Some(path), _) => Pipeline::load(path, &registry)?,
        (None, Some(relative)) => Pipeline::load(&relative_to_file(&scene.path, relative), &registry)?,
        (None, None) => Pipeline::parse(DEFAULT_SYSTEMS.1, Path::new(DEFAULT_SYSTEMS.0), &registry)?,
    })
}

/// Every robot's row for this step.
fn snapshot(world: &mut World, robots: &[Entity], world_index: u64, step: u64) -> Vec<TrajectoryRow> {
    robots
        .iter()
        .enumerate()
        .filter_map(|(index, &robot)| {
            let entity = world.get_entity(robot).ok()?;
            let pose = entity.get::<TruePose>()?.0;
            let map = entity.get::<OnMap>().and_then(|m| world.get::<MapName>(m.0)).map(|n| n.0.clone());
            let episode = entity.get::<Episode>().copied().unwrap_or_default();
            let action = entity.get::<Action>().copied().unwrap_or_default();
            // Every robot spawns with an empty set marked `NeedsInit`; `init_particles` fills it when a filter runs.
            let filtering = entity.get::<ParticleSet>().is_some_and(|set| !set.is_empty());
            Some(TrajectoryRow {
                world: world_index,
                step,
                robot: index,
                map: map.unwrap_or_default(),
                episode: episode.index,
                episode_step: episode.step,
                pose: [pose.x, pose.y, pose.yaw],
                estimate: filtering
                    .then(|| entity.get::<PoseEstimate>())
                    .flatten()
                    .map(|e| [e.pose.x, e.pose.y, e.pose.yaw]),
                action: [action.linear, action.angular],
                collided: entity.get::<Collided>().is_some_and(|c| c.0),
            })
        })
        .collect()
}

/// Writes both files atomically: an interrupted run never leaves half a file.
fn write_outputs(out: &Path, rows: &[TrajectoryRow], summary: &RunSummary) -> anyhow::Result<()> {
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    let mut lines = String::new();
    for row in rows {
        lines += &serde_json::to_string(row)?;
        lines.push('\n');
    }
    write_atomically(&out.join("trajectories.jsonl"), lines.as_bytes())?;
    write_atomically(&out.join("run.json"), serde_json::to_string_pretty(summary)?.as_bytes())?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::episode::{EpisodeLog, StepError};

    fn episode(final_err_m: f32) -> EpisodeRecord {
        let err = |pos_err_m| StepError { pos_err_m, orient_err_rad: 0.1, loss: 0.0 };
        let log = EpisodeLog { errors: vec![err(0.1), err(final_err_m)], ..Default::default() };
        EpisodeRecord { robot: Entity::PLACEHOLDER, map: Entity::PLACEHOLDER, episode: 0, log }
    }

    #[test]
    fn accuracy_line_reports_errors_success_or_why_not() {
        let registry = standard_registry();
        let parse = |text: &str| Pipeline::parse(text, Path::new("inline.ron"), &registry).expect("schedule");
        let measured = parse(DEFAULT_SYSTEMS.1);
        let line = accuracy_line(&measured, &[episode(0.2), episode(3.0)], 2, 10);
        assert!(line.contains("2 finished episodes of 2 steps"), "{line}");
        assert!(line.contains("final 160.0 cm") && line.contains("1 of 2: 50 %"), "{line}");
        let none = accuracy_line(&measured, &[], 50, 30);
        assert!(none.contains("no episode finished (50 steps per episode, 30 run)"), "{none}");
        let unmeasured = parse(r#"Schedule(steps: [("random_policy", ()), ("drive", ())])"#);
        assert!(accuracy_line(&unmeasured, &[], 50, 30).contains("not measured"));
    }
}
