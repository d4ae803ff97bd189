//! `apfn train-sac --config FILE.ron --out DIR [--resume]`: the APFN agent's training, with a
//! progress bar (return, pose loss, steps/s), `train_log.csv`, `train_curves.png`, the latest
//! policy (`policy.safetensors`, small) and the resumable state (`state.safetensors` with the
//! replay buffer beside it), all written atomically; with `snapshot_every`, a kept copy of the
//! policy every so many steps (`policy_<step>.safetensors`).

use crate::cli::progress::progress_bar;
use crate::cli::set_threads;
use crate::compose::read_ron;
use crate::train::curves::{CurveLabels, curves_png};
use crate::train::log::{read_log, write_log};
use crate::train::sac::{SacTrainer, TrainSacConfig};
use crate::world::map::write_atomically;
use anyhow::Context;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};
use std::time::Instant;

#[derive(clap::Args, Clone, Debug, PartialEq)]
pub struct TrainSacArgs {
    /// Training config (RON, a `TrainSacConfig`).
    #[arg(long)]
    pub config: PathBuf,
    /// Folder for the policy, the state, the log and the curves (created if missing).
    #[arg(long)]
    pub out: PathBuf,
    /// Continue from `<out>/state.safetensors` (the config must be the one it was trained with,
    /// but for `steps` and `snapshot_every`: raise `steps` to extend a finished run).
    #[arg(long)]
    pub resume: bool,
    /// Worker threads (default: all cores); the same seed and thread count give the same bytes.
    #[arg(long)]
    pub threads: Option<usize>,
}

/// One line of `train_log.csv`: means over the world steps since the previous line.
#[derive(Serialize, Deserialize, Clone, Debug, Default, PartialEq)]
pub struct LogRow {
    pub step: u64,
    pub transitions: u64,
    pub updates: u64,
    pub episodes: u64,
    /// Mean return of the episodes that ended.
    pub episode_return: f64,
    /// Mean squared pose error (m² + 0.36 rad², plus any bump) at those episodes' last step.
    pub final_loss: f64,
    pub critic_loss: f64,
    pub actor_loss: f64,
    pub alpha: f64,
    pub entropy: f64,
    pub q: f64,
    pub steps_per_s: f64,
    /// Wall-clock seconds of this process when the row was written.
    pub wall_s: f64,
}

pub fn run(args: TrainSacArgs) -> anyhow::Result<()> {
    set_threads(args.threads)?;
    let config: TrainSacConfig = read_ron(&args.config)?;
    std::fs::create_dir_all(&args.out).with_context(|| format!("creating {}", args.out.display()))?;
    let log_path = args.out.join("train_log.csv");
    let mut trainer = if args.resume {
        SacTrainer::resume(config, &args.config, &args.out)?
    } else {
        SacTrainer::new(config, &args.config)?
    };
    let mut rows: Vec<LogRow> = if args.resume { read_log(&log_path)? } else { vec![] };
    rows.retain(|r| r.step <= trainer.step);
    // A resumed run's clock continues from its last row, so `wall_s` is the run's whole cost.
    let wall_before = rows.last().map_or(0.0, |r| r.wall_s);
    let replay_mb = trainer.agent().replay.memory_bytes() as f64 / 1e6;
    println!(
        "training {} SAC from step {} to {}; replay buffer of {} transitions holds {replay_mb:.0} MB",
        trainer.config.network, trainer.step, trainer.config.steps, trainer.config.agent.buffer
    );

    let started = Instant::now();
    let bar = progress_bar(trainer.config.steps, "{bar:30} {pos}/{len} steps {per_sec} {msg} eta {eta}");
    bar.set_position(trainer.step);
    let mut last_log = (Instant::now(), trainer.step);
    let mut window = Window::default();
    while trainer.step < trainer.config.steps {
        trainer.step();
        window.drain(&mut trainer);
        bar.set_position(trainer.step);
        if trainer.step % trainer.config.log_every == 0 || trainer.step == trainer.config.steps {
            let row = window.row(&trainer, last_log, wall_before + started.elapsed().as_secs_f64());
            anyhow::ensure!(
                row.critic_loss.is_finite(),
                "training diverged at step {}: critic loss {}",
                row.step,
                row.critic_loss
            );
            bar.set_message(format!("return {:.2}, final loss {:.3}", row.episode_return, row.final_loss));
            rows.push(row);
            last_log = (Instant::now(), trainer.step);
            window = Window::default();
        }
        if trainer.checkpoint_due() {
            trainer.save_state(&args.out)?;
            trainer.agent().learner.nets.save(&args.out.join("policy.safetensors"))?;
            write_log(&log_path, &rows)?;
            write_curves(&args.out, &rows, &trainer)?;
        }
        if let Some(name) = trainer.snapshot_due() {
            trainer.agent().learner.nets.save(&args.out.join(name))?;
        }
    }
    bar.finish_and_clear();
    println!(
        "trained to step {} ({} transitions, {} updates) in {:.1} s; wrote {}/policy.safetensors, state.safetensors, train_log.csv",
        trainer.step,
        trainer.agent().transitions,
        trainer.agent().updates,
        started.elapsed().as_secs_f64(),
        args.out.display()
    );
    Ok(())
}

