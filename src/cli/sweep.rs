//! `apfn sweep FILE.ron`: every job (schedule × map group × task × seed) in parallel with a
//! progress bar, skipping finished ones, then the merged mean ± 95 % CI tables. For more than one
//! machine: `--list-jobs`, `--job N` on each worker, then `--merge` (docs/cluster.md).

use crate::cli::progress::progress_bar;
use crate::cli::{count, set_threads};
use crate::sweep::{
    JobStatus, LoadedSweep, SweepConfig, collect, job_at, job_status, job_steps, jobs, list_lines, markdown,
    merge, run_job, write_job_result, write_sweep,
};
use rayon::prelude::*;
use std::path::{Path, PathBuf};
use std::time::Instant;

#[derive(clap::Args, Clone, Debug, PartialEq)]
pub struct SweepArgs {
    /// Sweep file (RON): `Sweep(eval: (…an eval config…), seeds: [..], out: "..")`.
    pub file: PathBuf,
    /// Print one `index<TAB>name` line per job, and nothing else.
    #[arg(long, conflicts_with_all = ["job", "merge"])]
    pub list_jobs: bool,
    /// Run only job N (0-based, as `--list-jobs` numbers them) and write its result file.
    #[arg(long, value_name = "N", conflicts_with = "merge")]
    pub job: Option<usize>,
    /// Combine the job result files into sweep.json, sweep.csv and sweep.md.
    #[arg(long)]
    pub merge: bool,
    /// Merge whatever jobs have finished instead of failing on missing ones.
    #[arg(long)]
    pub allow_partial: bool,
    /// Output folder (default: the sweep file's `out`, relative to that file).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Worker threads for a whole-sweep run (default: all cores); results never depend on it.
    #[arg(long)]
    pub threads: Option<usize>,
}

pub fn run(args: SweepArgs) -> anyhow::Result<()> {
    let sweep = SweepConfig::load(&args.file)?;
    let out = args.out.clone().unwrap_or_else(|| sweep.out.clone());
    if args.list_jobs {
        for line in list_lines(&jobs(&sweep)?) {
            println!("{line}");
        }
        return Ok(());
    }
    if let Some(index) = args.job {
        return run_one(&sweep, &out, index);
    }
    if !args.merge {
        set_threads(args.threads)?;
        run_all(&sweep, &out)?;
    }
    merge_all(&sweep, &out, args.allow_partial)
}

/// `--job N`: one job, skipped if its result is already there and up to date.
fn run_one(sweep: &LoadedSweep, out: &Path, index: usize) -> anyhow::Result<()> {
    let job = job_at(sweep, &jobs(sweep)?, index)?;
    if let JobStatus::Done(_) = job_status(sweep, out, &job)? {
        println!("job {index} {} is already done; skipping it", job.name);
        return Ok(());
    }
    let result = run_job(sweep, &job, || {})?;
    let path = write_job_result(out, &job, &result)?;
    println!("job {index} {} done in {:.1} s; wrote {}", job.name, result.wall_s, path.display());
    Ok(())
}

/// Every job without an up-to-date result, in parallel; each writes its file when it finishes,
/// so an interrupted sweep resumes where it stopped.
fn run_all(sweep: &LoadedSweep, out: &Path) -> anyhow::Result<()> {
    let all = jobs(sweep)?;
    let mut todo = Vec::new();
    let (mut done, mut stale) = (0, 0);
    for job in all.iter() {
        match job_status(sweep, out, job)? {
            JobStatus::Done(_) => done += 1,
            JobStatus::Stale => {
                stale += 1;
                todo.push(job);
            }
            JobStatus::Missing => todo.push(job),
        }
    }
    println!(
        "{}: {done} already done (skipped), {stale} stale (rerun: inputs changed), {} to run",
        count(all.len() as u64, "job"),
        todo.len()
    );
    let total: u64 = todo.iter().map(|job| job_steps(sweep, job)).sum();
    let bar = progress_bar(total, "{bar:40} {pos}/{len} agent steps in {msg} jobs, eta {eta}");
    bar.set_message(todo.len().to_string());
    let started = Instant::now();
    todo.par_iter().try_for_each(|job| -> anyhow::Result<()> {
        let result = run_job(sweep, job, || bar.inc(1))?;
        write_job_result(out, job, &result)?;
        Ok(())
    })?;
    bar.finish_and_clear();
    println!(
        "ran {}, {} in {:.1} s ({})",
        count(todo.len() as u64, "job"),
        count(total, "agent step"),
        started.elapsed().as_secs_f64(),
        count(rayon::current_num_threads() as u64, "thread")
    );
    Ok(())
}

fn merge_all(sweep: &LoadedSweep, out: &Path, allow_partial: bool) -> anyhow::Result<()> {
    let all = jobs(sweep)?;
    let results = collect(sweep, out, &all, allow_partial)?;
    let rows = merge(&results);
    write_sweep(out, &rows)?;
    println!(
        "merged {} of {} into {}; wrote {}/sweep.{{json,csv,md}}",
        results.len(),
        count(all.len() as u64, "job"),
        count(rows.len() as u64, "row"),
        out.display()
    );
    print!("{}", markdown(&rows));
    Ok(())
}
