//! `apfn train-pfnet`: PF-net's supervised pretraining as in the paper, one explicit loop:
//! batch → forward → loss → backward → Adam → log → checkpoint.
//!
//! Data: goalnav episodes simulated on seen apartments before training (validation on unseen
//! ones), deterministic for the seed. Each batch draws B episodes (a fresh permutation every
//! epoch, across maps and episodes), K particles around a perturbed true pose at the first step,
//! moved by the odometry after it (with no motion noise unless `transition` adds the filter's) and
//! no resampling; the loss is the paper's Δx² + Δy² + β·Δθ² of the weighted mean (plus, when
//! configured, the `mixture` term), averaged over B and T. Every random draw of step s comes from a stream keyed by (seed, s), so
//! `--resume` continues exactly.

use crate::compose::{LoadedScene, Pipeline, Scene, standard_registry};
use crate::nn::adam::{Adam, AdamConfig};
use crate::nn::checkpoint::Checkpoint;
use crate::nn::pfnet::{
    FeatureBank, FeatureCacheSpec, GradBuffers, LocalMapSpec, MapInput, MixtureLoss, Observation, PfNet,
    PfNetConfig, PoseLoss, ScanOnMap, StepBatch, WideView, Workspaces, depth_image,
};
use crate::params::StepParams;
use crate::particles::{MapFeatures, TransitionParams, map_view};
use crate::train::collect::load_collection;
use crate::train::episodes::{EpisodeSet, RecordedEpisode, simulate_episodes};
use crate::world::map::procedural::{ApartmentParams, Split};
use crate::world::rng::stream;
use crate::world::{Pose2, wrap_angle};
use anyhow::Context;
use rand::Rng;
use rand::seq::SliceRandom;
use rand_distr::{Distribution, Normal};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::path::Path;

