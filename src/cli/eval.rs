//! `apfn eval --config FILE.ron [--out DIR]`: every cell of localizer × policy × task × split,
//! cells in parallel, with a progress bar; writes results.json, results.csv, results.md,
//! episodes.csv, steps.csv (the error at each step) with its figures under `curves/`, and
//! paired.md, and with `--figures N` a PNG of each cell's first N episodes under `figures/`.

use crate::cli::progress::progress_bar;
use crate::cli::{count, set_threads};
use crate::eval::{
    CellOutcome, EpisodeRow, EvalConfig, ResultRow, StepRow, cell_steps, cells, curve_figures, encode_png,
    episode_figure, figure_file_name, figure_title, run_cell, write_results,
};
use crate::world::map::write_atomically;
use anyhow::Context;
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
    /// Draw each cell's first N episodes as `<out>/figures/<localizer>_<policy>_<task>_<split>_ep<k>.png`.
    #[arg(long, default_value_t = 0)]
    pub figures: usize,
}

pub fn run(args: EvalArgs) -> anyhow::Result<()> {
    set_threads(args.threads)?;
    let eval = EvalConfig::load(&args.config)?;
    let cells = cells(&eval);
    let total: u64 = cells.iter().map(|c| cell_steps(&eval, c)).sum();
    let bar = progress_bar(total, "{bar:40} {pos}/{len} agent steps in {msg} cells, eta {eta}");
    bar.set_message(cells.len().to_string());
    let started = Instant::now();
    let outcomes = cells
        .par_iter()
        .map(|cell| {
            run_cell(&eval, cell, || bar.inc(1)).map(|outcome| keep_for_figures(outcome, args.figures))
        })
        .collect::<Result<Vec<CellOutcome>, _>>()?;
    bar.finish_and_clear();
    let rows: Vec<ResultRow> = outcomes.iter().map(|o| o.row.clone()).collect();
    let episodes: Vec<EpisodeRow> = outcomes.iter().flat_map(|o| o.episodes.iter().cloned()).collect();
    let steps: Vec<StepRow> = outcomes.iter().flat_map(|o| o.steps.iter().cloned()).collect();
    write_results(&args.out, &rows, &episodes, &steps)?;
    write_curves(&args.out.join("curves"), &steps)?;
    let figures = write_figures(&args.out.join("figures"), &outcomes)?;
    let seconds = started.elapsed().as_secs_f64();
    let robot_steps: u64 = cells
        .iter()
        .map(|c| {
            let scene = &eval.scenes[c.group];
            cell_steps(&eval, c) * (scene.maps.len() * scene.scene.robots_per_map) as u64
        })
        .sum();
    println!(
        "{}, {} ({:.0} robot-steps/s) in {:.1} s ({}); wrote {}/results.{{json,csv,md}}, episodes.csv, steps.csv and curves/",
        count(rows.len() as u64, "cell"),
        count(total, "agent step"),
        robot_steps as f64 / seconds,
        seconds,
        count(rayon::current_num_threads() as u64, "thread"),
        args.out.display()
    );
    if figures > 0 {
        println!(
            "wrote {} to {}",
            count(figures as u64, "episode figure"),
            args.out.join("figures").display()
        );
    }
    print!("{}", crate::eval::markdown(&rows));
    Ok(())
}

/// Draws each (localizer, task, split) group's error over time into `dir`.
fn write_curves(dir: &std::path::Path, steps: &[StepRow]) -> anyhow::Result<()> {
    std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    for (name, image) in curve_figures(steps)? {
        write_atomically(&dir.join(&name), &encode_png(&image)?).with_context(|| name.clone())?;
    }
    Ok(())
}

/// Keeps a cell's first `n` episode records and only the maps they ran on.
fn keep_for_figures(mut outcome: CellOutcome, n: usize) -> CellOutcome {
    outcome.records.truncate(n);
    let records = &outcome.records;
    outcome.maps.retain(|map, _| records.iter().any(|r| r.map == *map));
    outcome
}

/// Draws every kept record; returns how many figures were written.
fn write_figures(dir: &std::path::Path, outcomes: &[CellOutcome]) -> anyhow::Result<usize> {
    let jobs: Vec<_> =
        outcomes.iter().flat_map(|o| o.records.iter().enumerate().map(move |(k, r)| (o, k, r))).collect();
    if jobs.is_empty() {
        return Ok(0);
    }
    std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    jobs.par_iter().try_for_each(|(outcome, k, record)| {
        let name = figure_file_name(&outcome.row, *k);
        let map = outcome.maps.get(&record.map).with_context(|| format!("{name}: its map was not kept"))?;
        let image =
            episode_figure(map, record, &figure_title(&outcome.row, *k)).with_context(|| name.clone())?;
        write_atomically(&dir.join(&name), &encode_png(&image)?)?;
        anyhow::Ok(())
    })?;
    Ok(jobs.len())
}
