//! The `apfn` command line: one file per subcommand (and `task_arg`, how `--task` parses);
//! `main.rs` only parses and dispatches.

pub mod collect;
pub mod eval;
pub mod fuzz;
pub mod landscape;
pub mod localize;
pub mod map;
pub mod pfnet;
mod progress;
pub mod record;
pub mod run;
pub mod sac;
pub mod sweep;
pub mod systems;
mod task_arg;
pub mod train_pfnet;
pub mod train_sac;

use clap::{Parser, Subcommand};

/// apfn: active robot localization — simulate, localize and evaluate on 2D maps.
#[derive(Parser, Debug)]
#[command(name = "apfn", version, about)]
pub struct Cli {
    #[command(subcommand)]
    pub command: Command,
}

#[derive(Subcommand, Debug)]
pub enum Command {
    /// Inspect, render and export maps.
    #[command(subcommand)]
    Map(map::MapCommand),
    /// Run a scene headless with a schedule of systems and record the trajectories.
    Run(run::RunArgs),
    /// Evaluate localizers × policies × tasks × maps and write the paper-style tables.
    Eval(eval::EvalArgs),
    /// Simulate a scene and write one robot's odometry + LiDAR as a JSON Lines log for replay.
    Record(record::RecordArgs),
    /// Run the particle filter on a recorded log or ROS 2 bag and a ROS map; write one estimate per scan.
    Localize(localize::LocalizeArgs),
    /// Run an eval config for many seeds as independent jobs; merge to mean ± 95 % CI tables.
    Sweep(sweep::SweepArgs),
    /// PF-net, the learned observation model: size, check against the Keras reference, speed.
    #[command(subcommand)]
    Pfnet(pfnet::PfNetCommand),
    /// Simulate PF-net's training episodes and write them to disk in shards (resumable).
    Collect(collect::CollectArgs),
    /// Train PF-net on simulated episodes (supervised, as the paper), with checkpoints and resume.
    TrainPfnet(train_pfnet::TrainPfNetArgs),
    /// The APFN agent's networks: size and the speed of one SAC update.
    #[command(subcommand)]
    Sac(sac::SacCommand),
    /// Train the APFN agent (SAC) with the filter in the loop; checkpoints, log, curves, --resume.
    TrainSac(train_sac::TrainSacArgs),
    /// List the registered systems with their parameters.
    #[command(subcommand)]
    Systems(systems::SystemsCommand),
    /// Mutate the valid input files and load each as the CLI does; count panics and hangs.
    Fuzz(fuzz::FuzzArgs),
}

/// Runs the parsed command line.
pub fn run(cli: Cli) -> anyhow::Result<()> {
    match cli.command {
        Command::Map(cmd) => map::run(cmd),
        Command::Run(args) => run::run(args),
        Command::Eval(args) => eval::run(args),
        Command::Record(args) => record::run(args),
        Command::Localize(args) => localize::run(args),
        Command::Sweep(args) => sweep::run(args),
        Command::Pfnet(cmd) => pfnet::run(cmd),
        Command::Systems(cmd) => systems::run(cmd),
        Command::TrainPfnet(args) => train_pfnet::run(args),
        Command::TrainSac(args) => train_sac::run(args),
        Command::Sac(command) => sac::run(command),
        Command::Collect(args) => collect::run(args),
        Command::Fuzz(args) => fuzz::run(args),
    }
}

/// Sizes rayon's global pool. The pool is built once per process (by the first call, or by the
/// first parallel work), so a later call, e.g. a second command run from the library, may only ask
/// for the size it already has.
pub fn set_threads(threads: Option<usize>) -> anyhow::Result<()> {
    if let Some(n) = threads {
        crate::limits::THREADS.check("--threads", n).map_err(anyhow::Error::msg)?;
        let built = rayon::ThreadPoolBuilder::new().num_threads(n).build_global().is_ok();
        let running = rayon::current_num_threads();
        anyhow::ensure!(
            built || running == n,
            "--threads {n}: this process already runs {running} worker threads, and the count is set once per process"
        );
    }
    Ok(())
}

/// "1 cell", "3 cells": a count and its noun, plural unless the count is one.
pub fn count(n: impl Into<u64>, noun: &str) -> String {
    match n.into() {
        1 => format!("1 {noun}"),
        n => format!("{n} {noun}s"),
    }
}