/// Everything a training run needs; saved inside every checkpoint.
#[derive(Serialize, Deserialize, Clone, Debug, PartialEq)]
#[serde(default, deny_unknown_fields)]
pub struct TrainPfNetConfig {
    /// The network: `paper` or `compact`.
    pub network: String,
    /// What it observes (the paper: `grid`, the LiDAR grid); `depth` and `grid_and_depth` read
    /// the depth strips the collect schedule records when it runs the `depth` step.
    pub observation: Observation,
    /// Seen apartments to drive on (training) and unseen ones (validation).
    pub train_maps: usize,
    pub val_maps: usize,
    /// Shape of the apartments (default: the paper's size range, scan realism on).
    pub apartment: ApartmentParams,
    /// More seen apartments of other shapes mixed into the training episodes (validation stays on
    /// `apartment`'s): e.g. halls, so that a model meets open space it would otherwise only see on
    /// real maps. Default none.
    pub extra_train: Vec<ExtraTrainMaps>,
    /// Episodes simulated for training (paper: 4,000) and validation.
    pub train_episodes: usize,
    pub val_episodes: usize,
    /// Filter steps per sequence (paper: T = 25).
    pub steps: u32,
    /// Sequences per batch (paper: 8).
    pub batch: usize,
    /// Particles per sequence (paper: 30).
    pub particles: usize,
    /// Spread of the initial particles and of the perturbation of their centre (paper: 0.3 m, 30°).
    pub init_std_m: f32,
    pub init_std_deg: f32,
    /// Fraction of each sequence's particles drawn instead uniformly over a square of `wide_box_m`
    /// around the perturbed centre, with any heading (beyond the paper, whose particles all start
    /// near the truth: the filter's semi-global start asks the network to tell apart hypotheses
    /// metres away). Unlike the filter's box, walls are not excluded. Measured worse on every
    /// passive cell at 0.5 (docs/pfnet.md), so the default stays 0.
    pub wide_fraction: f32,
    pub wide_box_m: f32,
    /// Noise added to each particle's odometry between steps (paper: none, the particles keep
    /// their offsets from the truth). Beyond the paper, the filter's own noise (`transition`'s
    /// 1 cm / 5°) makes a sequence drift as a filter's particles do, so that the weights a
    /// sequence accumulates must follow particles that wander. Measured worse in procedural halls
    /// (docs/pfnet.md), so the default stays none.
    pub transition: TransitionParams,
    /// Heading weight β of the loss (paper: 0.36).
    pub heading_weight: f32,
    /// Beyond the paper: a mixture term added to the loss (`MixtureLoss`), which pays for weight
    /// on particles far from the truth where the paper's loss scores only the weighted mean.
    /// Default none (the paper's loss).
    pub mixture: Option<MixtureLoss>,
    /// Adam (the paper's table: 2.5e-3; the authors' code: 5e-5 constant, the default: measured
    /// over 1,000 steps, the larger rates stay on the loss's early plateau, docs/pfnet.md).
    pub adam: AdamConfig,
    /// When set, the learning rate falls from `adam.learning_rate` to this one along a half
    /// cosine over `train_steps` (constant when absent, as in the authors' code).
    pub final_learning_rate: Option<f32>,
    /// Gradient steps in all, and how often to validate, log and checkpoint.
    pub train_steps: u64,
    pub eval_every: u64,
    /// Root of every random stream (maps, episodes, batches, particles, initial weights).
    pub seed: u64,
    /// The schedule that drives the episodes (relative to the working directory).
    pub collect_schedule: String,
    /// A folder written by `apfn collect` to train on instead of simulating `train_episodes` on
    /// `train_maps` (validation is always simulated on unseen apartments).
    pub data: Option<String>,
    /// A PF-net checkpoint to start from instead of fresh weights (fine-tuning; Adam starts
    /// afresh), relative to the working directory. A `grid` or `depth` checkpoint may start a
    /// `grid_and_depth` run: its sensor's weights carry over and the other channel's start at
    /// zero (`PfNet::widened_to`).
    pub init: Option<String>,
    /// The particles' map features: `exact` (each local map through the map encoder, the paper)
    /// or `cached` (crops of each map's feature banks, as `pfnet_likelihood` with `features:
    /// cached` makes them). `cached` fine-tunes the observation encoder and the joint stage to
    /// the cache's features; the map encoder stays frozen at `init`'s weights, so each map's
    /// banks are built once.
    pub features: MapFeatures,
    /// The banks, with `features: cached`: orientations and pool phases, to match the
    /// `orientations` and `pool_phases` of the `pfnet_likelihood` that will read the checkpoint.
    pub cache: FeatureCacheSpec,
    /// Side of a local-map pixel, replacing the network's (paper: 0.1 m). Its 28 pixels see
    /// 2.8 m of map where the LiDAR grid spans 5 m, so in open halls the map window often holds
    /// no wall the scan shows; 0.18 m makes the two windows one (4,500 steps on from the 0.1 m
    /// model: 5 cm better on the depot, worse on the four other real maps, docs/pfnet.md). The pixel
    /// count stays, so `init`'s weights still fit. Default: the network's.
    pub local_map_cell_m: Option<f32>,
    /// Beyond the paper: the particle at its local map's centre instead of the bottom centre
    /// (`LocalMapSpec::centred`), replacing the network's layout; with `local_map_cell_m` set to
    /// the grid's cell (5 m / 28 pixels) map and scan features then meet where they show the same
    /// place. Measured from scratch, either way it trains far worse (docs/pfnet.md). Default: the
    /// network's.
    pub local_map_centred: Option<bool>,
    /// Beyond the paper: filters of each of the joint stage's locally-connected layers, where
    /// map and scan features meet, replacing the network's (8 in both); a network trained from
    /// scratch only (`init` must hold as many). 16 learned no faster over 1,500 steps
    /// (docs/pfnet.md). Default: the network's.
    pub joint_filters: Option<usize>,
    /// Beyond the paper: a second, zoomed-out view (`PfNetConfig::wide_view`): the local map
    /// again at `map_cell_m` pixels and the scan again over `grid_extent_m`, which the collect
    /// schedule's `local_grid` (or `data`'s) must record as its `wide_extent_m`. An `init`
    /// without it gains it at zero weight (`PfNet::with_wide_view`). Default: none.
    pub wide_view: Option<WideView>,
    /// Beyond the paper: the scan laid on every local map as a second input channel of its map
    /// encoder (`PfNetConfig::scan_on_map`); `features: exact` only. An `init` without it gains
    /// it at zero weight (`PfNet::with_scan_on_map`). Default: none.
    pub scan_on_map: Option<ScanOnMap>,
    /// Beyond the paper: the map encoders' first stage reads the map beyond the local map's edge
    /// (`PfNetConfig::map_context`); an `init` without it keeps its weights (no weight depends on
    /// it). Default: false.
    pub map_context: bool,
}

/// `episodes` goalnav episodes on `maps` seen apartments of shape `apartment`.
#[derive(Serialize, Deserialize, Clone, Debug, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct ExtraTrainMaps {
    pub maps: usize,
    pub episodes: usize,
    pub apartment: ApartmentParams,
}

impl Default for TrainPfNetConfig {
    fn default() -> Self {
        Self {
            network: "compact".into(),
            observation: Observation::Grid,
            train_maps: 40,
            val_maps: 10,
            apartment: ApartmentParams::paper_size(),
            extra_train: vec![],
            train_episodes: 4000,
            val_episodes: 64,
            steps: 25,
            batch: 8,
            particles: 30,
            init_std_m: 0.3,
            init_std_deg: 30.0,
            wide_fraction: 0.0,
            wide_box_m: 3.3,
            transition: TransitionParams { trans_noise_m: 0.0, rot_noise_deg: 0.0 },
            heading_weight: 0.36,
            mixture: None,
            adam: AdamConfig { learning_rate: 5e-5, ..AdamConfig::default() },
            final_learning_rate: None,
            train_steps: 10_000,
            eval_every: 250,
            seed: 0,
            collect_schedule: "systems/collect_pfnet.ron".into(),
            data: None,
            init: None,
            features: MapFeatures::Exact,
            cache: FeatureCacheSpec::default(),
            local_map_cell_m: None,
            local_map_centred: None,
            joint_filters: None,
            wide_view: None,
            scan_on_map: None,
            map_context: false,
        }
    }
}

