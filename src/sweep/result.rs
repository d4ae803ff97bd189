//! Running one job, and its result file, `<out>/jobs/<name>.json`: the eval row, the wall-clock time, and a
//! fingerprint of everything the job depends on, so a rerun skips finished jobs but redoes
//! those whose schedule file or eval settings changed since.

use crate::eval::{MapGroup, ResultRow, run_cell};
use crate::sweep::config::LoadedSweep;
use crate::sweep::error::SweepError;
use crate::sweep::jobs::Job;
use crate::world::map::write_atomically;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};
use std::time::Instant;

#[derive(Serialize, Deserialize, Clone, Debug, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct JobResult {
    pub name: String,
    /// The schedule file's stem.
    pub schedule: String,
    /// FNV-1a (64 bit, hex) of the job's inputs; see `fingerprint`.
    pub fingerprint: String,
    /// Wall-clock seconds the job took.
    pub wall_s: f64,
    pub row: ResultRow,
}

/// Runs one job: its cell with its seed. `on_step` is called after every agent step.
pub fn run_job(sweep: &LoadedSweep, job: &Job, on_step: impl Fn()) -> Result<JobResult, SweepError> {
    let started = Instant::now();
    let eval = sweep.seeded(job.seed);
    let row = run_cell(&eval, &job.cell, on_step)?.row;
    Ok(JobResult {
        name: job.name.clone(),
        schedule: job.schedule.clone(),
        fingerprint: fingerprint(sweep, job)?,
        wall_s: started.elapsed().as_secs_f64(),
        row,
    })
}

/// What a job's result file says about it.
#[derive(Debug)]
pub enum JobStatus {
    Missing,
    /// A result exists but was computed from other inputs (the schedule or settings changed).
    Stale,
    Done(Box<JobResult>),
}

/// `<out>/jobs/<name>.json`.
pub fn job_path(out: &Path, job: &Job) -> PathBuf {
    out.join("jobs").join(format!("{}.json", job.name))
}

/// Writes a job's result atomically, so a killed job leaves either nothing or a whole file.
pub fn write_job_result(out: &Path, job: &Job, result: &JobResult) -> Result<PathBuf, SweepError> {
    let path = job_path(out, job);
    let dir = out.join("jobs");
    std::fs::create_dir_all(&dir).map_err(|source| SweepError::CreateDir { path: dir, source })?;
    let json = serde_json::to_string_pretty(result).map_err(|e| SweepError::JobFile {
        path: path.clone(),
        message: format!("cannot encode the result: {e}"),
    })?;
    write_atomically(&path, json.as_bytes())?;
    Ok(path)
}

/// Reads a job's result file, if any, and checks it belongs to this job and these inputs.
pub fn job_status(sweep: &LoadedSweep, out: &Path, job: &Job) -> Result<JobStatus, SweepError> {
    let path = job_path(out, job);
    let text = match std::fs::read_to_string(&path) {
        Ok(text) => text,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(JobStatus::Missing),
        Err(source) => return Err(SweepError::Read { path, source }),
    };
    let result: JobResult = serde_json::from_str(&text).map_err(|e| SweepError::JobFile {
        path: path.clone(),
        message: format!("not a job result ({e}); expected the JSON `apfn sweep --job` writes, or delete it"),
    })?;
    if result.name != job.name {
        return Err(SweepError::JobFile {
            path,
            message: format!("holds job `{}`, expected `{}`", result.name, job.name),
        });
    }
    Ok(if result.fingerprint == fingerprint(sweep, job)? {
        JobStatus::Done(Box::new(result))
    } else {
        JobStatus::Stale
    })
}

/// Everything a job's numbers depend on, hashed: the schedule file's text, the task, the map
/// group, the eval settings (swaps, inserts, overrides, variants and labels included) and the
/// seed. Other cells and seeds of the sweep do not enter, so adding a seed or a schedule keeps the
/// finished jobs (adding a variant reruns them: every job's hash holds all variants).
pub fn fingerprint(sweep: &LoadedSweep, job: &Job) -> Result<String, SweepError> {
    #[derive(Serialize)]
    struct Inputs<'a> {
        schedule: String,
        task: &'static str,
        maps: &'a MapGroup,
        episodes: usize,
        robots_per_map: usize,
        particles: Option<usize>,
        episode: &'a crate::episode::EpisodeParams,
        robot: &'a crate::world::RobotParams,
        swaps: &'a [(String, String, Box<ron::value::RawValue>)],
        // Left out when empty (as `variants`), so the fingerprints of sweeps without them stay
        // as they were.
        #[serde(skip_serializing_if = "<[_]>::is_empty")]
        inserts: &'a [(String, String, Box<ron::value::RawValue>)],
        overrides: &'a [(String, Box<ron::value::RawValue>)],
        #[serde(skip_serializing_if = "<[_]>::is_empty")]
        variants: &'a [(String, String, Box<ron::value::RawValue>)],
        localizer: &'a Option<String>,
        seed: u64,
    }
    let config = &sweep.eval.config;
    let schedule_path = &sweep.eval.schedules[job.cell.schedule].1.source;
    let schedule = std::fs::read_to_string(schedule_path)
        .map_err(|source| SweepError::Read { path: schedule_path.clone(), source })?;
    let inputs = Inputs {
        schedule,
        task: job.cell.task.name(),
        maps: &config.maps[job.cell.group],
        episodes: config.episodes,
        robots_per_map: config.robots_per_map,
        particles: config.particles,
        episode: &config.episode,
        robot: &config.robot,
        swaps: &config.swaps,
        inserts: &config.inserts,
        overrides: &config.overrides,
        variants: &config.variants,
        localizer: &config.localizer,
        seed: job.seed,
    };
    let bytes = serde_json::to_vec(&inputs).map_err(|e| SweepError::JobFile {
        path: schedule_path.clone(),
        message: format!("cannot fingerprint the job's inputs: {e}"),
    })?;
    Ok(format!("{:016x}", fnv1a(&bytes)))
}

/// FNV-1a, 64 bit (Fowler–Noll–Vo): stable across Rust versions, unlike `DefaultHasher`.
fn fnv1a(bytes: &[u8]) -> u64 {
    bytes.iter().fold(0xcbf2_9ce4_8422_2325, |h, &b| (h ^ b as u64).wrapping_mul(0x0000_0100_0000_01b3))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fnv1a_matches_the_reference_vectors() {
        // From the FNV reference test suite (isthe.com/chongo/tech/comp/fnv).
        assert_eq!(fnv1a(b""), 0xcbf2_9ce4_8422_2325);
        assert_eq!(fnv1a(b"a"), 0xaf63_dc4c_8601_ec8c);
        assert_eq!(fnv1a(b"foobar"), 0x8594_4171_f739_67e8);
    }
}
