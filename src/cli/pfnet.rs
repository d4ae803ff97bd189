//! `apfn pfnet info | verify | bench | export`: PF-net's size, its check against the Keras
//! reference and its speed (one filter step or one training step), each printed as one JSON
//! object; and a training checkpoint's network alone, the file that ships.

use crate::cli::set_threads;
use crate::nn::adam::{Adam, AdamConfig};
use crate::nn::checkpoint::{Checkpoint, Storage};
use crate::nn::pfnet::{
    FeatureBank, FeatureCacheSpec, GradBuffers, MapInput, PfNet, PfNetConfig, PoseLoss, StepBatch,
    Workspaces, verify,
};
use crate::particles::{MapFeatures, map_view};
use crate::world::map::NetworkMap;
use crate::world::map::procedural::{ApartmentParams, generate_apartment};
use anyhow::Context;
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;
use std::path::{Path, PathBuf};
use std::time::Instant;

#[derive(clap::Subcommand, Clone, Debug, PartialEq)]
pub enum PfNetCommand {
    /// Parameter counts per part and in total.
    Info {
        /// `paper`, `compact`, a checkpoint (`.safetensors`) or a RON file holding a `PfNetConfig`.
        #[arg(long, default_value = "paper")]
        config: String,
    },
    /// Compare our network with the Keras reference's outputs, loss and gradients.
    Verify {
        /// The reference folder (weights.safetensors, case.safetensors).
        #[arg(long, default_value = "../shared/reference/pfnet_oracle")]
        reference: PathBuf,
    },
    /// Time one filter step (observation encoder + K likelihoods), or with `--train` one training step.
    Bench(BenchArgs),
    /// Where, and how sharply, the network's likelihood peaks around true poses on a map, slice by
    /// slice (forward, leftward, heading), beside the likelihood field's: one JSON object per
    /// model and slice.
    Landscape(crate::cli::landscape::LandscapeArgs),
    /// Write a checkpoint's network alone (weights and architecture, no optimizer state): a
    /// training run's `last.safetensors` becomes a file to ship, a third of its size.
    Export {
        /// A PF-net checkpoint, e.g. `runs/…/last.safetensors`.
        #[arg(long)]
        checkpoint: PathBuf,
        /// Where to write the network (atomically).
        #[arg(long)]
        out: PathBuf,
        /// Store the weights as F16: half the size, each weight rounded to 11 significant bits.
        #[arg(long)]
        half: bool,
    },
}

#[derive(clap::Args, Clone, Debug, PartialEq)]
pub struct BenchArgs {
    /// Particles per filter step (with `--train`: per sequence step).
    #[arg(long, default_value_t = 3000)]
    pub particles: usize,
    /// `paper`, `compact`, a checkpoint (`.safetensors`: its architecture, fresh weights) or a RON
    /// file holding a `PfNetConfig`.
    #[arg(long, default_value = "paper")]
    pub config: String,
    /// Worker threads (default: all cores).
    #[arg(long)]
    pub threads: Option<usize>,
    /// Timed repetitions (after two untimed ones); the median is reported.
    #[arg(long, default_value_t = 10)]
    pub reps: usize,
    /// Map features per particle: `exact` (crop + map encoder, the paper) or `cached` (crop of the
    /// map's feature banks, built once on a procedural apartment before timing).
    #[arg(long, value_enum, default_value_t = MapFeatures::Exact)]
    pub features: MapFeatures,
    /// Time a training step (forward, backward, Adam) instead of a filter step.
    #[arg(long)]
    pub train: bool,
    /// Sequences per training batch.
    #[arg(long, default_value_t = 8)]
    pub batch: usize,
    /// Filter steps per training sequence.
    #[arg(long, default_value_t = 25)]
    pub steps: usize,
}

