//! Everything that can go wrong reading, writing or deriving maps. Each variant names the file
//! (and the field) involved and says what was expected.

use std::path::PathBuf;
use thiserror::Error;

/// Errors of the `world::map` module.
#[derive(Debug, Error)]
pub enum MapError {
    /// The map YAML itself could not be read.
    #[error("cannot read map YAML {path}: {source}")]
    YamlUnreadable {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },

    /// The map YAML is not valid YAML (or not a mapping of `key: value` lines).
    #[error("map YAML {path} is not valid YAML at line {line}, column {column}: {message}")]
    YamlParse { path: PathBuf, line: usize, column: usize, message: String },

    /// A required field is absent from the map YAML.
    #[error("map YAML {path} has no `{field}` field; expected {expected}")]
    MissingField { path: PathBuf, field: &'static str, expected: String },

    /// A field is present but its value is unusable.
    #[error("map YAML {path}: field `{field}` is {found}; expected {expected}")]
    InvalidField { path: PathBuf, field: &'static str, expected: String, found: String },

    /// The image named by the YAML's `image` field does not exist.
    #[error("map image {image} (named by `image` in {yaml}) does not exist")]
    ImageMissing { yaml: PathBuf, image: PathBuf },

    /// The image's header asks for more pixels, or a larger map, than `crate::limits` allows;
    /// checked before the pixels are decoded.
    #[error(
        "map image {path} is {width} × {height} pixels ({width_m} × {height_m} m at {resolution_m} m per pixel); expected {expected}"
    )]
    ImageTooLarge {
        path: PathBuf,
        width: u32,
        height: u32,
        resolution_m: f32,
        width_m: f32,
        height_m: f32,
        expected: String,
    },

    /// The image exists but cannot be opened or decoded as PGM/PNG.
    #[error("map image {path} cannot be decoded (expected an 8-bit PGM or PNG): {reason}")]
    ImageUnreadable { path: PathBuf, reason: String },

    /// The loaded map has not a single free cell: nothing to drive or localize in.
    #[error("map {path} has no free cell; expected some free space (check `negate` and the thresholds)")]
    NoFreeSpace { path: PathBuf },

    /// Eroding free space by the robot radius left nothing.
    #[error(
        "no traversable space: no free cell is farther than the robot radius {robot_radius_m} m from every non-free cell"
    )]
    NoTraversableSpace { robot_radius_m: f32 },

    /// Writing a map file (or its temporary sibling) failed; files already there are untouched.
    #[error("cannot write {path}: {source}")]
    Write {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
}