/// What the agent reported since the last log row.
#[derive(Default)]
struct Window {
    episodes: Vec<(f32, f32)>,
    stats: Vec<crate::nn::sac::UpdateStats>,
}

impl Window {
    fn drain(&mut self, trainer: &mut SacTrainer) {
        let mut agent = trainer.agent_mut();
        self.episodes.extend(agent.finished.drain(..).map(|e| (e.total, e.final_loss)));
        self.stats.append(&mut agent.stats);
    }

    fn row(&self, trainer: &SacTrainer, (since, from): (Instant, u64), wall_s: f64) -> LogRow {
        let mean = |v: &mut dyn Iterator<Item = f32>| {
            let (sum, n) = v.fold((0.0f64, 0usize), |(s, n), x| (s + f64::from(x), n + 1));
            if n == 0 { f64::NAN } else { sum / n as f64 }
        };
        let s = &self.stats;
        let agent = trainer.agent();
        LogRow {
            step: trainer.step,
            transitions: agent.transitions,
            updates: agent.updates,
            episodes: self.episodes.len() as u64,
            episode_return: mean(&mut self.episodes.iter().map(|e| e.0)),
            final_loss: mean(&mut self.episodes.iter().map(|e| e.1)),
            critic_loss: if s.is_empty() { 0.0 } else { mean(&mut s.iter().map(|u| u.critic_loss)) },
            actor_loss: mean(&mut s.iter().map(|u| u.actor_loss)),
            alpha: f64::from(agent.learner.alpha()),
            entropy: mean(&mut s.iter().map(|u| u.entropy)),
            q: mean(&mut s.iter().map(|u| u.q)),
            steps_per_s: (trainer.step - from) as f64 / since.elapsed().as_secs_f64().max(1e-9),
            wall_s,
        }
    }
}

/// `train_curves.png`: the episodes' pose loss per rewarded step and at their last step, each a
/// trailing mean over `SMOOTH` log rows (one row averages only a handful of episodes).
fn write_curves(out: &Path, rows: &[LogRow], trainer: &SacTrainer) -> anyhow::Result<()> {
    const SMOOTH: usize = 10;
    let rewarded = trainer.episode_steps().saturating_sub(1).max(1) as f64;
    let rows: Vec<&LogRow> = rows.iter().filter(|r| r.episodes > 0).collect();
    let points: Vec<_> = (0..rows.len())
        .map(|i| {
            let window = &rows[i.saturating_sub(SMOOTH - 1)..=i];
            let mean =
                |f: &dyn Fn(&LogRow) -> f64| window.iter().map(|r| f(r)).sum::<f64>() / window.len() as f64;
            (rows[i].transitions, mean(&|r| -r.episode_return / rewarded), mean(&|r| r.final_loss))
        })
        .collect();
    let labels = CurveLabels {
        x: "transitions",
        y: "pose loss, m2 + 0.36 rad2",
        series: ["per rewarded step", "at the episode's last step"],
    };
    let title = format!("APFN agent, {} SAC (trailing mean of {SMOOTH} logs)", trainer.config.network);
    write_atomically(&out.join("train_curves.png"), &curves_png(&points, &title, &labels)?)?;
    Ok(())
}
