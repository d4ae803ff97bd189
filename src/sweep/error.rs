//! Errors of sweeps: the sweep file, its job list and the per-job result files, each naming the
//! file (and field or job) and what was expected.

use crate::compose::ComposeError;
use crate::world::map::MapError;
use std::path::PathBuf;

#[derive(Debug, thiserror::Error)]
pub enum SweepError {
    #[error("cannot read {path}: {source}")]
    Read { path: PathBuf, source: std::io::Error },

    #[error("cannot create the folder {path}: {source}")]
    CreateDir { path: PathBuf, source: std::io::Error },

    /// The sweep file parsed but asks for something impossible (no seeds, colliding job names…).
    #[error("{path}: field `{field}`: {message}")]
    Invalid { path: PathBuf, field: String, message: String },

    /// A schedule, map or eval field named by the sweep's `eval: (…)` is unusable.
    #[error(transparent)]
    Compose(#[from] ComposeError),

    /// `--job N` past the end of the job list.
    #[error("{path}: job {index} does not exist; expected an index below {count} (see `--list-jobs`)")]
    JobOutOfRange { path: PathBuf, index: usize, count: usize },

    /// A job result file exists but is not a job result of this sweep.
    #[error("{path}: {message}")]
    JobFile { path: PathBuf, message: String },

    /// `--merge` found jobs without a result file.
    #[error(
        "{out}: {} of {total} jobs have no result yet: {}; run them (`--job N`) or pass --allow-partial",
        missing.len(),
        missing.join(", ")
    )]
    MissingJobs { out: PathBuf, total: usize, missing: Vec<String> },

    /// Writing a result file failed.
    #[error(transparent)]
    Write(#[from] MapError),
}