impl TrainPfNetConfig {
    /// `Err("field: expected …")` for values no run can use.
    pub fn check(&self) -> Result<(), String> {
        let positive = [
            ("train_maps", self.train_maps),
            ("val_maps", self.val_maps),
            ("train_episodes", self.train_episodes),
            ("val_episodes", self.val_episodes),
            ("batch", self.batch),
            ("particles", self.particles),
        ];
        for (field, value) in positive {
            if value == 0 || value > 1_000_000 {
                return Err(format!("{field}: expected 1 to 1,000,000, found {value}"));
            }
        }
        for (i, extra) in self.extra_train.iter().enumerate() {
            for (field, value) in [("maps", extra.maps), ("episodes", extra.episodes)] {
                if value == 0 || value > 1_000_000 {
                    return Err(format!("extra_train[{i}].{field}: expected 1 to 1,000,000, found {value}"));
                }
            }
            extra.apartment.validate().map_err(|e| format!("extra_train[{i}].{e}"))?;
        }
        if !(1..=1000).contains(&self.steps) {
            return Err(format!("steps: expected 1 to 1,000, found {}", self.steps));
        }
        if self.train_steps == 0 || self.eval_every == 0 {
            return Err("train_steps, eval_every: expected at least 1".into());
        }
        if !(0.0..=1.0).contains(&self.wide_fraction) {
            return Err(format!("wide_fraction: expected 0 to 1, found {}", self.wide_fraction));
        }
        if !(self.wide_box_m > 0.0 && self.wide_box_m <= 100.0) {
            return Err(format!(
                "wide_box_m: expected more than 0 and at most 100 m, found {}",
                self.wide_box_m
            ));
        }
        let (std_m, std_deg) = (self.init_std_m, self.init_std_deg);
        if !((0.0..=100.0).contains(&std_m) && (0.0..=360.0).contains(&std_deg)) {
            return Err(format!(
                "init_std_m, init_std_deg: expected spreads of 0 to 100 m and 0 to 360°, found {std_m} and {std_deg}"
            ));
        }
        if !(self.heading_weight >= 0.0 && self.heading_weight.is_finite()) {
            return Err(format!("heading_weight: expected a number ≥ 0, found {}", self.heading_weight));
        }
        if let Some(mixture) = self.mixture {
            mixture.check()?;
        }
        self.transition.check().map_err(|e| format!("transition.{e}"))?;
        self.adam.check().map_err(|e| format!("adam.{e}"))?;
        if let Some(rate) = self.final_learning_rate
            && !(rate >= 0.0 && rate <= self.adam.learning_rate)
        {
            return Err(format!(
                "final_learning_rate: expected 0 to adam.learning_rate ({}), found {rate}",
                self.adam.learning_rate
            ));
        }
        if self.features == MapFeatures::Cached && self.init.is_none() {
            return Err("init: `features: cached` trains after a frozen map encoder, expected the \
                        checkpoint whose encoder it keeps"
                .into());
        }
        if !(1..=360).contains(&self.cache.orientations) {
            return Err(format!("cache.orientations: expected 1 to 360, found {}", self.cache.orientations));
        }
        if let Some(cell_m) = self.local_map_cell_m {
            LocalMapSpec::check_cell_m("local_map_cell_m", cell_m)?;
        }
        if let Some(filters) = self.joint_filters
            && !(1..=64).contains(&filters)
        {
            return Err(format!("joint_filters: expected 1 to 64, found {filters}"));
        }
        if self.wide_view.is_some_and(|view| !view.own_map_encoder) && self.features == MapFeatures::Cached {
            return Err("wide_view: the feature cache holds map encoders of one map channel, expected \
                 `own_map_encoder: true` or `features: exact`"
                .into());
        }
        if self.scan_on_map.is_some_and(|scan| !scan.own_encoder) && self.features == MapFeatures::Cached {
            return Err("scan_on_map: the map features then change with every scan, so no feature bank \
                        holds them (the filter's cache holds their first stage; training through it is \
                        not built): expected `features: exact` or `own_encoder: true`"
                .into());
        }
        let network = PfNetConfig {
            scan_on_map: self.scan_on_map,
            map_context: self.map_context,
            ..PfNetConfig::compact()
        };
        network.observing(self.observation).with_wide_view(self.wide_view).check()?;
        PfNetConfig::named(&self.network)
            .map(|_| ())
            .ok_or_else(|| format!("network: expected `paper` or `compact`, found `{}`", self.network))
    }

    /// `network`'s local map with `local_map_cell_m` and `local_map_centred` applied.
    fn local_map(&self, network: LocalMapSpec) -> LocalMapSpec {
        LocalMapSpec {
            cell_m: self.local_map_cell_m.unwrap_or(network.cell_m),
            centred: self.local_map_centred.unwrap_or(network.centred),
            ..network
        }
    }

