//! Training logs as CSV, one row per logged step: read back on `--resume`, rewritten atomically.

use crate::world::map::write_atomically;
use anyhow::Context;
use serde::Serialize;
use serde::de::DeserializeOwned;
use std::path::Path;

/// The rows of `path`, or none when it does not exist yet.
pub fn read_log<Row: DeserializeOwned>(path: &Path) -> anyhow::Result<Vec<Row>> {
    if !path.exists() {
        return Ok(vec![]);
    }
    let mut reader = csv::Reader::from_path(path).with_context(|| format!("reading {}", path.display()))?;
    reader
        .deserialize()
        .collect::<Result<_, _>>()
        .with_context(|| format!("{}: not a training log", path.display()))
}

/// Writes every row to `path` (temporary file + rename).
pub fn write_log<Row: Serialize>(path: &Path, rows: &[Row]) -> anyhow::Result<()> {
    let mut writer = csv::Writer::from_writer(vec![]);
    for row in rows {
        writer.serialize(row)?;
    }
    write_atomically(path, &writer.into_inner()?)?;
    Ok(())
}
