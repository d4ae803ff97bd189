//! Evaluation configs (`apfn eval --config FILE.ron`): which schedules (localizer × policy), tasks
//! and maps to cross, and how many episodes per cell.
//!
//! ```ron
//! Eval(
//!     schedules: ["../systems/turn.ron", "../systems/random.ron"],
//!     tasks: [tracking, semi_global, global],
//!     maps: [Apartments(split: seen, count: 5), Apartments(split: unseen, count: 5)],
//!     episodes: 50,
//! )
//! ```

use crate::compose::{
    ComposeError, MapSource, Pipeline, Scene, read_ron, relative_to_file, standard_registry,
};
use crate::episode::EpisodeParams;
use crate::limits::{EPISODES, PARTICLES};
use crate::particles::Task;
use crate::world::RobotParams;
use crate::world::map::procedural::{ApartmentParams, Split};
use ron::value::RawValue;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

#[derive(Serialize, Deserialize, Clone, Debug, PartialEq)]
#[serde(rename = "Eval", deny_unknown_fields)]
pub struct EvalConfig {
    /// Schedule files to compare, relative to this file; each is one localizer × policy.
    pub schedules: Vec<PathBuf>,
    #[serde(default = "all_tasks")]
    pub tasks: Vec<Task>,
    /// Map groups; each is one `split` column of the table.
    pub maps: Vec<MapGroup>,
    /// Episodes per cell (paper: 50).
    #[serde(default = "fifty")]
    pub episodes: usize,
    /// Robots driving at once on each map of a cell (batched through every system).
    #[serde(default = "five")]
    pub robots_per_map: usize,
    /// Particle count for every task; `None` keeps the task defaults (300 / 500 / 3,000).
    #[serde(default)]
    pub particles: Option<usize>,
    #[serde(default)]
    pub seed: u64,
    #[serde(default)]
    pub episode: EpisodeParams,
    #[serde(default)]
    pub robot: RobotParams,
    /// Parameters that replace a step's own in every schedule that runs the step, e.g.
    /// `overrides: [("lidar", (range_max_m: 12.0))]`: one config evaluates every policy under
    /// another sensor or filter setting without copies of their schedule files. Fields left out
    /// take the system's defaults.
    #[serde(default)]
    pub overrides: Vec<(String, Box<RawValue>)>,
    /// Steps that replace another in every schedule that runs it, applied before `overrides`:
    /// `swaps: [("mcl_likelihood_field", "pfnet_likelihood", (checkpoint: Some("m.safetensors")))]`
    /// evaluates every policy with PF-net as the localizer from the same schedule files.
    #[serde(default)]
    pub swaps: Vec<(String, String, Box<RawValue>)>,
    /// Steps inserted right after another in every schedule that runs it, applied after `swaps`
    /// and before `overrides`: `inserts: [("mcl_likelihood_field", "augmented_recovery",
    /// (alpha_slow: 0.05, alpha_fast: 0.5))]` evaluates every policy with augmented MCL.
    #[serde(default)]
    pub inserts: Vec<(String, String, Box<RawValue>)>,
    /// The localizer's name in the tables; `None` derives it from the schedules' likelihood step.
    #[serde(default)]
    pub localizer: Option<String>,
    /// More rows: every schedule that runs the step is evaluated once more per variant, with the
    /// step's parameters replaced (after `overrides`), its row labelled `<policy> (<schedule
    /// file stem>+<name>)`.
    /// `variants: [("sac_policy", "step_8000", (checkpoint: Some("runs/sac/policy_8000.safetensors")))]`
    /// compares a training run's checkpoints in one table; `[("infogain_policy", "horizon_3",
    /// (horizon_steps: 3))]` a parameter.
    #[serde(default)]
    pub variants: Vec<(String, String, Box<RawValue>)>,
}

fn all_tasks() -> Vec<Task> {
    vec![Task::Tracking, Task::SemiGlobal, Task::Global]
}

fn fifty() -> usize {
    50
}

fn five() -> usize {
    5
}

