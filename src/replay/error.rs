//! Everything that can go wrong replaying a log: reading it, a malformed line (with its number and
//! field), or a filter that cannot start (no initial pose, no particles, an unusable map).

use crate::particles::{ParticleError, Task};
use crate::world::map::MapError;
use std::path::PathBuf;
use thiserror::Error;

/// Errors of the `replay` module.
#[derive(Debug, Error)]
pub enum ReplayError {
    /// The log file could not be read.
    #[error("cannot read log {path}: {source}")]
    Read {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },

    /// A line is not a JSON object; `line` and `column` are 1-based.
    #[error("{path}:{line}:{column}: not a JSON object: {message}")]
    Syntax { path: PathBuf, line: usize, column: usize, message: String },

    /// A line parsed as JSON but one field is missing or unusable; `line` is 1-based.
    #[error("{path}:{line}: field `{field}`: expected {expected}, found {found}")]
    Field { path: PathBuf, line: usize, field: &'static str, expected: &'static str, found: String },

    /// The log holds no line to localize.
    #[error("log {path} holds no line; expected one JSON object per line")]
    Empty { path: PathBuf },

    /// Tracking and semi-global need to know roughly where the robot starts.
    #[error(
        "task {} needs an initial pose: pass --init x,y,θ or record `truth` on the log's first line (or use --task global)",
        task.name()
    )]
    NoInitialPose { task: Task },

    /// A filter parameter is out of range.
    #[error("parameter `{field}` out of range: expected {expected}")]
    InvalidParam { field: &'static str, expected: &'static str },

    /// The filter's schedule does not build (e.g. a PF-net checkpoint that does not load).
    #[error("{0}")]
    Schedule(String),

    /// The map cannot carry a filter (e.g. no traversable space for the robot radius).
    #[error(transparent)]
    Map(#[from] MapError),

    /// The initial particle set cannot be drawn.
    #[error(transparent)]
    Particles(#[from] ParticleError),
}
