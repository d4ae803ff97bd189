//! `apfn sac info | bench`: the agent's network sizes and the speed of one SAC update, printed
//! as one JSON object (the fields of the JAX peer's, for side-by-side runs).

use crate::cli::pfnet::{median, peak_rss_mb, round, time};
use crate::cli::set_threads;
use crate::nn::sac::{
    ACTION_LEN, Observations, SacHyper, SacLearner, SacNetConfig, SacNetworks, Transitions,
};
use rand::{Rng, SeedableRng};
use rand_distr::StandardNormal;
use rand_pcg::Pcg64Mcg;

#[derive(clap::Subcommand, Clone, Debug, PartialEq)]
pub enum SacCommand {
    /// Parameter counts of the encoders, critics and actor.
    Info {
        /// `paper` or `compact`.
        #[arg(long, default_value = "compact")]
        config: String,
    },
    /// Time one SAC update (critics, actor, entropy coefficient, Polyak) on random inputs.
    Bench {
        /// `paper` or `compact`.
        #[arg(long, default_value = "compact")]
        config: String,
        #[arg(long, default_value_t = 256)]
        batch: usize,
        /// Timed repetitions (after two untimed ones); the median is reported.
        #[arg(long, default_value_t = 20)]
        reps: usize,
        /// Worker threads (default: all cores).
        #[arg(long)]
        threads: Option<usize>,
    },
}

pub fn run(command: SacCommand) -> anyhow::Result<()> {
    match command {
        SacCommand::Info { config } => {
            let nets = SacNetworks::zeros(&named(&config)?);
            let critics = nets.critic_len - nets.encoder_len;
            let json = serde_json::json!({
                "config": config,
                "encoders": nets.encoder_len,
                "critics": critics,
                "actor": nets.params.len() - nets.critic_len,
                "params": nets.params.len(),
                "policy_file_mb": round(nets.params.len() as f64 * 4.0 / 1e6),
            });
            println!("{json}");
            Ok(())
        }
        SacCommand::Bench { config, batch, reps, threads } => bench(&config, batch, reps, threads),
    }
}

fn named(name: &str) -> anyhow::Result<SacNetConfig> {
    match name {
        "paper" => Ok(SacNetConfig::paper()),
        "compact" => Ok(SacNetConfig::compact()),
        other => anyhow::bail!("--config: expected `paper` or `compact`, found `{other}`"),
    }
}

fn bench(config: &str, n: usize, reps: usize, threads: Option<usize>) -> anyhow::Result<()> {
    set_threads(threads)?;
    anyhow::ensure!((1..=65_536).contains(&n), "--batch: expected 1 to 65,536 transitions, found {n}");
    anyhow::ensure!(reps >= 1, "--reps: expected at least 1");
    let c = named(config)?;
    let mut learner = SacLearner::new(SacNetworks::new(&c, 0), SacHyper::default());
    let mut rng = Pcg64Mcg::seed_from_u64(1);
    let mut uniform = |len: usize, lo: f32| (0..len).map(|_| rng.random_range(lo..1.0)).collect::<Vec<f32>>();
    let (bl, gl) = (c.belief_channels * c.belief_cells * c.belief_cells, c.grid_cells * c.grid_cells);
    let images = [uniform(n * bl, 0.0), uniform(n * gl, 0.0), uniform(n * bl, 0.0), uniform(n * gl, 0.0)];
    let states = [uniform(n * c.state_len(), 0.0), uniform(n * c.state_len(), 0.0)];
    let (actions, rewards, dones) = (uniform(n * ACTION_LEN, -1.0), uniform(n, -1.0), vec![0.0; n]);
    let noise: Vec<f32> = (0..2 * n * ACTION_LEN).map(|_| rng.sample(StandardNormal)).collect();
    let obs =
        |i: usize| Observations { n, belief: &images[2 * i], grid: &images[2 * i + 1], state: &states[i] };
    let batch =
        Transitions { obs: obs(0), actions: &actions, rewards: &rewards, dones: &dones, next_obs: obs(1) };
    let timings = time(reps, || {
        learner.update(&batch, &noise);
    });
    let json = serde_json::json!({
        "config": config,
        "shared_encoder": true,
        "batch": n,
        "params": learner.nets.params.len(),
        "ms_per_update": round(median(timings.clone()) * 1e3),
        "min_ms": round(timings.iter().copied().fold(f64::INFINITY, f64::min) * 1e3),
        "threads": rayon::current_num_threads(),
        "peak_rss_mb": peak_rss_mb(),
    });
    println!("{json}");
    Ok(())
}