/// How a config entry edits the schedules.
#[derive(Clone, Copy)]
enum Edit {
    Replace,
    InsertAfter,
}

/// One column group of the results table.
#[derive(Serialize, Deserialize, Clone, Debug, PartialEq)]
#[serde(deny_unknown_fields)]
pub enum MapGroup {
    /// `count` procedural apartments of a split, starting `first` seeds into its range.
    Apartments {
        split: Split,
        #[serde(default)]
        first: u64,
        count: usize,
        /// Their shape (default: `ApartmentParams::default()`; the paper's size range with scan
        /// realism is `(min_side_m: 5.0, max_side_m: 10.0, max_rooms: 5, mean_room_area_m2: 15.0,
        /// realism: ())`, what PF-net trains on).
        #[serde(default)]
        params: ApartmentParams,
    },
    /// ROS maps (relative to the config file), spelled as in scenes: `Ros(path: "a.yaml")` for
    /// one, `Ros(paths: [...])` for a column over several. Its split is the maps' names.
    Ros {
        #[serde(default, deserialize_with = "crate::compose::some_path")]
        path: Option<PathBuf>,
        #[serde(default)]
        paths: Vec<PathBuf>,
    },
}

impl MapGroup {
    /// The table's `split` label: `seen`, `unseen`, or the ROS map's file stem.
    pub fn split_label(&self) -> String {
        match self {
            MapGroup::Apartments { split: Split::Seen, .. } => "seen".into(),
            MapGroup::Apartments { split: Split::Unseen, .. } => "unseen".into(),
            MapGroup::Ros { path, paths } => {
                let stem =
                    |p: &PathBuf| p.file_stem().map_or("map".into(), |s| s.to_string_lossy().into_owned());
                path.iter().chain(paths).map(stem).collect::<Vec<_>>().join("+")
            }
        }
    }

    /// The table's `map` label: the seeds or the file.
    pub fn map_label(&self) -> String {
        match self {
            MapGroup::Apartments { split, first, count, .. } => {
                let start = split.seeds().start + first;
                format!("apartments {start}..{}", start + *count as u64)
            }
            MapGroup::Ros { path, paths } => {
                path.iter().chain(paths).map(|p| p.display().to_string()).collect::<Vec<_>>().join(", ")
            }
        }
    }

    /// Paths stay relative to the config file, which the scene resolves them against.
    fn map_source(&self) -> MapSource {
        match self {
            MapGroup::Apartments { split, first, count, params } => {
                MapSource::Procedural { split: *split, first: *first, count: *count, params: params.clone() }
            }
            MapGroup::Ros { path, paths } => MapSource::Ros { path: path.clone(), paths: paths.clone() },
        }
    }
}

/// A config with everything it names loaded and validated, before any episode runs.
pub struct LoadedEval {
    pub path: PathBuf,
    pub config: EvalConfig,
    pub schedules: Vec<(PathBuf, Pipeline)>,
    /// One loaded scene per map group, in config order.
    pub scenes: Vec<crate::compose::LoadedScene>,
}

impl EvalConfig {
    /// Reads a config and loads every schedule and map it names, so that a typo fails in
    /// seconds rather than after hours of episodes.
    pub fn load(path: &Path) -> Result<LoadedEval, ComposeError> {
        read_ron::<EvalConfig>(path)?.into_loaded(path)
    }