    fn map_input(&self) -> MapInput {
        match self.features {
            MapFeatures::Exact => MapInput::LocalMaps,
            MapFeatures::Cached => MapInput::Features,
        }
    }

    /// Whether a run saved under `saved` may continue under `self`: only `train_steps` and
    /// `eval_every` may differ (to extend a finished run), and `train_steps` only while the
    /// learning rate is constant, since a cosine schedule is laid out over it.
    pub fn continues(&self, saved: &Self) -> bool {
        let steps_free = self.final_learning_rate.is_none();
        let train_steps = if steps_free { self.train_steps } else { saved.train_steps };
        Self { train_steps, eval_every: self.eval_every, ..saved.clone() } == *self
    }

    /// The learning rate of gradient step `step` (0-based).
    pub fn learning_rate_at(&self, step: u64) -> f32 {
        let start = self.adam.learning_rate;
        let Some(end) = self.final_learning_rate else { return start };
        let progress = step as f64 / self.train_steps as f64;
        let cosine = 0.5 * (1.0 + (std::f64::consts::PI * progress.min(1.0)).cos());
        (f64::from(end) + f64::from(start - end) * cosine) as f32
    }

    fn loss(&self) -> PoseLoss {
        let scale = 1.0 / (self.batch * self.steps as usize) as f32;
        PoseLoss {
            weights: [1.0, 1.0, self.heading_weight],
            wrap_heading: true,
            scale,
            mixture: self.mixture,
        }
    }
}

/// Simulates the training and validation episodes.
pub fn simulate_data(
    config: &TrainPfNetConfig,
    progress: impl Fn(&str, usize),
) -> anyhow::Result<[EpisodeSet; 2]> {
    let registry = standard_registry();
    let pipeline = Pipeline::load(Path::new(&config.collect_schedule), &registry)?;
    let simulate = |split: Split, maps: usize, count: usize, salt: u64, params: &ApartmentParams| {
        let mut scene = Scene::apartments(split, 0, maps, 4);
        scene.maps = match scene.maps {
            crate::compose::MapSource::Procedural { split, first, count, .. } => {
                crate::compose::MapSource::Procedural { split, first, count, params: params.clone() }
            }
            other => other,
        };
        scene.seed = config.seed.wrapping_add(salt);
        scene.episode.steps = config.steps;
        let loaded: LoadedScene = scene.into_loaded(Path::new("train-pfnet"))?;
        let name = if split == Split::Seen { "training" } else { "validation" };
        simulate_episodes(&loaded, pipeline.clone(), count, |done| progress(name, done))
    };
    let mut train = match &config.data {
        Some(dir) => load_collection(Path::new(dir))?,
        None => simulate(Split::Seen, config.train_maps, config.train_episodes, 0, &config.apartment)?,
    };
    for (i, extra) in config.extra_train.iter().enumerate() {
        let salt = 2 + i as u64; // 0 and 1 are the main training and validation sets
        train.extend(simulate(Split::Seen, extra.maps, extra.episodes, salt, &extra.apartment)?)?;
    }
    anyhow::ensure!(
        train.steps() == config.steps as usize,
        "data: episodes of {} steps, expected `steps` = {}",
        train.steps(),
        config.steps
    );
    let validation = simulate(Split::Unseen, config.val_maps, config.val_episodes, 1, &config.apartment)?;
    for (set, source) in [(&train, "data (or collect_schedule)"), (&validation, "collect_schedule")] {
        anyhow::ensure!(
            !config.observation.uses_depth() || set.depth_columns > 0,
            "observation: `{}` reads depth strips, but the episodes of {source} have none: \
             expected a schedule with the `depth` step",
            config.observation.name()
        );
        let wide = config.wide_view.map(|view| view.grid_extent_m);
        anyhow::ensure!(
            set.wide_extent_m == wide,
            "wide_view: expected episodes whose wide grid spans {wide:?} m, but those of {source} span \
             {:?} m: set `local_grid`'s `wide_extent_m` in {} (or the collection's schedule) to match",
            set.wide_extent_m,
            config.collect_schedule
        );
    }
    Ok([train, validation])
}

/// The feature banks of every map of `data` with `features: cached` (none with `exact`), built
/// with `model`'s map encoder; `progress` hears how many are done.
pub fn feature_banks(
    config: &TrainPfNetConfig,
    model: &PfNet,
    data: &EpisodeSet,
    progress: impl Fn(usize),
) -> Vec<FeatureBank> {
    if config.features == MapFeatures::Exact {
        return vec![];
    }
    let mut banks = Vec::with_capacity(data.maps.len());
    for map in &data.maps {
        banks.push(FeatureBank::build(model, &map_view(map), &config.cache));
        progress(banks.len());
    }
    banks
}

/// A batch's tensors, rebuilt every step into the same buffers.
#[derive(Default)]
pub struct BatchBuffers {
    obs: Vec<f32>,
    maps: Vec<f32>,
    states: Vec<[f32; 3]>,
    targets: Vec<[f32; 3]>,
}

