//! `apfn eval --config FILE.ron [--out DIR]`: every cell of localizer × policy × task × split,
//! cells in parallel, with a progress bar; writes results.json, results.csv and results.md.

use crate::cli::set_threads;
use crate::eval::{EvalConfig, ResultRow, cell_steps, cells, run_cell, write_results};
use indicatif::{ProgressBar, ProgressStyle};
use rayon::prelude::*;
use std::path::PathBuf;
use std::time::Instant;

#[derive(clap::Args, Clone, Debug, PartialEq)]
pub struct EvalArgs {
    /// Evaluation config (RON): schedules, tasks, maps, episodes per cell.
    #[arg(long)]
    pub config: PathBuf,
    /// Folder for the results (created if missing).
    #[arg(long, default_value = "results")]
    pub out: PathBuf,
    /// Worker threads (default: all cores); the same seed and thread count give the same table.
    #[arg(long)]
    pub threads: Option<usize>,
}

pub fn run(args: EvalArgs) -> anyhow::Result<()> {
    set_threads(args.threads)?;
    let eval = EvalConfig::load(&args.config)?;
    let cells = cells(&eval);
    let total: u64 = cells.iter().map(|c| cell_steps(&eval, c)).sum();
    let bar = ProgressBar::new(total).with_style(
        ProgressStyle::with_template("{bar:40} {pos}/{len} agent steps in {msg} cells, eta {eta}")
            .expect("static progress template"),
    );
    bar.set_message(cells.len().to_string());
    let started = Instant::now();
    let rows = cells
        .par_iter()
        .map(|cell| run_cell(&eval, cell, || bar.inc(1)).map(|outcome| outcome.row))
        .collect::<Result<Vec<ResultRow>, _>>()?;
    bar.finish_and_clear();
    write_results(&args.out, &rows)?;
    println!(
        "{} cells, {} agent steps in {:.1} s ({} threads); wrote {}/results.{{json,csv,md}}",
        rows.len(),
        total,
        started.elapsed().as_secs_f64(),
        rayon::current_num_threads(),
        args.out.display()
    );
    print!("{}", crate::eval::markdown(&rows));
    Ok(())
}