    pub fn into_loaded(self, path: &Path) -> Result<LoadedEval, ComposeError> {
        let invalid = |field: &str, message: String| ComposeError::Scene {
            path: path.to_owned(),
            field: field.to_owned(),
            message,
        };
        for (field, empty) in [
            ("schedules", self.schedules.is_empty()),
            ("tasks", self.tasks.is_empty()),
            ("maps", self.maps.is_empty()),
        ] {
            if empty {
                return Err(invalid(field, "expected at least one entry".into()));
            }
        }
        if !EPISODES.contains(self.episodes) {
            let message = format!("expected {}, got {}", EPISODES.expected, self.episodes);
            return Err(invalid("episodes", message));
        }
        if let Some(n) = self.particles
            && !PARTICLES.contains(n)
        {
            let message =
                format!("expected {} (or leave it out for the task defaults), got {n}", PARTICLES.expected);
            return Err(invalid("particles", message));
        }
        let registry = standard_registry();
        let mut schedules = self
            .schedules
            .iter()
            .map(|p| {
                let pipeline = Pipeline::load(&relative_to_file(path, p), &registry)?;
                // A filter to evaluate, and the episodes and per-step errors the table is made of
                // (`step_metrics` itself needs `episode_reset`).
                for needed in ["init_particles", "estimate", "step_metrics"] {
                    if !pipeline.names().contains(&needed) {
                        return Err(invalid(
                            "schedules",
                            format!(
                                "{} has no `{needed}` step; an evaluated schedule needs `init_particles`, \
                                 `estimate` and `step_metrics`",
                                p.display()
                            ),
                        ));
                    }
                }
                Ok((p.clone(), pipeline))
            })
            .collect::<Result<Vec<_>, ComposeError>>()?;
        // An override is a swap of a step for itself with other parameters.
        let swaps = self.swaps.iter().enumerate().map(|(index, (old, new, params))| {
            (format!("swaps[{index}] (`{old}` → `{new}`)"), Edit::Replace, old, new, params)
        });
        let inserts = self.inserts.iter().enumerate().map(|(index, (after, new, params))| {
            (format!("inserts[{index}] (`{new}` after `{after}`)"), Edit::InsertAfter, after, new, params)
        });
        let overrides = self.overrides.iter().enumerate().map(|(index, (name, params))| {
            (format!("overrides[{index}] (`{name}`)"), Edit::Replace, name, name, params)
        });
        for (field, edit, at, new, params) in swaps.chain(inserts).chain(overrides) {
            let mut applied = false;
            for (_, pipeline) in &mut schedules {
                let edited = match edit {
                    Edit::Replace => pipeline.replace_step(at, new, params.get_ron(), &registry),
                    Edit::InsertAfter => pipeline.insert_step_after(at, new, params.get_ron(), &registry),
                };
                applied |= edited.map_err(|message| invalid(&field, message))?;
            }
            if !applied {
                return Err(invalid(&field, format!("no schedule of this config runs `{at}`")));
            }
        }
        let mut variants = Vec::new();
        for (index, (step, name, params)) in self.variants.iter().enumerate() {
            let field = format!("variants[{index}] (`{name}`)");
            // The name becomes part of a file stem: the row's label, a sweep job's file name.
            if name.is_empty() || !name.chars().all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '-') {
                return Err(invalid(&field, "expected a name of letters, digits, `_` and `-`".into()));
            }
            let before = variants.len();
            for (path, pipeline) in &schedules {
                let mut variant = pipeline.clone();
                if variant
                    .replace_step(step, step, params.get_ron(), &registry)
                    .map_err(|m| invalid(&field, m))?
                {
                    let stem =
                        path.file_stem().map_or("schedule".into(), |s| s.to_string_lossy().into_owned());
                    variants.push((path.with_file_name(format!("{stem}+{name}.ron")), variant));
                }
            }
            if variants.len() == before {
                return Err(invalid(&field, format!("no schedule of this config runs `{step}`")));
            }
        }
        schedules.extend(variants);
        for (_, pipeline) in &schedules {
            crate::plugin::check_policy_inputs(pipeline)?;
        }
        let scenes = self
            .maps
            .iter()
            .map(|group| {
                let scene = Scene {
                    maps: group.map_source(),
                    robots_per_map: self.robots_per_map,
                    robots_collide: false,
                    seed: self.seed,
                    episode: self.episode.clone(),
                    robot: self.robot.clone(),
                    physics: Default::default(),
                    systems: None,
                };
                scene.into_loaded(path)
            })
            .collect::<Result<Vec<_>, ComposeError>>()?;
        Ok(LoadedEval { path: path.to_owned(), config: self, schedules, scenes })
    }
}