impl BatchBuffers {
    /// Fills the buffers for `episodes` of `data` (with its maps' `banks` under `features:
    /// cached`), particles drawn from `rng`.
    pub fn fill(
        &mut self,
        config: &TrainPfNetConfig,
        model: &PfNet,
        (data, banks): (&EpisodeSet, &[FeatureBank]),
        episodes: &[usize],
        rng: &mut impl Rng,
    ) {
        let (k, t) = (config.particles, config.steps as usize);
        let grid = data.grid_cells * data.grid_cells;
        let n = episodes.len() * t;
        let per_particle = match config.features {
            MapFeatures::Exact => model.local_map_len(),
            MapFeatures::Cached => model.map_feature_len(),
        };
        self.obs.resize(n * model.obs_len(), 0.0);
        self.maps.resize(n * k * per_particle, 0.0);
        self.states.clear();
        self.targets.clear();
        let (std_m, std_rad) = (config.init_std_m, config.init_std_deg.to_radians());
        let (pos, rot) = (Normal::new(0.0, std_m).expect("σ ≥ 0"), Normal::new(0.0, std_rad).expect("σ ≥ 0"));
        let noise = |rng: &mut _| Pose2::new(pos.sample(rng), pos.sample(rng), rot.sample(rng));
        let wide = (config.wide_fraction * k as f32).round() as usize;
        let half_box = 0.5 * config.wide_box_m;
        for (b, &e) in episodes.iter().enumerate() {
            let episode: &RecordedEpisode = &data.episodes[e];
            let centre = add(episode.poses[0], noise(rng));
            let mut particles: Vec<Pose2> = (0..k)
                .map(|i| {
                    if i < wide {
                        Pose2::new(
                            centre.x + rng.random_range(-half_box..half_box),
                            centre.y + rng.random_range(-half_box..half_box),
                            rng.random_range(-std::f32::consts::PI..std::f32::consts::PI),
                        )
                    } else {
                        add(centre, noise(rng))
                    }
                })
                .collect();
            for step in 0..t {
                if step > 0 {
                    let odometry = &episode.odometry[step];
                    particles
                        .iter_mut()
                        .for_each(|p| *p = p.compose(&config.transition.noisy(odometry, rng)));
                }
                let s = b * t + step;
                let truth = episode.poses[step];
                let obs = &mut self.obs[s * model.obs_len()..(s + 1) * model.obs_len()];
                let (grid_channel, depth_channel, wide_channel) = model.config.split_observation(obs);
                for (channel, grids) in [(grid_channel, &episode.grids), (wide_channel, &episode.wide_grids)]
                {
                    if let Some(channel) = channel {
                        let grids = &grids[step * grid..(step + 1) * grid];
                        channel.iter_mut().zip(grids).for_each(|(o, &g)| *o = f32::from(g) / 255.0);
                    }
                }
                if let Some(channel) = depth_channel {
                    let columns = data.depth_columns;
                    depth_image(
                        &episode.depths[step * columns..(step + 1) * columns],
                        model.config.obs_cells,
                        channel,
                    );
                }
                let (xs, ys, yaws): (Vec<f32>, Vec<f32>, Vec<f32>) = (
                    particles.iter().map(|p| p.x).collect(),
                    particles.iter().map(|p| p.y).collect(),
                    particles.iter().map(|p| p.yaw).collect(),
                );
                let out = &mut self.maps[s * k * per_particle..(s + 1) * k * per_particle];
                let obs = &self.obs[s * model.obs_len()..(s + 1) * model.obs_len()];
                match config.features {
                    MapFeatures::Exact => {
                        model.crop_inputs(&map_view(&data.maps[episode.map]), (&xs, &ys, &yaws), obs, out)
                    }
                    MapFeatures::Cached => banks[episode.map].crop_features(&xs, &ys, &yaws, out),
                }
                // Headings relative to the truth's, so the linear mean of the loss is taken
                // where it is meaningful (the reference's linear mean breaks across ±π).
                self.states
                    .extend(particles.iter().map(|p| [p.x, p.y, truth.yaw + wrap_angle(p.yaw - truth.yaw)]));
                self.targets.push([truth.x, truth.y, truth.yaw]);
            }
        }
    }

    pub fn batch(&self, config: &TrainPfNetConfig) -> StepBatch<'_> {
        StepBatch {
            obs: &self.obs,
            maps: &self.maps,
            states: &self.states,
            targets: &self.targets,
            k: config.particles,
            sequence: config.steps as usize,
            input: config.map_input(),
        }
    }
}

fn add(p: Pose2, noise: Pose2) -> Pose2 {
    Pose2::new(p.x + noise.x, p.y + noise.y, wrap_angle(p.yaw + noise.yaw))
}

