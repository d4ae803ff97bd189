//! Sweep files (`apfn sweep FILE.ron`): an evaluation config run once per seed.
//!
//! ```ron
//! Sweep(
//!     // The same fields as an `apfn eval` config; paths are relative to this file.
//!     eval: (
//!         schedules: ["../systems/random.ron"],
//!         tasks: [tracking],
//!         maps: [Apartments(split: seen, count: 2)],
//!         episodes: 10,
//!     ),
//!     seeds: [0, 1, 2],
//!     out: "../results/sweep_resampling",
//! )
//! ```
//!
//! `eval.seed` is ignored: each job runs with one of `seeds`. `out` is relative to this file
//! (`apfn sweep --out DIR` overrides it).

use crate::compose::{read_ron, relative_to_file};
use crate::eval::{EvalConfig, LoadedEval};
use crate::limits::SEEDS;
use crate::sweep::error::SweepError;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

#[derive(Serialize, Deserialize, Clone, Debug, PartialEq)]
#[serde(rename = "Sweep", deny_unknown_fields)]
pub struct SweepConfig {
    /// What every seed runs: schedules × tasks × map groups, as in `apfn eval`.
    pub eval: EvalConfig,
    /// One job per seed for every cell; the table reports mean and 95 % CI across them.
    pub seeds: Vec<u64>,
    /// Output folder for `jobs/` and the merged tables, relative to the sweep file.
    pub out: PathBuf,
}

/// A sweep with every schedule and map loaded and validated, before any job runs.
pub struct LoadedSweep {
    pub path: PathBuf,
    pub config: SweepConfig,
    /// The eval config, loaded once; `seeded` gives each job its copy.
    pub eval: LoadedEval,
    /// Where `jobs/` and the merged tables go.
    pub out: PathBuf,
}

impl SweepConfig {
    /// Reads a sweep file and loads everything it names, so that a typo fails in seconds.
    pub fn load(path: &Path) -> Result<LoadedSweep, SweepError> {
        read_ron::<SweepConfig>(path)?.into_loaded(path)
    }

    /// Validates an in-code sweep; `path` labels errors and anchors relative paths.
    pub fn into_loaded(self, path: &Path) -> Result<LoadedSweep, SweepError> {
        let invalid = |field: &str, message: String| SweepError::Invalid {
            path: path.to_owned(),
            field: field.to_owned(),
            message,
        };
        if !SEEDS.contains(self.seeds.len()) {
            return Err(invalid("seeds", format!("expected {}, got {}", SEEDS.expected, self.seeds.len())));
        }
        if let Some(seed) =
            self.seeds.iter().enumerate().find_map(|(i, s)| self.seeds[..i].contains(s).then_some(s))
        {
            return Err(invalid("seeds", format!("seed {seed} is listed twice; expected distinct seeds")));
        }
        let out = relative_to_file(path, &self.out);
        let eval = self.eval.clone().into_loaded(path)?;
        Ok(LoadedSweep { path: path.to_owned(), config: self, eval, out })
    }
}

impl LoadedSweep {
    /// The loaded eval with `seed` in place of its own: the config's and every scene's (the
    /// only places a seed lives; maps do not depend on it).
    pub fn seeded(&self, seed: u64) -> LoadedEval {
        let mut config = self.eval.config.clone();
        config.seed = seed;
        let scenes = self
            .eval
            .scenes
            .iter()
            .map(|scene| {
                let mut scene = scene.clone();
                scene.scene.seed = seed;
                scene
            })
            .collect();
        LoadedEval { path: self.eval.path.clone(), config, schedules: self.eval.schedules.clone(), scenes }
    }
}
