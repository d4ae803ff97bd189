//! `apfn train-pfnet --config FILE.ron --out DIR [--resume]`: PF-net's pretraining with a
//! progress bar, `train_log.csv`, `train_curves.png`, and atomic checkpoints (`last.safetensors` with the optimizer
//! state for `--resume`, `best.safetensors` with the best validation loss).

use crate::cli::progress::progress_bar;
use crate::cli::set_threads;
use crate::compose::read_ron;
use crate::nn::checkpoint::Checkpoint;
use crate::nn::pfnet::{FeatureBank, GradBuffers, Workspaces};
use crate::particles::MapFeatures;
use crate::train::curves::loss_curves_png;
use crate::train::log::{read_log, write_log};
use crate::train::pfnet::{
    BatchBuffers, TrainPfNetConfig, TrainState, feature_banks, simulate_data, validation_loss,
};
use crate::world::map::write_atomically;
use anyhow::Context;
use indicatif::ProgressBar;
use serde::{Deserialize, Serialize};
use std::path::PathBuf;
use std::time::Instant;

#[derive(clap::Args, Clone, Debug, PartialEq)]
pub struct TrainPfNetArgs {
    /// Training config (RON, a `TrainPfNetConfig`).
    #[arg(long)]
    pub config: PathBuf,
    /// Folder for checkpoints and the log (created if missing).
    #[arg(long)]
    pub out: PathBuf,
    /// Continue from `<out>/last.safetensors` (the config must be the one it was trained with).
    #[arg(long)]
    pub resume: bool,
    /// Worker threads (default: all cores); the same seed and thread count give the same bytes.
    #[arg(long)]
    pub threads: Option<usize>,
}

/// One line of `train_log.csv`.
#[derive(Serialize, Deserialize, Clone, Debug, PartialEq)]
pub struct LogRow {
    pub step: u64,
    /// Mean training loss over the steps since the previous row.
    pub train_loss: f64,
    pub val_loss: f64,
    /// Wall-clock seconds of the run (all its processes) when the row was written.
    pub wall_s: f64,
}

pub fn run(args: TrainPfNetArgs) -> anyhow::Result<()> {
    set_threads(args.threads)?;
    let config: TrainPfNetConfig = read_ron(&args.config)?;
    config.check().map_err(|e| anyhow::anyhow!("{}: {e}", args.config.display()))?;
    std::fs::create_dir_all(&args.out).with_context(|| format!("creating {}", args.out.display()))?;
    let (last, best, log_path) = (
        args.out.join("last.safetensors"),
        args.out.join("best.safetensors"),
        args.out.join("train_log.csv"),
    );

    let mut state = if args.resume {
        let file = Checkpoint::load(&last)?;
        let saved = file.metadata.get("train_config").map(String::as_str).unwrap_or_default();
        anyhow::ensure!(
            ron::from_str::<TrainPfNetConfig>(saved).is_ok_and(|saved| config.continues(&saved)),
            "--resume: {} was trained with another config than {} (only `train_steps`, when the \
             learning rate is constant, and `eval_every` may change)",
            last.display(),
            args.config.display()
        );
        TrainState::from_checkpoint(&file, &config)?
    } else {
        TrainState::new(&config)?
    };
    let mut rows: Vec<LogRow> = if args.resume { read_log(&log_path)? } else { vec![] };
    rows.retain(|r| r.step <= state.step);
    // A resumed run's clock continues from its last row, so `wall_s` is the run's whole cost.
    let wall_before = rows.last().map_or(0.0, |r| r.wall_s);

    let started = Instant::now();
    let sim_bar = ProgressBar::new_spinner();
    let [train, val] = simulate_data(&config, |name, done| {
        sim_bar.set_message(format!("simulating {name} episodes: {done}"))
    })?;
    sim_bar.finish_and_clear();
    println!(
        "{} training episodes on {} seen apartments, {} validation episodes on {} unseen, simulated in {:.1} s",
        train.episodes.len(),
        train.maps.len(),
        val.episodes.len(),
        val.maps.len(),
        started.elapsed().as_secs_f64()
    );

    let bank_bar = ProgressBar::new_spinner();
    let built = Instant::now();
    let banks = [&train, &val].map(|data| {
        feature_banks(&config, &state.model, data, |done| {
            bank_bar.set_message(format!("feature banks: {done} of {} maps", data.maps.len()))
        })
    });
    bank_bar.finish_and_clear();
    if config.features == MapFeatures::Cached {
        let bytes: usize = banks.iter().flatten().map(FeatureBank::memory_bytes).sum();
        println!(
            "feature banks of {} maps built in {:.1} s, {:.0} MB; the map encoder stays frozen",
            banks[0].len() + banks[1].len(),
            built.elapsed().as_secs_f64(),
            bytes as f64 / 1e6
        );
    }
    let ([train_banks, val_banks], (train, val)) = (&banks, (&train, &val));
    let pool = Workspaces::for_current_pool();
    let (mut buffers, mut grads) = (BatchBuffers::default(), GradBuffers::default());
    let bar = progress_bar(config.train_steps, "{bar:40} {pos}/{len} steps, loss {msg}, eta {eta}");
    bar.set_position(state.step);
    let mut since_log = (0.0, 0u64);
    while state.step < config.train_steps {
        let loss = state.train_step(&config, (train, train_banks), &mut buffers, &mut grads, &pool);
        anyhow::ensure!(loss.is_finite(), "training diverged at step {}: loss {loss}", state.step);
        since_log = (since_log.0 + loss, since_log.1 + 1);
        bar.set_position(state.step);
        bar.set_message(format!("{:.4}", since_log.0 / since_log.1 as f64));
        if state.step % config.eval_every == 0 || state.step == config.train_steps {
            let val_loss = validation_loss(&config, &state.model, (val, val_banks), &mut buffers, &pool);
            let train_loss = since_log.0 / since_log.1 as f64;
            rows.push(LogRow {
                step: state.step,
                train_loss,
                val_loss,
                wall_s: wall_before + started.elapsed().as_secs_f64(),
            });
            since_log = (0.0, 0);
            if val_loss < state.best_val_loss {
                state.best_val_loss = val_loss;
                state.model.save(&best)?;
            }
            state.to_checkpoint(&config).save(&last)?;
            write_log(&log_path, &rows)?;
            let points: Vec<_> = rows.iter().map(|r| (r.step, r.train_loss, r.val_loss)).collect();
            let title = format!("PF-net {} pretraining", config.network);
            write_atomically(&args.out.join("train_curves.png"), &loss_curves_png(&points, &title)?)?;
            bar.println(format!(
                "step {}: train loss {train_loss:.4}, validation loss {val_loss:.4}",
                state.step
            ));
        }
    }
    bar.finish_and_clear();
    println!(
        "trained {} steps in {:.1} s; best validation loss {:.4}; wrote {}, {} and {}",
        config.train_steps,
        started.elapsed().as_secs_f64(),
        state.best_val_loss,
        best.display(),
        last.display(),
        log_path.display()
    );
    Ok(())
}