/// The episodes of training step `step`: a fresh permutation of all episodes every epoch.
pub fn batch_episodes(config: &TrainPfNetConfig, episodes: usize, step: u64) -> Vec<usize> {
    let per_epoch = (episodes / config.batch).max(1) as u64;
    let (epoch, within) = (step / per_epoch, (step % per_epoch) as usize);
    let mut order: Vec<usize> = (0..episodes).collect();
    order.shuffle(&mut stream(&[config.seed, 0xE90C, epoch]));
    (0..config.batch).map(|i| order[(within * config.batch + i) % episodes]).collect()
}

/// Mean validation loss over the validation episodes (fixed particle draws).
pub fn validation_loss(
    config: &TrainPfNetConfig,
    model: &PfNet,
    (data, banks): (&EpisodeSet, &[FeatureBank]),
    buffers: &mut BatchBuffers,
    pool: &Workspaces,
) -> f64 {
    let all: Vec<usize> = (0..data.episodes.len()).collect();
    let mut total = 0.0;
    for (i, chunk) in all.chunks(config.batch).enumerate() {
        buffers.fill(config, model, (data, banks), chunk, &mut stream(&[config.seed, 0x7A1, i as u64]));
        total += model.batch_loss(&buffers.batch(config), &config.loss(), pool) * chunk.len() as f64;
    }
    total / data.episodes.len() as f64
}

/// The resumable state of a run.
pub struct TrainState {
    pub model: PfNet,
    pub adam: Adam,
    /// Gradient steps done.
    pub step: u64,
    pub best_val_loss: f64,
}

const ADAM_M: &str = "adam.m/";
const ADAM_V: &str = "adam.v/";

impl TrainState {
    /// Fresh weights from the seed, or `config.init`'s (which must be of `config.network`).
    pub fn new(config: &TrainPfNetConfig) -> anyhow::Result<Self> {
        let mut network = PfNetConfig::named(&config.network).expect("checked").observing(config.observation);
        network.local_map = config.local_map(network.local_map);
        network.joint_filters = config.joint_filters.unwrap_or(network.joint_filters);
        let network = PfNetConfig {
            scan_on_map: config.scan_on_map,
            map_context: config.map_context,
            ..network.with_wide_view(config.wide_view)
        };
        let model = match &config.init {
            None => PfNet::new(network, config.seed).map_err(anyhow::Error::msg)?,
            Some(path) => {
                let model = PfNet::load(Path::new(path)).with_context(|| format!("init: {path}"))?;
                let mut model =
                    model.widened_to(config.observation).map_err(|e| anyhow::anyhow!("init: {path}: {e}"))?;
                // A pixel's size and the particle's place are in no weight: the same filters
                // read another window.
                model.config.local_map = config.local_map(model.config.local_map);
                if let Some(view) = config.wide_view {
                    model = model.with_wide_view(view).map_err(|e| anyhow::anyhow!("init: {path}: {e}"))?;
                }
                if let Some(scan) = config.scan_on_map {
                    model = model.with_scan_on_map(scan).map_err(|e| anyhow::anyhow!("init: {path}: {e}"))?;
                }
                model = model
                    .with_map_context(config.map_context)
                    .map_err(|e| anyhow::anyhow!("init: {path}: {e}"))?;
                anyhow::ensure!(
                    model.config == network,
                    "init: {path} holds another network than `network: {}` observing `{}`",
                    config.network,
                    config.observation.name()
                );
                model
            }
        };
        let adam = Adam::new(config.adam.clone(), model.params.len());
        Ok(Self { model, adam, step: 0, best_val_loss: f64::INFINITY })
    }

    /// Weights, Adam's moments and step, the run's config and progress.
    pub fn to_checkpoint(&self, config: &TrainPfNetConfig) -> Checkpoint {
        let mut metadata = BTreeMap::new();
        metadata.insert("train_config".into(), ron::to_string(config).expect("a config serialises"));
        metadata.insert("step".into(), self.step.to_string());
        metadata.insert("adam_step".into(), self.adam.step.to_string());
        metadata.insert("best_val_loss".into(), format!("{:e}", self.best_val_loss));
        let mut file = self.model.to_checkpoint(metadata);
        file.push_buffer(&self.model.params, &self.adam.m, ADAM_M);
        file.push_buffer(&self.model.params, &self.adam.v, ADAM_V);
        file
    }

    pub fn from_checkpoint(file: &Checkpoint, config: &TrainPfNetConfig) -> anyhow::Result<Self> {
        let model = PfNet::from_checkpoint(file)?;
        let mut adam = Adam::new(config.adam.clone(), model.params.len());
        file.read_buffer(&model.params, &mut adam.m, ADAM_M)?;
        file.read_buffer(&model.params, &mut adam.v, ADAM_V)?;
        adam.step = metadata_number(file, "adam_step")?;
        let step = metadata_number(file, "step")?;
        let best_val_loss = metadata_number(file, "best_val_loss")?;
        Ok(Self { model, adam, step, best_val_loss })
    }

