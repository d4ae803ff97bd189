//! `apfn fuzz [--target NAME] [--inputs N] [--seed S]`: mutates the valid input files of every
//! loader (or one) and loads each input as the CLI does; prints per target how many inputs
//! loaded, failed cleanly, panicked, were slow or hung. Fails if any panicked or hung.

use crate::cli::count;
use crate::fuzz::{FuzzOptions, HANG_FACTOR, TARGETS, Target, TargetReport, fuzz_target, target};
use rayon::prelude::*;
use std::path::PathBuf;
use std::time::{Duration, Instant};

#[derive(clap::Args, Clone, Debug, PartialEq)]
pub struct FuzzArgs {
    /// Fuzz only these targets (repeatable); default: all of them.
    #[arg(long = "target", value_name = "NAME")]
    pub targets: Vec<String>,
    /// Inputs per target.
    #[arg(long, default_value_t = 100_000)]
    pub inputs: u64,
    /// Seed of the mutations: the same seed gives the same inputs.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Milliseconds an input may take before it counts as slow; it counts as a hang after 60 times as long (CPU time of the loading thread on Linux).
    #[arg(long, default_value_t = 1_000)]
    pub budget_ms: u64,
    /// The repository, whose `scenes/` and `systems/` hold the valid files to mutate.
    #[arg(long, default_value = ".")]
    pub root: PathBuf,
    /// Folder to save panicking, slow and hanging inputs in (one folder each, with the message).
    #[arg(long, default_value = "fuzz_findings")]
    pub findings: PathBuf,
}

pub fn run(args: FuzzArgs) -> anyhow::Result<()> {
    let chosen = chosen_targets(&args.targets)?;
    let options = FuzzOptions {
        inputs: args.inputs,
        seed: args.seed,
        budget: Duration::from_millis(args.budget_ms),
        root: args.root.clone(),
        findings: Some(args.findings.clone()),
    };
    println!(
        "fuzzing {} with {} each (seed {}, slow after {} ms, hang after {} ms)",
        chosen.iter().map(|t| t.name).collect::<Vec<_>>().join(", "),
        count(args.inputs, "input"),
        args.seed,
        args.budget_ms,
        args.budget_ms * u64::from(HANG_FACTOR)
    );
    let started = Instant::now();
    let reports = chosen.par_iter().map(|t| fuzz_target(t, &options)).collect::<Result<Vec<_>, _>>()?;
    print!("{}", table(&reports));
    for report in &reports {
        for finding in &report.findings {
            println!("{}: {finding}", report.target);
        }
    }
    println!("wall-clock {:.1} s", started.elapsed().as_secs_f64());
    let (panics, hangs): (u64, u64) =
        (reports.iter().map(|r| r.panics).sum(), reports.iter().map(|r| r.hangs).sum());
    anyhow::ensure!(
        panics + hangs == 0,
        "{} and {} found; inputs saved under {}",
        count(panics, "panic"),
        count(hangs, "hang"),
        args.findings.display()
    );
    Ok(())
}

/// The targets named on the command line, or all.
fn chosen_targets(names: &[String]) -> anyhow::Result<Vec<&'static Target>> {
    if names.is_empty() {
        return Ok(TARGETS.iter().collect());
    }
    names
        .iter()
        .map(|name| {
            target(name).ok_or_else(|| {
                let known: Vec<_> = TARGETS.iter().map(|t| t.name).collect();
                anyhow::anyhow!("--target {name}: unknown; expected one of {}", known.join(", "))
            })
        })
        .collect()
}

/// The per-target counts as a Markdown table.
pub fn table(reports: &[TargetReport]) -> String {
    let mut out = String::from(
        "| target | inputs | ok | clean errors | panics | slow | hangs | slowest | wall |\n|---|---:|---:|---:|---:|---:|---:|---:|---:|\n",
    );
    for r in reports {
        out += &format!(
            "| {} | {} | {} | {} | {} | {} | {} | {:.0} ms | {:.0} s |\n",
            r.target,
            r.inputs,
            r.ok,
            r.clean_errors,
            r.panics,
            r.slow,
            r.hangs,
            r.slowest.as_secs_f64() * 1e3,
            r.wall.as_secs_f64()
        );
    }
    out
}
