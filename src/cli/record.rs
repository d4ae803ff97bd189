//! `apfn record`: simulates a scene and writes one robot's odometry and LiDAR as a JSON Lines log
//! that `apfn localize` (or any other localizer) can replay.
//!
//! Timing: every agent step senses first (odometry, LiDAR) and moves last, so line k holds the
//! scan taken at the start of step k, `truth` = the pose it was taken from (the robot's
//! `PreviousPose` after the step, which `odometry` sets to the pre-motion `TruePose`) and
//! `t` = k × dt × substeps simulated seconds (rounded to the microsecond).
//!
//! Odometry: like a ROS `nav_msgs/Odometry` pose, `odom` is cumulative in the odom frame and starts
//! at (0, 0, 0) on the first line; line k is line k−1 composed with the simulator's noisy
//! per-step `Odometry.delta` (the motion between the two scans).
//!
//! Episodes never reset while recording (the episode length is raised above `--steps`): a reset
//! teleports the robot, which no odometry could explain.

use crate::cli::progress::progress_bar;
use crate::cli::run::SceneArgs;
use crate::compose::{LoadedScene, MapName, Pipeline};
use crate::plugin::headless_app;
use crate::replay::{LogLine, to_jsonl};
use crate::sense::{LidarScan, Odometry};
use crate::world::map::{save_ros_map, write_atomically};
use crate::world::{OccupancyMap, OnMap, Pose2, PreviousPose};
use anyhow::{Context, bail};
use std::path::{Path, PathBuf};

#[derive(clap::Args, Clone, Debug, PartialEq)]
pub struct RecordArgs {
    /// The schedule must run `odometry` and `lidar`.
    #[command(flatten)]
    pub input: SceneArgs,
    /// Agent steps to record: one log line each.
    #[arg(long, default_value_t = 200)]
    pub steps: u64,
    /// Which robot to log (spawn order: map by map, robots_per_map each).
    #[arg(long, default_value_t = 0)]
    pub robot: usize,
    /// The log to write (JSON Lines, written atomically).
    #[arg(long)]
    pub out: PathBuf,
    /// Folder to save the logged robot's map in as ROS YAML + PGM (`<map name>.yaml`), for replay.
    #[arg(long)]
    pub export_map: Option<PathBuf>,
}

/// One robot's recorded log and the map it drove on.
#[derive(Clone, Debug)]
pub struct Recording {
    pub lines: Vec<LogLine>,
    /// The scene's name for the map (e.g. `apartment_0`).
    pub map_name: String,
    /// Index of that map in the scene's map list.
    pub map_index: usize,
    pub map: OccupancyMap,
}

pub fn run(args: RecordArgs) -> anyhow::Result<()> {
    let (loaded, pipeline) = args.input.load()?;
    let bar = progress_bar(args.steps, "{bar:40} {pos}/{len} steps, {per_sec}, eta {eta}");
    let map_count = loaded.maps.len();
    let recording = record(loaded, pipeline, args.steps, args.robot, || bar.inc(1))?;
    bar.finish_and_clear();

    if let Some(parent) = args.out.parent().filter(|p| !p.as_os_str().is_empty()) {
        std::fs::create_dir_all(parent).with_context(|| format!("creating {}", parent.display()))?;
    }
    write_atomically(&args.out, to_jsonl(&recording.lines)?.as_bytes())?;
    println!(
        "wrote {} lines of robot {} to {}; it drove on map `{}` (map {} of {})",
        recording.lines.len(),
        args.robot,
        args.out.display(),
        recording.map_name,
        recording.map_index + 1,
        map_count
    );
    match &args.export_map {
        Some(dir) => {
            let yaml = export_map(&recording, dir)?;
            println!("saved map `{}` as {} (replay with --map {1})", recording.map_name, yaml.display());
        }
        None if map_count > 1 => {
            println!("the scene has {map_count} maps: add --export-map DIR to save this one for replay")
        }
        None => {}
    }
    Ok(())
}

/// Simulates `steps` agent steps of `scene` under `pipeline` and logs robot `robot` (spawn
/// order). Errors before simulating when the pipeline lacks `odometry` or `lidar`, or the robot
/// index is out of range. `after_step` is called once per step (for progress bars).
pub fn record(
    mut scene: LoadedScene,
    pipeline: Pipeline,
    steps: u64,
    robot: usize,
    mut after_step: impl FnMut(),
) -> anyhow::Result<Recording> {
    let names = pipeline.names();
    for needed in ["odometry", "lidar"] {
        if !names.contains(&needed) {
            bail!(
                "schedule {} has no `{needed}` step; a recording needs both `odometry` and `lidar` (it has {names:?})",
                pipeline.source.display()
            );
        }
    }
    let robots = scene.maps.len() * scene.scene.robots_per_map;
    if robot >= robots {
        bail!(
            "--robot {robot}: scene {} has {robots} robots ({} maps × {} per map); expected 0..={}",
            scene.path.display(),
            scene.maps.len(),
            scene.scene.robots_per_map,
            robots.saturating_sub(1)
        );
    }
    let episode_steps = u32::try_from(steps.saturating_add(1)).unwrap_or(u32::MAX);
    scene.scene.episode.steps = scene.scene.episode.steps.max(episode_steps);
    let step_s = f64::from(scene.scene.physics.dt_s) * f64::from(scene.scene.physics.substeps);

    let (mut app, entities) = headless_app(&scene, pipeline)?;
    let entity = entities[robot];
    let map_entity = app.world().get::<OnMap>(entity).context("the logged robot has no OnMap")?.0;
    let map_name = app.world().get::<MapName>(map_entity).map(|n| n.0.clone()).unwrap_or_default();
    let map_index = scene.maps.iter().position(|m| m.name == map_name).unwrap_or(0);
    let map = scene.maps[map_index].map.clone();

    let mut lines = Vec::new();
    let mut odom = Pose2::default();
    for step in 0..steps {
        app.update();
        let world = app.world();
        let delta = world.get::<Odometry>(entity).context("the logged robot has no Odometry")?.delta;
        let truth = world.get::<PreviousPose>(entity).context("the logged robot has no PreviousPose")?.0;
        let scan = world.get::<LidarScan>(entity).context("the logged robot has no LidarScan")?;
        if step > 0 {
            odom = odom.compose(&delta);
        }
        let t = (step as f64 * step_s * 1e6).round() / 1e6;
        lines.push(LogLine::new(t, odom, scan, Some(truth)));
        after_step();
    }
    Ok(Recording { lines, map_name, map_index, map })
}

/// Saves the recording's map as `<dir>/<map name>.yaml` + `.pgm`; returns the YAML path.
pub fn export_map(recording: &Recording, dir: &Path) -> anyhow::Result<PathBuf> {
    std::fs::create_dir_all(dir).with_context(|| format!("--export-map: creating {}", dir.display()))?;
    let name = if recording.map_name.is_empty() { "map" } else { recording.map_name.as_str() };
    let yaml = dir.join(format!("{name}.yaml"));
    save_ros_map(&recording.map, &yaml)?;
    Ok(yaml)
}
