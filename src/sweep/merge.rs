//! `--merge`: gathers the job result files and reduces each cell across its seeds to the mean
//! and 95 % confidence interval of every error metric, and its success rate over all its
//! episodes with a Wilson interval.

use crate::eval::ResultRow;
use crate::particles::Task;
use crate::sweep::config::LoadedSweep;
use crate::sweep::error::SweepError;
use crate::sweep::jobs::Job;
use crate::sweep::proportion::Proportion;
use crate::sweep::result::{JobResult, JobStatus, job_status};
use crate::sweep::stats::{MeanCi, mean_ci};
use serde::{Deserialize, Serialize};
use std::path::Path;

/// One row of sweep.json: a cell (schedule × task × split) across its seeds.
#[derive(Serialize, Deserialize, Clone, Debug, PartialEq)]
pub struct SweepRow {
    /// The schedule file's stem (ablations of one localizer × policy differ only here).
    pub schedule: String,
    pub localizer: String,
    pub policy: String,
    pub task: Task,
    pub split: String,
    pub map: String,
    pub particles: usize,
    /// Episodes per seed.
    pub episodes: usize,
    /// Seeds merged, in job order; `n` is their count.
    pub seeds: Vec<u64>,
    pub n: usize,
    pub mean_pos_err_m: MeanCi,
    pub rmse_pos_m: MeanCi,
    pub final_pos_err_m: MeanCi,
    pub mean_orient_err_rad: MeanCi,
    pub final_orient_err_rad: MeanCi,
    /// Successful episodes pooled over the seeds, with their Wilson interval.
    pub success: Proportion,
    /// Summed wall-clock seconds of the cell's jobs.
    pub wall_s: f64,
}

/// Reads every job's result. Missing or stale jobs are an error naming them, unless
/// `allow_partial`, which merges what is there (and fails only if nothing is).
pub fn collect(
    sweep: &LoadedSweep,
    out: &Path,
    jobs: &[Job],
    allow_partial: bool,
) -> Result<Vec<JobResult>, SweepError> {
    let mut results = Vec::new();
    let mut missing = Vec::new();
    for job in jobs {
        match job_status(sweep, out, job)? {
            JobStatus::Done(result) => results.push(*result),
            JobStatus::Missing => missing.push(job.name.clone()),
            JobStatus::Stale => missing.push(format!("{} (stale: its inputs changed)", job.name)),
        }
    }
    if !missing.is_empty() && (!allow_partial || results.is_empty()) {
        return Err(SweepError::MissingJobs { out: out.to_owned(), total: jobs.len(), missing });
    }
    Ok(results)
}

/// Groups results by (schedule, localizer, policy, task, split), in job order, and reduces each
/// group across seeds.
pub fn merge(results: &[JobResult]) -> Vec<SweepRow> {
    let key = |r: &JobResult| {
        (r.schedule.clone(), r.row.localizer.clone(), r.row.policy.clone(), r.row.task, r.row.split.clone())
    };
    let mut groups: Vec<(_, Vec<&JobResult>)> = Vec::new();
    for r in results {
        match groups.iter_mut().find(|(k, _)| *k == key(r)) {
            Some((_, members)) => members.push(r),
            None => groups.push((key(r), vec![r])),
        }
    }
    groups.into_iter().map(|(_, members)| reduce(&members)).collect()
}

fn reduce(members: &[&JobResult]) -> SweepRow {
    let first = &members[0].row;
    let stat = |metric: fn(&ResultRow) -> f32| {
        let xs: Vec<f64> = members.iter().map(|m| metric(&m.row) as f64).collect();
        mean_ci(&xs).expect("a group has at least one member")
    };
    SweepRow {
        schedule: members[0].schedule.clone(),
        localizer: first.localizer.clone(),
        policy: first.policy.clone(),
        task: first.task,
        split: first.split.clone(),
        map: first.map.clone(),
        particles: first.particles,
        episodes: first.episodes,
        seeds: members.iter().map(|m| m.row.seed).collect(),
        n: members.len(),
        mean_pos_err_m: stat(|r| r.mean_pos_err_m),
        rmse_pos_m: stat(|r| r.rmse_pos_m),
        final_pos_err_m: stat(|r| r.final_pos_err_m),
        mean_orient_err_rad: stat(|r| r.mean_orient_err_rad),
        final_orient_err_rad: stat(|r| r.final_orient_err_rad),
        success: pooled_success(members),
        wall_s: members.iter().map(|m| m.wall_s).sum(),
    }
}

/// Each job's rate × its episodes, summed: the rate over every episode of the cell.
fn pooled_success(members: &[&JobResult]) -> Proportion {
    let successes =
        members.iter().map(|m| (m.row.success_rate * m.row.episodes as f32).round() as usize).sum();
    let trials = members.iter().map(|m| m.row.episodes).sum();
    Proportion::wilson(successes, trials).expect("a job runs at least 1 episode")
}

#[cfg(test)]
mod tests {
    use super::*;

    fn result(schedule: &str, seed: u64, err: f32) -> JobResult {
        JobResult {
            name: format!("{schedule}__tracking__seen__seed{seed}"),
            schedule: schedule.into(),
            fingerprint: "0".into(),
            wall_s: 1.0,
            row: ResultRow {
                localizer: "mcl".into(),
                policy: "random".into(),
                task: Task::Tracking,
                split: "seen".into(),
                map: "apartments 0..1".into(),
                particles: 300,
                episodes: 2,
                seed,
                mean_pos_err_m: err,
                rmse_pos_m: err,
                final_pos_err_m: err,
                mean_orient_err_rad: 0.1,
                final_orient_err_rad: 0.1,
                success_rate: 1.0,
            },
        }
    }

    #[test]
    fn merge_groups_seeds_and_keeps_ablations_apart() {
        let results = [
            result("random", 0, 1.0),
            result("random", 1, 2.0),
            result("random_alpha1", 0, 5.0),
            result("random", 2, 3.0),
        ];
        let rows = merge(&results);
        assert_eq!(rows.len(), 2, "same localizer and policy, different schedule files: two rows");
        assert_eq!((rows[0].schedule.as_str(), rows[0].n, &rows[0].seeds), ("random", 3, &vec![0, 1, 2]));
        assert!((rows[0].mean_pos_err_m.mean - 2.0).abs() < 1e-9);
        let ci = rows[0].mean_pos_err_m.ci95.expect("three seeds give a CI");
        assert!((ci - 4.303 / 3f64.sqrt()).abs() < 1e-6, "ci {ci}");
        let success = rows[0].success;
        assert_eq!((success.successes, success.trials), (6, 6), "pooled over 3 seeds × 2 episodes");
        assert!(
            success.low95 > 0.5 && success.high95 == 1.0,
            "6 of 6: a Wilson interval below 1: {success:?}"
        );
        assert_eq!((rows[1].n, rows[1].mean_pos_err_m.ci95), (1, None), "one seed: no interval");
        assert_eq!(rows[0].wall_s, 3.0);
    }
}
