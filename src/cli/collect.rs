//! `apfn collect --config FILE.ron --out DIR`: PF-net's training episodes on disk, in shards,
//! resumable (a rerun continues at the first missing shard).

use crate::cli::progress::progress_bar;
use crate::compose::read_ron;
use crate::train::collect::{CollectConfig, collect};
use anyhow::Context;
use std::path::PathBuf;
use std::time::Instant;

#[derive(clap::Args, Clone, Debug, PartialEq)]
pub struct CollectArgs {
    /// Collection config (RON, a `CollectConfig`).
    #[arg(long)]
    pub config: PathBuf,
    /// Folder for the shards and `manifest.json` (created if missing).
    #[arg(long)]
    pub out: PathBuf,
}

pub fn run(args: CollectArgs) -> anyhow::Result<()> {
    let config: CollectConfig = read_ron(&args.config)?;
    let total = (config.shards * config.episodes_per_shard) as u64;
    let bar = progress_bar(total, "{bar:40} {pos}/{len} episodes, eta {eta}");
    let started = Instant::now();
    let per_shard = config.episodes_per_shard as u64;
    let manifest =
        collect(&config, &args.out, |shard, done| bar.set_position(shard as u64 * per_shard + done as u64))
            .with_context(|| format!("collecting with {}", args.config.display()))?;
    bar.finish_and_clear();
    println!(
        "{} shards of {} episodes in {} ({:.1} s); train on them with `data: Some(\"{}\")`",
        manifest.shards.len(),
        config.episodes_per_shard,
        args.out.display(),
        started.elapsed().as_secs_f64(),
        args.out.display()
    );
    Ok(())
}