pub fn run(cmd: PfNetCommand) -> anyhow::Result<()> {
    match cmd {
        PfNetCommand::Info { config } => {
            let model = PfNet::new(load_config(&config)?, 0)
                .map_err(|e| anyhow::anyhow!("--config {config}: {e}"))?;
            println!("{}", serde_json::to_string(&model.param_counts())?);
        }
        PfNetCommand::Verify { reference } => {
            let report =
                verify(&reference).with_context(|| format!("verifying against {}", reference.display()))?;
            println!("{}", serde_json::to_string(&report)?);
        }
        PfNetCommand::Bench(args) => bench(&args)?,
        PfNetCommand::Landscape(args) => crate::cli::landscape::run(&args)?,
        PfNetCommand::Export { checkpoint, out, half } => {
            let model =
                PfNet::load(&checkpoint).with_context(|| format!("--checkpoint {}", checkpoint.display()))?;
            let storage = if half { Storage::F16 } else { Storage::F32 };
            let file = Checkpoint { storage, ..model.to_checkpoint(Default::default()) };
            file.save(&out).with_context(|| format!("--out {}", out.display()))?;
            println!("wrote {} ({} parameters, {storage:?})", out.display(), model.params.len());
        }
    }
    Ok(())
}

/// A named configuration, a checkpoint's (`.safetensors`), or a RON file.
pub fn load_config(name: &str) -> anyhow::Result<PfNetConfig> {
    if let Some(config) = PfNetConfig::named(name) {
        return Ok(config);
    }
    let path = Path::new(name);
    if path.extension().is_some_and(|ext| ext == "safetensors") {
        return Ok(PfNet::load(path).with_context(|| format!("--config {name}"))?.config);
    }
    let text = std::fs::read_to_string(path)
        .with_context(|| format!("--config {name}: expected `paper`, `compact` or a readable RON file"))?;
    let config: PfNetConfig =
        ron::from_str(&text).with_context(|| format!("{}: not a PfNetConfig", path.display()))?;
    config.check().map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
    Ok(config)
}