    /// One gradient step on the batch of step `self.step`; returns its loss.
    pub fn train_step(
        &mut self,
        config: &TrainPfNetConfig,
        (data, banks): (&EpisodeSet, &[FeatureBank]),
        buffers: &mut BatchBuffers,
        grads: &mut GradBuffers,
        pool: &Workspaces,
    ) -> f64 {
        let episodes = batch_episodes(config, data.episodes.len(), self.step);
        buffers.fill(
            config,
            &self.model,
            (data, banks),
            &episodes,
            &mut stream(&[config.seed, 0xBA7C, self.step]),
        );
        self.adam.config.learning_rate = config.learning_rate_at(self.step);
        let loss = self.model.train_step(&buffers.batch(config), &config.loss(), &mut self.adam, grads, pool);
        self.step += 1;
        loss
    }
}

/// The training checkpoint's metadata `key`, a number, or an error naming the file and the key.
fn metadata_number<T: std::str::FromStr>(file: &Checkpoint, key: &str) -> anyhow::Result<T>
where
    T::Err: std::fmt::Display,
{
    let path = file.source.as_deref().unwrap_or(Path::new("checkpoint")).display();
    let text = file.metadata.get(key).with_context(|| format!("{path}: metadata `{key}` is missing"))?;
    text.parse().map_err(|e| anyhow::anyhow!("{path}: metadata `{key}`: `{text}` is not a number: {e}"))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The x, y and heading ranges (max − min) of particles `range` of every sequence's first step.
    fn spreads(states: &[[f32; 3]], k: usize, t: usize, range: std::ops::Range<usize>) -> [f32; 3] {
        let mut spread = [0.0f32; 3];
        for first in states.chunks(k * t).map(|sequence| &sequence[..k]) {
            for (axis, s) in spread.iter_mut().enumerate() {
                let values = first[range.clone()].iter().map(|p| p[axis]);
                let (lo, hi) = values.fold((f32::MAX, f32::MIN), |(lo, hi), v| (lo.min(v), hi.max(v)));
                *s = s.max(hi - lo);
            }
        }
        spread
    }

    #[test]
    fn wide_particles_fill_their_box_with_any_heading_and_the_rest_stay_near() {
        let config = TrainPfNetConfig {
            train_maps: 1,
            val_maps: 1,
            train_episodes: 3,
            val_episodes: 1,
            steps: 2,
            batch: 3,
            particles: 40,
            wide_fraction: 0.25,
            ..TrainPfNetConfig::default()
        };
        config.check().unwrap();
        let [data, _] = simulate_data(&config, |_, _| {}).unwrap();
        let model = TrainState::new(&config).unwrap().model;
        let mut buffers = BatchBuffers::default();
        buffers.fill(&config, &model, (&data, &[]), &[0, 1, 2], &mut stream(&[1]));
        let [wide_x, wide_y, wide_yaw] = spreads(&buffers.states, 40, 2, 0..10);
        let [near_x, near_y, near_yaw] = spreads(&buffers.states, 40, 2, 10..40);
        assert!(wide_x > 2.0 && wide_y > 2.0, "10 wide particles span most of 3.3 m: {wide_x}, {wide_y}");
        assert!(wide_x <= 3.3 && wide_y <= 3.3, "and stay in the box: {wide_x}, {wide_y}");
        assert!(wide_yaw > 3.0, "with any heading: {wide_yaw} rad");
        assert!(
            near_x < 2.0 && near_y < 2.0 && near_yaw < 3.0,
            "σ 0.3 m / 30°: {near_x}, {near_y}, {near_yaw}"
        );
        let wider = TrainPfNetConfig { wide_fraction: 1.5, ..config };
        assert_eq!(wider.check().unwrap_err(), "wide_fraction: expected 0 to 1, found 1.5");
    }

    /// Without noise a particle keeps its offset from the truth along the whole sequence (the
    /// episodes' odometry is exact); with the filter's noise the offsets drift, and the drift is
    /// drawn from the batch's stream, so one seed gives one batch.
    #[test]
    fn transition_noise_makes_the_particles_drift_from_their_offsets() {
        let config = TrainPfNetConfig {
            train_maps: 1,
            val_maps: 1,
            train_episodes: 2,
            val_episodes: 1,
            steps: 6,
            batch: 2,
            particles: 20,
            ..TrainPfNetConfig::default()
        };
        let [data, _] = simulate_data(&config, |_, _| {}).unwrap();
        let model = TrainState::new(&config).unwrap().model;
        let (k, t) = (config.particles, config.steps as usize);
        // Each particle's offset from the truth at every step of sequence 0.
        let offsets = |config: &TrainPfNetConfig, seed: u64| {
            let mut buffers = BatchBuffers::default();
            buffers.fill(config, &model, (&data, &[]), &[0, 1], &mut stream(&[seed]));
            (0..t)
                .map(|step| {
                    let [tx, ty, tyaw] = buffers.targets[step];
                    // Both move by the same exact odometry, so p ⊕ truth⁻¹ stays.
                    let truth_inverse = Pose2::new(tx, ty, tyaw).between(&Pose2::default());
                    buffers.states[step * k..(step + 1) * k]
                        .iter()
                        .map(|&[x, y, yaw]| Pose2::new(x, y, yaw).compose(&truth_inverse))
                        .collect::<Vec<_>>()
                })
                .collect::<Vec<_>>()
        };
        let drift = |offsets: &[Vec<Pose2>]| {
            let (first, last) = (&offsets[0], &offsets[t - 1]);
            first.iter().zip(last).map(|(a, b)| (a.x - b.x).hypot(a.y - b.y)).fold(0.0f32, f32::max)
        };
        let exact = offsets(&config, 3);
        assert!(drift(&exact) < 1e-4, "without noise the offsets stay: {} m", drift(&exact));
        let noisy_config = TrainPfNetConfig {
            transition: TransitionParams { trans_noise_m: 0.01, rot_noise_deg: 5.0 },
            ..config.clone()
        };
        let noisy = offsets(&noisy_config, 3);
        assert!(
            drift(&noisy) > 0.005,
            "five noisy moves shift some offset by more than 5 mm: {} m",
            drift(&noisy)
        );
        assert_eq!(noisy, offsets(&noisy_config, 3), "one seed, one batch");
        assert_ne!(noisy, offsets(&noisy_config, 4));
        let negative = TransitionParams { rot_noise_deg: f32::NAN, ..noisy_config.transition.clone() };
        let err = TrainPfNetConfig { transition: negative, ..config.clone() }.check().unwrap_err();
        assert_eq!(err, "transition.rot_noise_deg: expected a std-dev ≥ 0°");
        let endless = TransitionParams { trans_noise_m: f32::INFINITY, ..noisy_config.transition };
        let err = TrainPfNetConfig { transition: endless, ..config }.check().unwrap_err();
        assert_eq!(err, "transition.trans_noise_m: expected a std-dev ≥ 0 m");
    }

    #[test]
    fn the_layout_and_joint_options_reach_the_network() {
        let config = TrainPfNetConfig {
            local_map_cell_m: Some(0.18),
            local_map_centred: Some(true),
            joint_filters: Some(4),
            ..TrainPfNetConfig::default()
        };
        let model = TrainState::new(&config).unwrap().model;
        let local = model.config.local_map;
        assert_eq!((local.cells, local.cell_m, local.centred), (28, 0.18, true));
        assert_eq!(model.config.joint_filters, 4);
        let paper_joint = TrainState::new(&TrainPfNetConfig::default()).unwrap().model;
        assert!(model.params.len() < paper_joint.params.len(), "half the joint stage's weights");
    }

    #[test]
    fn a_training_checkpoint_with_damaged_metadata_names_the_key() {
        let config = TrainPfNetConfig::default();
        let mut file = TrainState::new(&config).unwrap().to_checkpoint(&config);
        file.metadata.insert("step".into(), "12x".into());
        let err = TrainState::from_checkpoint(&file, &config).err().expect("a damaged step").to_string();
        assert!(err.starts_with("checkpoint: metadata `step`: `12x` is not a number"), "{err}");
        file.metadata.remove("best_val_loss");
        file.metadata.insert("step".into(), "12".into());
        let err = TrainState::from_checkpoint(&file, &config).err().expect("a missing key").to_string();
        assert_eq!(err, "checkpoint: metadata `best_val_loss` is missing");
    }

    /// Values the particle draws or the loss cannot use are refused while the config loads, not
    /// by a panic in the first batch after minutes of simulating data.
    #[test]
    fn spreads_weights_and_adam_are_checked_by_name() {
        let ok = TrainPfNetConfig::default();
        assert_eq!(ok.check(), Ok(()));
        let err = |c: TrainPfNetConfig| c.check().unwrap_err();
        let spread = err(TrainPfNetConfig { init_std_m: -0.3, ..ok.clone() });
        assert!(
            spread.starts_with("init_std_m, init_std_deg: expected") && spread.ends_with("found -0.3 and 30")
        );
        assert!(
            err(TrainPfNetConfig { init_std_deg: f32::NAN, ..ok.clone() }).ends_with("found 0.3 and NaN")
        );
        assert_eq!(
            err(TrainPfNetConfig { heading_weight: f32::INFINITY, ..ok.clone() }),
            "heading_weight: expected a number ≥ 0, found inf"
        );
        let mixture = Some(MixtureLoss { weight: 0.03, std_m: 0.2, std_deg: -10.0 });
        assert!(
            err(TrainPfNetConfig { mixture, ..ok.clone() }).starts_with("mixture.std_m, mixture.std_deg")
        );
        assert_eq!(
            err(TrainPfNetConfig { joint_filters: Some(0), ..ok.clone() }),
            "joint_filters: expected 1 to 64, found 0"
        );
        let adam = AdamConfig { beta1: -0.1, ..ok.adam.clone() };
        assert_eq!(
            err(TrainPfNetConfig { adam, ..ok }),
            "adam.beta1: expected a decay rate in [0, 1), found -0.1"
        );
    }
}
