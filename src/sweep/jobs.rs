//! The job list of a sweep: schedules × map groups × tasks × seeds, in that order, each job one
//! eval cell with one seed and a stable, filesystem-safe name such as
//! `random__tracking__seen__seed1`. Any engine that can run `apfn sweep FILE --job N` for N in
//! 0..jobs runs the sweep (see docs/cluster.md).

use crate::eval::{CellSpec, cell_steps};
use crate::sweep::config::LoadedSweep;
use crate::sweep::error::SweepError;

/// One job: which cell of the eval config, with which seed, and the name its result is stored under.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Job {
    pub index: usize,
    pub name: String,
    /// The schedule file's stem, which tells ablations with the same localizer and policy apart.
    pub schedule: String,
    pub cell: CellSpec,
    pub seed: u64,
}

/// Every job of a sweep, in the order `--job N` indexes. Fails if two jobs would share a name
/// (two schedule files with one stem, or two map groups with one split label).
pub fn jobs(sweep: &LoadedSweep) -> Result<Vec<Job>, SweepError> {
    let eval = &sweep.eval;
    let mut jobs: Vec<Job> = Vec::new();
    for (schedule, (path, _)) in eval.schedules.iter().enumerate() {
        let stem = safe(&path.file_stem().map_or("schedule".into(), |s| s.to_string_lossy().into_owned()));
        for (group, map_group) in eval.config.maps.iter().enumerate() {
            for &task in &eval.config.tasks {
                for &seed in &sweep.config.seeds {
                    let name =
                        format!("{stem}__{}__{}__seed{seed}", task.name(), safe(&map_group.split_label()));
                    if let Some(other) = jobs.iter().find(|j| j.name == name) {
                        return Err(SweepError::Invalid {
                            path: sweep.path.clone(),
                            field: "eval".into(),
                            message: format!(
                                "jobs {} and {} would both be named `{name}`; expected schedule files with \
                                 distinct names, map groups with distinct splits, and tasks listed once",
                                other.index,
                                jobs.len()
                            ),
                        });
                    }
                    let cell = CellSpec { schedule, task, group };
                    jobs.push(Job { index: jobs.len(), name, schedule: stem.clone(), cell, seed });
                }
            }
        }
    }
    Ok(jobs)
}

/// `--list-jobs`: one `index<TAB>name` line per job, so `cut -f1` gives the indices.
pub fn list_lines(jobs: &[Job]) -> Vec<String> {
    jobs.iter().map(|j| format!("{}\t{}", j.index, j.name)).collect()
}

/// The job `--job index` runs, or a clear error past the end.
pub fn job_at(sweep: &LoadedSweep, jobs: &[Job], index: usize) -> Result<Job, SweepError> {
    jobs.get(index).cloned().ok_or_else(|| SweepError::JobOutOfRange {
        path: sweep.path.clone(),
        index,
        count: jobs.len(),
    })
}

/// Agent steps a job runs (for progress bars).
pub fn job_steps(sweep: &LoadedSweep, job: &Job) -> u64 {
    cell_steps(&sweep.eval, &job.cell)
}

/// Keeps letters, digits, `-` and `.`; anything else (spaces, slashes, `__`) becomes `_`,
/// so names stay one path component and `__` stays the field separator.
fn safe(label: &str) -> String {
    let mut out = String::with_capacity(label.len());
    for c in label.chars() {
        let c = if c.is_ascii_alphanumeric() || c == '-' || c == '.' { c } else { '_' };
        if !(c == '_' && out.ends_with('_')) {
            out.push(c);
        }
    }
    out
}