fn bench(args: &BenchArgs) -> anyhow::Result<()> {
    set_threads(args.threads)?;
    anyhow::ensure!(
        (1..=1_000_000).contains(&args.particles),
        "--particles: expected 1 to 1,000,000, found {}",
        args.particles
    );
    anyhow::ensure!(args.reps >= 1, "--reps: expected at least 1");
    let mut model =
        PfNet::new(load_config(&args.config)?, 0).map_err(|e| anyhow::anyhow!("--config: {e}"))?;
    let pool = Workspaces::for_current_pool();
    let mut rng = Pcg64Mcg::seed_from_u64(1);
    let mut uniform = |n: usize| (0..n).map(|_| rng.random::<f32>()).collect::<Vec<f32>>();
    let timings = if args.train {
        let steps = args.batch * args.steps;
        anyhow::ensure!(
            (1..=100_000).contains(&steps),
            "--batch × --steps: expected 1 to 100,000 filter steps"
        );
        let k = args.particles;
        let (obs, maps) = (uniform(steps * model.obs_len()), uniform(steps * k * model.local_map_len()));
        let poses = uniform(steps * (k + 1) * 3);
        let states: Vec<[f32; 3]> = poses[..steps * k * 3].chunks(3).map(|p| [p[0], p[1], p[2]]).collect();
        let targets: Vec<[f32; 3]> = poses[steps * k * 3..].chunks(3).map(|p| [p[0], p[1], p[2]]).collect();
        let batch = StepBatch {
            obs: &obs,
            maps: &maps,
            states: &states,
            targets: &targets,
            k,
            sequence: args.steps,
            input: MapInput::LocalMaps,
        };
        let loss = PoseLoss {
            weights: [1.0, 1.0, 0.36],
            wrap_heading: true,
            scale: 1.0 / steps as f32,
            mixture: None,
        };
        let mut adam = Adam::new(AdamConfig::default(), model.params.len());
        let mut grads = GradBuffers::default();
        time(args.reps, || {
            model.train_step(&batch, &loss, &mut adam, &mut grads, &pool);
        })
    } else {
        let k = args.particles;
        let owner = vec![0u32; k];
        let (mut obs_terms, mut loglik) = (vec![0.0; model.obs_term_len()], vec![0.0; k]);
        let obs = uniform(model.obs_len());
        match args.features {
            // Local maps as network input, like the Keras peer's benchmark.
            MapFeatures::Exact => {
                let maps = uniform(k * model.local_map_len());
                time(args.reps, || {
                    model.observation_terms_par(&obs, &mut obs_terms, &pool);
                    model.log_likelihoods_exact(&obs_terms, &owner, &maps, &mut loglik, &pool);
                })
            }
            MapFeatures::Cached => {
                let apartment = generate_apartment(0, &ApartmentParams::default());
                let map = NetworkMap::from_fine(&apartment, 0.1);
                let bank = FeatureBank::build(&model, &map_view(&map), &FeatureCacheSpec::default());
                let (w, h) = apartment.size_m();
                let poses = uniform(3 * k);
                let xs: Vec<f32> = poses[..k].iter().map(|u| u * w).collect();
                let ys: Vec<f32> = poses[k..2 * k].iter().map(|u| u * h).collect();
                let yaws: Vec<f32> =
                    poses[2 * k..].iter().map(|u| (u - 0.5) * std::f32::consts::TAU).collect();
                if bank.holds_first_stage() {
                    // A network laying the scan on its local maps: the first stage from the banks.
                    let mut scan_terms = vec![0.0; model.scan_term_len()];
                    let poses: Vec<[f32; 3]> = (0..k).map(|i| [xs[i], ys[i], yaws[i]]).collect();
                    let banks = [std::sync::Arc::new(bank)];
                    time(args.reps, || {
                        model.observation_terms_par(&obs, &mut obs_terms, &pool);
                        model.scan_terms_par(&obs, &mut scan_terms, &pool);
                        let terms = (&obs_terms[..], &scan_terms[..]);
                        model.log_likelihoods_banked(terms, &owner, (&poses, &banks), &mut loglik, &pool);
                    })
                } else {
                    let mut features = vec![0.0; k * model.map_feature_len()];
                    time(args.reps, || {
                        // As `pfnet_likelihood`: the observation is encoded while the crops are cut.
                        rayon::join(
                            || model.observation_terms_par(&obs, &mut obs_terms, &pool),
                            || bank.crop_features(&xs, &ys, &yaws, &mut features),
                        );
                        model.log_likelihoods_from_features(
                            &obs_terms,
                            &owner,
                            &features,
                            &mut loglik,
                            &pool,
                        );
                    })
                }
            }
        }
    };
    let ms = median(timings) * 1e3;
    let mut out = serde_json::json!({ "ms_per_step": round(ms), "peak_rss_mb": peak_rss_mb() });
    if !args.train {
        out["likelihoods_per_s"] = serde_json::json!(round(args.particles as f64 / (ms / 1e3)));
    }
    println!("{out}");
    Ok(())
}

/// Seconds per call of `f`, after two untimed calls that size every buffer.
pub(crate) fn time(reps: usize, mut f: impl FnMut()) -> Vec<f64> {
    f();
    f();
    (0..reps)
        .map(|_| {
            let started = Instant::now();
            f();
            started.elapsed().as_secs_f64()
        })
        .collect()
}

pub(crate) fn median(mut xs: Vec<f64>) -> f64 {
    xs.sort_by(f64::total_cmp);
    xs[xs.len() / 2]
}

pub(crate) fn round(x: f64) -> f64 {
    (x * 100.0).round() / 100.0
}

/// This process's peak resident memory (Linux `VmHWM`), MB; `null` where unavailable.
pub fn peak_rss_mb() -> Option<f64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kb: f64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(round(kb / 1024.0))
}
