//! One cell of a results table: a schedule (localizer × policy) on one task and one map group,
//! run for a fixed number of episodes in a single batched world.

use crate::compose::{ComposeError, Pipeline};
use crate::episode::{CompletedEpisodes, EpisodeRecord, summarize};
use crate::eval::config::LoadedEval;
use crate::eval::episodes::EpisodeRow;
use crate::eval::row::ResultRow;
use crate::eval::steps::StepRow;
use crate::particles::{InitParams, ObservationModel, Task};
use crate::plugin::{ApfnSet, headless_app};
use crate::world::OccupancyMap;
use bevy::prelude::Entity;
use std::collections::HashMap;

/// Which schedule, task and map group a cell crosses (indices into the loaded config).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct CellSpec {
    pub schedule: usize,
    pub task: Task,
    pub group: usize,
}

/// Every cell of a config: schedules × tasks × map groups, in table order.
pub fn cells(eval: &LoadedEval) -> Vec<CellSpec> {
    let mut cells = Vec::new();
    for schedule in 0..eval.schedules.len() {
        for &task in &eval.config.tasks {
            for group in 0..eval.scenes.len() {
                cells.push(CellSpec { schedule, task, group });
            }
        }
    }
    cells
}

/// Agent steps a cell runs: enough whole episodes for every robot to reach `episodes` in total.
pub fn cell_steps(eval: &LoadedEval, cell: &CellSpec) -> u64 {
    let scene = &eval.scenes[cell.group];
    let robots = scene.maps.len() * scene.scene.robots_per_map;
    (eval.config.episodes.div_ceil(robots) as u64) * eval.config.episode.steps as u64
}

/// The localizer and policy a schedule runs, for the table: the Particles-stage step that
/// weighs particles against a sensor (`mcl` for the likelihood field, `mcl_beam` for the beam
/// model, `pfnet` for PF-net), and the Agent-stage policy, without its `_policy` suffix (the SAC
/// agent's rows are `apfn`, the paper's name for it).
pub fn labels(pipeline: &Pipeline) -> (String, String) {
    let policy =
        pipeline.steps.iter().find(|s| s.stage == ApfnSet::Agent).map_or("none".into(), |s| match s.name {
            "sac_policy" => "apfn".into(),
            name => name.trim_end_matches("_policy").to_owned(),
        });
    let is_likelihood = |n: &&&str| {
        [ObservationModel::LikelihoodField, ObservationModel::BeamModel, ObservationModel::PfNet]
            .iter()
            .any(|m| m.system_name() == **n)
    };
    let localizer = match pipeline.names().iter().find(is_likelihood) {
        Some(&"mcl_beam_model") => "mcl_beam".to_owned(),
        Some(&"pfnet_likelihood") => "pfnet".to_owned(),
        Some(name) if name.starts_with("mcl") => "mcl".to_owned(),
        Some(name) => name.to_string(),
        None => "odometry_only".to_owned(),
    };
    (localizer, policy)
}

/// The table labels of the config's `index`-th schedule: [`labels`] (the localizer renamed when
/// the config names it), with the schedule's file
/// stem appended to the policy when another schedule of the config has the same labels (an
/// ablation that changes a parameter or a filter step), e.g. `random (resample_none)`.
pub fn schedule_labels(eval: &LoadedEval, index: usize) -> (String, String) {
    let (path, pipeline) = &eval.schedules[index];
    let own = labels(pipeline);
    let clash = (eval.schedules.iter().enumerate()).any(|(other, (_, p))| other != index && labels(p) == own);
    let (derived, policy) = own;
    let localizer = eval.config.localizer.clone().unwrap_or(derived);
    match (clash, path.file_stem()) {
        (true, Some(stem)) => (localizer, format!("{policy} ({})", stem.to_string_lossy())),
        _ => (localizer, policy),
    }
}

/// A finished cell: its table row, one summary per episode, the error at each step over its
/// episodes, the episodes' full records, and the maps they ran on (by entity, as
/// `EpisodeRecord::map` names them) for figures.
pub struct CellOutcome {
    pub row: ResultRow,
    pub episodes: Vec<EpisodeRow>,
    pub steps: Vec<StepRow>,
    pub records: Vec<EpisodeRecord>,
    pub maps: HashMap<Entity, OccupancyMap>,
}

/// Runs one cell. `on_step` is called after every agent step (for progress bars).
pub fn run_cell(eval: &LoadedEval, cell: &CellSpec, on_step: impl Fn()) -> Result<CellOutcome, ComposeError> {
    let (schedule_path, pipeline) = &eval.schedules[cell.schedule];
    let scene = &eval.scenes[cell.group];
    let (localizer, policy) = schedule_labels(eval, cell.schedule);
    let (mut app, _robots) = headless_app(scene, pipeline.clone())?;
    let world = app.world_mut();
    // The config's count wins, then the schedule's own `init_particles (particles: …)`, then the
    // task default.
    let schedule_init = world.resource::<InitParams>().clone();
    let init = InitParams {
        task: cell.task,
        particles: eval.config.particles.or(schedule_init.particles),
        mix: Vec::new(),
        ..schedule_init
    };
    let particles = init.particle_count();
    world.insert_resource(init);
    world.init_resource::<CompletedEpisodes>();
    for _ in 0..cell_steps(eval, cell) {
        app.update();
        on_step();
    }
    let world = app.world_mut();
    let mut records = std::mem::take(&mut world.resource_mut::<CompletedEpisodes>().0);
    let maps = world.query::<(Entity, &OccupancyMap)>().iter(world).map(|(e, m)| (e, m.clone())).collect();
    records.truncate(eval.config.episodes);
    let m = summarize(&records).ok_or_else(|| ComposeError::Scene {
        path: eval.path.clone(),
        field: "episode".into(),
        message: format!(
            "no episode of {} finished in {} agent steps",
            schedule_path.display(),
            cell_steps(eval, cell)
        ),
    })?;
    let group = &eval.config.maps[cell.group];
    let row = ResultRow {
        localizer,
        policy,
        task: cell.task,
        split: group.split_label(),
        map: group.map_label(),
        particles,
        episodes: m.episodes,
        seed: eval.config.seed,
        mean_pos_err_m: m.mean_pos_err_m,
        rmse_pos_m: m.rmse_pos_m,
        final_pos_err_m: m.final_pos_err_m,
        mean_orient_err_rad: m.mean_orient_err_rad,
        final_orient_err_rad: m.final_orient_err_rad,
        success_rate: m.success_rate,
    };
    let episodes =
        records.iter().enumerate().filter_map(|(k, r)| EpisodeRow::from_record(&row, k, r)).collect();
    let steps = StepRow::of_cell(&row, &records);
    Ok(CellOutcome { row, episodes, steps, records, maps })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::compose::standard_registry;
    use std::path::Path;

    #[test]
    fn labels_name_the_likelihood_model() {
        let registry = standard_registry();
        let label = |step: &str| {
            let text = format!(
                r#"Schedule(steps: [("lidar", ()), ("init_particles", ()), ("{step}", ()), ("random_policy", ())])"#
            );
            let pipeline =
                Pipeline::parse(&text, Path::new("inline.ron"), &registry).expect("valid schedule");
            labels(&pipeline)
        };
        assert_eq!(label("mcl_likelihood_field"), ("mcl".into(), "random".into()));
        assert_eq!(
            label("mcl_beam_model"),
            ("mcl_beam".into(), "random".into()),
            "beam model is not plain mcl"
        );
    }
}
