//! Errors of composition: schedule and scene files, with the file, the place and what was expected.

use serde::de::DeserializeOwned;
use std::path::{Path, PathBuf};

#[derive(Debug, thiserror::Error)]
pub enum ComposeError {
    #[error("cannot read {path}: {source}")]
    Read { path: PathBuf, source: std::io::Error },

    /// A RON syntax or type error; `line` and `col` are 1-based.
    #[error("{path}:{line}:{col}: {message}")]
    Parse { path: PathBuf, line: usize, col: usize, message: String },

    /// The file parsed but its steps cannot run in this order or combination.
    #[error("{path}: step {index} `{name}`: {message}")]
    Step { path: PathBuf, index: usize, name: String, message: String },

    /// A scene asks for something impossible (no maps, zero robots, an unloadable map…).
    #[error("{path}: field `{field}`: {message}")]
    Scene { path: PathBuf, field: String, message: String },
}

impl ComposeError {
    pub(crate) fn from_ron(path: impl Into<PathBuf>, err: ron::error::SpannedError) -> Self {
        ComposeError::Parse {
            path: path.into(),
            line: err.span.start.line,
            col: err.span.start.col,
            message: err.code.to_string(),
        }
    }
}

/// Reads a RON file into `T`; errors name the file, and the line and column for syntax and type
/// errors.
pub fn read_ron<T: DeserializeOwned>(path: &Path) -> Result<T, ComposeError> {
    let text = read_text(path)?;
    ron::Options::default().from_str(&text).map_err(|e| ComposeError::from_ron(path, e))
}

/// Reads a text file, naming it in the error.
pub fn read_text(path: &Path) -> Result<String, ComposeError> {
    std::fs::read_to_string(path).map_err(|source| ComposeError::Read { path: path.to_owned(), source })
}
