//! PF-net as the filter's observation model: a drop-in for `mcl_likelihood_field` that adds the
//! network's log-likelihoods to the particles' log-weights, with one batched forward pass over
//! every particle of every robot in the world.

use crate::nn::pfnet::{FeatureBank, FeatureCacheSpec, MapView, PfNet, PfNetConfig, Workspaces, depth_image};
use crate::params::{StepParams, expect_param};
use crate::particles::set::{
    FilterHealth, LikelihoodStats, ObservationModel, ParticleSet, record_observation,
};
use crate::sense::{DepthStrip, LocalGrid, LocalGridParams};
use crate::world::OnMap;
use crate::world::map::NetworkMap;
use bevy::prelude::*;
use serde::{Deserialize, Serialize};
use std::collections::HashMap;
use std::path::Path;
use std::sync::{Arc, Mutex, OnceLock};

/// How a particle's map features are computed. Spelled `exact` and `cached` in RON and on the
/// command line.
#[derive(Serialize, Deserialize, clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq, Default)]
#[serde(rename_all = "snake_case")]
#[value(rename_all = "snake_case")]
pub enum MapFeatures {
    /// Crop the particle's local map, then run the map encoder on it (the paper).
    #[default]
    Exact,
    /// Crop from the map's feature banks, encoded once per map at a few orientations.
    Cached,
}

/// Which network weighs the particles and how.
#[derive(Resource, Serialize, Deserialize, Clone, Debug, PartialEq)]
#[serde(default, deny_unknown_fields)]
pub struct PfNetLikelihoodParams {
    /// A PF-net checkpoint (safetensors, as `apfn train-pfnet` writes), relative to the working
    /// directory; `None`: an untrained network of `config` with weights from `seed`, for wiring
    /// and speed tests only.
    pub checkpoint: Option<String>,
    /// `paper` or `compact`, used without a checkpoint.
    pub config: String,
    /// Seed of the untrained network's weights.
    pub seed: u64,
    /// `exact` (the paper) or `cached` (beyond the paper: see `nn::pfnet::FeatureBank`).
    pub features: MapFeatures,
    /// Orientations the cached feature banks are encoded at (2π / N apart).
    pub orientations: usize,
    /// Cached banks hold every phase of the map encoder's stride-2 pool: features every pixel
    /// instead of every second one (0.1 m, or a wide view's 0.2 m, instead of twice that), for 4×
    /// the banks' memory and build time.
    pub pool_phases: bool,
    /// Multiplies the network's log-likelihoods before they reach the weights: a temperature.
    /// The network was trained on sequences without resampling, so its likelihoods are as sharp as
    /// that loss made them; below 1 the filter trusts each scan less and keeps more hypotheses
    /// alive through resampling.
    pub likelihood_scale: f32,
    /// Beyond the paper: another scale once a robot's belief has converged. `None`: one scale.
    pub converged: Option<ConvergedScale>,
}

/// The scale of a converged belief's log-likelihoods: a sharper likelihood pulls a converged
/// belief closer to the truth, but on a broad one (semi-global and global localization) it
/// collapses the belief onto the first place that fits, so it waits for the belief to converge.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ConvergedScale {
    /// Converged: the particles' position spread before the update, √(σx² + σy²) by weight,
    /// below this, metres.
    pub spread_m: f32,
    /// Multiplies the network's log-likelihoods then, instead of `likelihood_scale`.
    pub likelihood_scale: f32,
}

impl Default for PfNetLikelihoodParams {
    fn default() -> Self {
        Self {
            checkpoint: None,
            config: "paper".into(),
            seed: 0,
            features: MapFeatures::Exact,
            orientations: FeatureCacheSpec::default().orientations,
            pool_phases: FeatureCacheSpec::default().pool_phases,
            likelihood_scale: 1.0,
            converged: None,
        }
    }
}

impl PfNetLikelihoodParams {
    /// The feature banks `features: cached` builds.
    pub fn cache_spec(&self) -> FeatureCacheSpec {
        FeatureCacheSpec { orientations: self.orientations, pool_phases: self.pool_phases }
    }

    /// The scale of `set`'s log-likelihoods: `converged`'s once its spread is below it.
    fn scale_for(&self, set: &ParticleSet) -> f32 {
        match self.converged {
            Some(converged) if set.position_spread_m() < converged.spread_m => converged.likelihood_scale,
            _ => self.likelihood_scale,
        }
    }
}

impl StepParams for PfNetLikelihoodParams {
    /// Loads the network (once per process), so a missing or broken checkpoint fails when the
    /// schedule loads, naming the file.
    fn check(&self) -> Result<(), String> {
        expect_param((1..=1024).contains(&self.orientations), "orientations", "1 to 1024")?;
        expect_param(
            self.likelihood_scale.is_finite() && self.likelihood_scale > 0.0,
            "likelihood_scale",
            "a finite number > 0",
        )?;
        if let Some(converged) = self.converged {
            let positive = |v: f32| v.is_finite() && v > 0.0;
            expect_param(positive(converged.spread_m), "converged.spread_m", "a finite spread > 0 m")?;
            expect_param(
                positive(converged.likelihood_scale),
                "converged.likelihood_scale",
                "a finite number > 0",
            )?;
        }
        let model = shared_model(self)?;
        let checkpoint = self.checkpoint.as_deref().unwrap_or("(untrained)");
        let config = &model.config;
        match self.features {
            MapFeatures::Cached if config.wide_view.is_some() && !config.wide_map_encoder() => Err(format!(
                "features: the checkpoint {checkpoint} reads its wide view through the paper's map encoder \
                 (two map channels); the feature cache holds encoders of one: expected `exact`"
            )),
            _ => Ok(()),
        }
    }
}

/// The network for `params`, loaded once per process and shared read-only by every world (eval
/// runs one world per cell in parallel; each would otherwise load its own copy).
pub fn shared_model(params: &PfNetLikelihoodParams) -> Result<Arc<PfNet>, String> {
    static MODELS: OnceLock<Mutex<HashMap<String, Arc<PfNet>>>> = OnceLock::new();
    let key = match &params.checkpoint {
        Some(path) => format!("file:{path}"),
        None => format!("untrained:{}:{}", params.config, params.seed),
    };
    let mut models = MODELS.get_or_init(Mutex::default).lock().unwrap_or_else(|p| p.into_inner());
    if let Some(model) = models.get(&key) {
        return Ok(model.clone());
    }
    let model = match &params.checkpoint {
        Some(path) => PfNet::load(Path::new(path)).map_err(|e| format!("checkpoint: {e}"))?,
        None => {
            let config = PfNetConfig::named(&params.config)
                .ok_or_else(|| format!("config: expected `paper` or `compact`, found `{}`", params.config))?;
            PfNet::new(config, params.seed).map_err(|e| format!("config: {e}"))?
        }
    };
    let model = Arc::new(model);
    models.insert(key, model.clone());
    Ok(model)
}

/// The system's buffers and caches, kept across steps (the filter path allocates nothing once warm).
#[derive(Default)]
pub struct PfNetState {
    model: Option<Arc<PfNet>>,
    pool: Option<Workspaces>,
    /// Feature banks per map entity, built on first use, dropped once no robot is on the map.
    banks: HashMap<Entity, Arc<FeatureBank>>,
    obs: Vec<f32>,
    obs_terms: Vec<f32>,
    /// With first-stage banks (a network laying the scan on its local maps): each weighed
    /// robot's scan terms and bank, and every particle's pose.
    scan_terms: Vec<f32>,
    robot_banks: Vec<Arc<FeatureBank>>,
    poses: Vec<[f32; 3]>,
    owner: Vec<u32>,
    inputs: Vec<f32>,
    loglik: Vec<f32>,
    /// Whether a robot without what the network observes was reported (once per system).
    reported_missing: bool,
}

/// The `local_grid` a network reads: a grid of its size over the window its scan is laid from
/// (the paper's 5 m when it lays none), and the wide window of a wide view.
pub fn local_grid_for(config: &PfNetConfig) -> LocalGridParams {
    let defaults = LocalGridParams::default();
    LocalGridParams {
        out_cells: config.obs_cells,
        extent_m: config.scan_on_map.map_or(defaults.extent_m, |scan| scan.grid_extent_m),
        wide_extent_m: config.wide_view.map(|view| view.grid_extent_m),
        ..defaults
    }
}

/// What of the sensing the network observes a robot lacks, if anything.
fn missing_input(model: &PfNet, grid: &LocalGrid, strip: Option<&DepthStrip>) -> Option<&'static str> {
    let observation = model.config.observation;
    if observation.uses_grid() && grid.values.len() != model.config.obs_cells.pow(2) {
        return Some("a LiDAR grid of the network's size (the `local_grid` step)");
    }
    if observation.uses_depth() && strip.is_none_or(|strip| strip.depths_m.is_empty()) {
        return Some("a depth strip (the `depth` step)");
    }
    // The scan is laid on the local map by its metres, so a grid over another window would land
    // every wall at the wrong distance.
    if let Some(scan) = model.config.scan_on_map
        && grid.extent_m != scan.grid_extent_m
    {
        return Some(
            "a LiDAR grid over the window the scan is laid from (`local_grid`'s `extent_m`, the checkpoint's `scan_on_map.grid_extent_m`)",
        );
    }
    if let Some(view) = model.config.wide_view
        && grid
            .wide
            .as_ref()
            .is_none_or(|wide| wide.extent_m != view.grid_extent_m || wide.values.len() != grid.values.len())
    {
        return Some("a wide LiDAR grid over the network's window (`local_grid`'s `wide_extent_m`)");
    }
    None
}

/// The robots `pfnet_likelihood` weighs: what they sense, the map they are on, their filter.
pub type PfNetRobots<'w, 's> = Query<
    'w,
    's,
    (
        &'static LocalGrid,
        Option<&'static DepthStrip>,
        &'static OnMap,
        &'static mut ParticleSet,
        &'static mut FilterHealth,
        &'static mut LikelihoodStats,
    ),
>;

/// Reads LocalGrid and/or DepthStrip (what the network observes), OnMap → the map's NetworkMap,
/// PfNetLikelihoodParams. Writes ParticleSet
/// weights, LikelihoodStats, FilterHealth.degeneracies.
pub fn pfnet_likelihood(
    params: Res<PfNetLikelihoodParams>,
    maps: Query<&NetworkMap>,
    mut robots: PfNetRobots,
    mut state: Local<PfNetState>,
) {
    let state = &mut *state;
    if state.model.is_none() {
        match shared_model(&params) {
            Ok(model) => state.model = Some(model),
            Err(e) => return tracing::warn!("pfnet_likelihood: {e}"),
        }
    }
    let model = state.model.clone().expect("loaded above");
    let PfNetState {
        pool, banks, obs, obs_terms, scan_terms, robot_banks, poses, owner, inputs, loglik, ..
    } = state;
    let pool = pool.get_or_insert_with(Workspaces::for_current_pool);
    // The robots the network weighs, and their maps.
    let weighed = |grid: &LocalGrid, strip: Option<&DepthStrip>, on_map: &OnMap, set: &ParticleSet| {
        let map = maps.get(on_map.0).ok()?;
        (missing_input(&model, grid, strip).is_none() && !set.is_empty()).then_some(map)
    };

    // Gather every robot's observation, then encode them while every particle's local map (or
    // map features) is cut out: one robot's observation is one task, its particles many. A
    // network laying the scan on its local maps crops its first-stage banks inside the forward
    // pass instead (a particle's first stage is 38 K values), from each particle's pose.
    let first_stage = params.features == MapFeatures::Cached && model.banks_hold_first_stage();
    let per_particle = match params.features {
        MapFeatures::Exact => model.local_map_len(),
        MapFeatures::Cached if first_stage => 0,
        MapFeatures::Cached => model.map_feature_len(),
    };
    banks.retain(|map, _| robots.iter().any(|(_, _, on_map, ..)| on_map.0 == *map));
    robot_banks.clear();
    poses.clear();
    let (mut robot_count, mut particles) = (0usize, 0usize);
    obs.clear();
    owner.clear();
    for (grid, strip, on_map, set, ..) in &robots {
        if let Some(missing) = missing_input(&model, grid, strip).filter(|_| !state.reported_missing) {
            state.reported_missing = true;
            tracing::warn!(
                "pfnet_likelihood: a robot has no {missing}, which the network observes (`{}`); \
                 its particles are left unweighed",
                model.config.observation.name()
            );
        }
        if weighed(grid, strip, on_map, set).is_some() {
            let at = obs.len();
            obs.resize(at + model.obs_len(), 0.0);
            let (grid_channel, depth_channel, wide_channel) = model.config.split_observation(&mut obs[at..]);
            if let Some(channel) = grid_channel {
                channel.copy_from_slice(&grid.values);
            }
            if let (Some(channel), Some(wide)) = (wide_channel, &grid.wide) {
                channel.copy_from_slice(&wide.values);
            }
            if let (Some(channel), Some(strip)) = (depth_channel, strip) {
                depth_image(&strip.depths_m, model.config.obs_cells, channel);
            }
            owner.extend(std::iter::repeat_n(robot_count as u32, set.len()));
            robot_count += 1;
            particles += set.len();
        }
    }
    if particles == 0 {
        return;
    }
    obs_terms.resize(robot_count * model.obs_term_len(), 0.0);
    scan_terms.resize(if first_stage { robot_count * model.scan_term_len() } else { 0 }, 0.0);
    inputs.resize(particles * per_particle, 0.0);
    rayon::join(
        || {
            model.observation_terms_par(obs, obs_terms, pool);
            if first_stage {
                model.scan_terms_par(obs, scan_terms, pool);
            }
        },
        || {
            let (mut first, mut robot_obs) = (0, obs.chunks_exact(model.obs_len()));
            for (grid, strip, on_map, set, ..) in &robots {
                let Some(map) = weighed(grid, strip, on_map, set) else { continue };
                let out = &mut inputs[first * per_particle..(first + set.len()) * per_particle];
                first += set.len();
                let obs = robot_obs.next().expect("one observation per weighed robot");
                match params.features {
                    MapFeatures::Exact => {
                        model.crop_inputs(&map_view(map), (&set.x, &set.y, &set.yaw), obs, out)
                    }
                    MapFeatures::Cached => {
                        let bank = banks.entry(on_map.0).or_insert_with(|| {
                            Arc::new(FeatureBank::build(&model, &map_view(map), &params.cache_spec()))
                        });
                        if first_stage {
                            robot_banks.push(bank.clone());
                            let pose = set.x.iter().zip(&set.y).zip(&set.yaw);
                            poses.extend(pose.map(|((&x, &y), &yaw)| [x, y, yaw]));
                        } else {
                            bank.crop_features(&set.x, &set.y, &set.yaw, out);
                        }
                    }
                }
            }
        },
    );

    // One batched forward pass for the whole world.
    loglik.resize(particles, 0.0);
    match params.features {
        MapFeatures::Exact => model.log_likelihoods_exact(obs_terms, owner, inputs, loglik, pool),
        MapFeatures::Cached if first_stage => {
            model.log_likelihoods_banked((obs_terms, scan_terms), owner, (poses, robot_banks), loglik, pool)
        }
        MapFeatures::Cached => model.log_likelihoods_from_features(obs_terms, owner, inputs, loglik, pool),
    }

    // Scatter, in the same order as the gather.
    let mut first = 0;
    for (grid, strip, on_map, mut set, mut health, mut stats) in &mut robots {
        if weighed(grid, strip, on_map, &set).is_none() {
            continue;
        }
        let loglik = &loglik[first..first + set.len()];
        first += set.len();
        let scale = params.scale_for(&set);
        let outcome = set.weigh_with(|set| {
            for (w, l) in set.log_w.iter_mut().zip(loglik) {
                *w += scale * l;
            }
            Ok(())
        });
        record_observation(ObservationModel::PfNet, outcome, &mut health, &mut stats);
    }
}

/// The engine's read-only view of a map's network layer.
pub fn map_view(map: &NetworkMap) -> MapView<'_> {
    MapView {
        occupancy: &map.occupancy,
        width: map.width,
        height: map.height,
        resolution_m: map.resolution_m,
        origin_x_m: map.origin.x,
        origin_y_m: map.origin.y,
        origin_yaw_rad: map.origin.yaw,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::nn::pfnet::{MapInput, Observation, ScanOnMap, WideView, Workspace};
    use crate::particles::{RecoveryBeforeUpdateParams, RecoveryState, recovery_before_update};
    use crate::sense::WideGrid;
    use crate::testing::tiny_room;
    use crate::world::map::TraversableMap;
    use crate::world::{Cell, FilterRng, OccupancyMap, Pose2};
    use bevy::ecs::system::{RunSystemOnce, SystemState};

    const POSES: [Pose2; 3] =
        [Pose2::new(0.5, 0.5, 0.0), Pose2::new(1.2, 0.8, 1.5), Pose2::new(1.6, 1.1, -2.5)];

    fn grid(seed: usize) -> LocalGrid {
        LocalGrid {
            cells: 56,
            extent_m: 5.0,
            values: (0..56 * 56).map(|i| ((i * 7 + seed) % 3) as f32 / 2.0).collect(),
            wide: None,
        }
    }

    /// A world with the tiny room's network map and one robot per grid, each with `POSES`.
    fn world_with_robots(grids: &[LocalGrid], features: MapFeatures) -> (World, Vec<Entity>) {
        let mut world = World::new();
        let params = PfNetLikelihoodParams { config: "compact".into(), features, ..Default::default() };
        world.insert_resource(params);
        let map = world.spawn(NetworkMap::from_fine(&tiny_room(), 0.1)).id();
        let robots = grids
            .iter()
            .map(|g| world.spawn((g.clone(), OnMap(map), ParticleSet::from_poses(&POSES))).id())
            .collect();
        (world, robots)
    }

    /// `model`'s weights for `POSES` and the observation image `obs`, without the system.
    fn expected_weights(model: &PfNet, obs: &[f32]) -> Vec<f32> {
        let map = NetworkMap::from_fine(&tiny_room(), 0.1);
        let (xs, ys, yaws) = pose_columns();
        let mut maps = vec![0.0; 3 * model.local_map_len()];
        model.crop_inputs(&map_view(&map), (&xs, &ys, &yaws), obs, &mut maps);
        // The training path: the joint stage on concatenated features, not the system's split one.
        normalised(model.forward_steps(obs, (&maps, MapInput::LocalMaps), 1, 3, &mut Workspace::default()))
    }

    /// `expected_weights` through the feature banks of `spec` (their first stage and `obs`'s scan
    /// terms for a network laying the scan on its local maps).
    fn expected_cached_weights(model: &PfNet, obs: &[f32], spec: &FeatureCacheSpec) -> Vec<f32> {
        expected_cached_weights_on(&tiny_room(), model, obs, spec)
    }

    /// `expected_cached_weights` with the particles on `room`.
    fn expected_cached_weights_on(
        room: &OccupancyMap,
        model: &PfNet,
        obs: &[f32],
        spec: &FeatureCacheSpec,
    ) -> Vec<f32> {
        let map = NetworkMap::from_fine(room, 0.1);
        let (xs, ys, yaws) = pose_columns();
        let mut features = vec![0.0; 3 * model.map_feature_len()];
        let bank = FeatureBank::build(model, &map_view(&map), spec);
        if bank.holds_first_stage() {
            let (mut ws, mut terms) = (Workspace::default(), vec![0.0; model.scan_term_len()]);
            model.scan_terms(obs, &mut terms, &mut ws);
            let poses: Vec<[f32; 3]> = POSES.iter().map(|p| [p.x, p.y, p.yaw]).collect();
            model.encode_banked((&poses, &[0; 3]), (&[Arc::new(bank)], &terms), &mut features, &mut ws);
        } else {
            bank.crop_features(&xs, &ys, &yaws, &mut features);
        }
        let features = (&features[..], MapInput::Features);
        normalised(model.forward_steps(obs, features, 1, 3, &mut Workspace::default()))
    }

    fn pose_columns() -> (Vec<f32>, Vec<f32>, Vec<f32>) {
        (
            POSES.iter().map(|p| p.x).collect(),
            POSES.iter().map(|p| p.y).collect(),
            POSES.iter().map(|p| p.yaw).collect(),
        )
    }

    fn normalised(loglik: &[f32]) -> Vec<f32> {
        let total: f32 = loglik.iter().map(|l| l.exp()).sum();
        loglik.iter().map(|l| l.exp() / total).collect()
    }

    #[test]
    fn pfnet_likelihood_weighs_every_robot_with_its_own_observation_in_one_batch() {
        let grids = [grid(0), grid(1)];
        let (mut world, robots) = world_with_robots(&grids, MapFeatures::Exact);
        world.run_system_once(pfnet_likelihood).expect("system runs");
        let model =
            shared_model(&PfNetLikelihoodParams { config: "compact".into(), ..Default::default() }).unwrap();
        for (robot, grid) in robots.iter().zip(&grids) {
            let weights = world.get::<ParticleSet>(*robot).unwrap().weights();
            let want = expected_weights(&model, &grid.values);
            for (w, e) in weights.iter().zip(&want) {
                assert!(
                    (w - e).abs() < 1e-5,
                    "batched weights {weights:?} differ from one robot alone {want:?}"
                );
            }
            let stats = world.get::<LikelihoodStats>(*robot).unwrap();
            assert_eq!((stats.model, stats.updates), (ObservationModel::PfNet, 1), "the update is booked");
        }
        let (a, b) =
            (world.get::<ParticleSet>(robots[0]).unwrap(), world.get::<ParticleSet>(robots[1]).unwrap());
        assert_ne!(a.log_w, b.log_w, "different observations must give different weights");
    }

    #[test]
    fn pfnet_likelihood_weighs_the_particles_recovery_injected_before_it() {
        let (mut world, robots) = world_with_robots(&[grid(0)], MapFeatures::Exact);
        let robot = robots[0];
        let map = world.get::<OnMap>(robot).expect("on a map").0;
        let room = tiny_room();
        let traversable = TraversableMap::build(&room, 0.1).expect("room has space");
        world.entity_mut(map).insert((room, traversable));
        world.insert_resource(RecoveryBeforeUpdateParams::default());
        // The scans have fit worse than the belief's average for a while: about half are replaced.
        let last = LikelihoodStats { mean_log_likelihood: -80.0, updates: 2, ..Default::default() };
        let state = RecoveryState { log_w: Some((-30.0, -30.7)), seen_updates: 1, ..Default::default() };
        world.entity_mut(robot).insert((last, state, FilterRng::seeded(5)));
        world.run_system_once(recovery_before_update).expect("system runs");
        world.run_system_once(pfnet_likelihood).expect("system runs");
        let set = world.get::<ParticleSet>(robot).expect("set").clone();
        let moved = (0..set.len()).filter(|&k| set.pose(k) != POSES[k]).count();
        assert!((1..set.len()).contains(&moved), "some particles replaced and some kept, got {moved}");

        // The same poses weighed from a uniform set by the network alone.
        let (mut alone, robots) = world_with_robots(&[grid(0)], MapFeatures::Exact);
        let poses: Vec<Pose2> = (0..set.len()).map(|k| set.pose(k)).collect();
        alone.entity_mut(robots[0]).insert(ParticleSet::from_poses(&poses));
        alone.run_system_once(pfnet_likelihood).expect("system runs");
        let want = alone.get::<ParticleSet>(robots[0]).expect("set").weights();
        for (w, e) in set.weights().iter().zip(&want) {
            assert!(
                (w - e).abs() < 1e-5,
                "newcomers weighed like the rest: {:?} against {want:?}",
                set.weights()
            );
        }
    }

    /// A compact network laying the 5 m scan on its local maps (through encoders of its own or
    /// not), saved in `dir`, and its checkpoint path.
    fn saved_scan_network(dir: &Path, own_encoder: bool) -> (PfNet, Option<String>) {
        let path = dir.join("scan_on_map.safetensors");
        let scan = Some(ScanOnMap { grid_extent_m: 5.0, own_encoder });
        let model = PfNet::new(PfNetConfig { scan_on_map: scan, ..PfNetConfig::compact() }, 2).unwrap();
        model.save(&path).unwrap();
        (model, Some(path.display().to_string()))
    }

    /// Each robot's own scan is laid on its particles' maps; a robot whose grid spans another
    /// window than the checkpoint's is left unweighed.
    #[test]
    fn pfnet_likelihood_lays_each_robots_own_scan_on_its_particles_maps() {
        let dir = tempfile::tempdir().unwrap();
        let (model, checkpoint) = saved_scan_network(dir.path(), false);
        let params = PfNetLikelihoodParams { checkpoint, ..Default::default() };
        let other_window = LocalGrid { extent_m: 4.0, ..grid(2) };
        let grids = [grid(0), grid(1), other_window];
        let (mut world, robots) = world_with_robots(&grids, MapFeatures::Exact);
        world.insert_resource(params);
        world.run_system_once(pfnet_likelihood).expect("system runs");
        for (robot, grid) in robots.iter().zip(&grids[..2]) {
            let weights = world.get::<ParticleSet>(*robot).unwrap().weights();
            let want = expected_weights(&model, &grid.values);
            assert!(weights.iter().zip(&want).all(|(w, e)| (w - e).abs() < 1e-5), "{weights:?} vs {want:?}");
        }
        let stats = world.get::<LikelihoodStats>(robots[2]).unwrap();
        assert_eq!(stats.updates, 0, "a 4 m grid would lay the scan's walls at the wrong distance");
    }

    /// A checkpoint laying the scan on its local maps weighs through the feature cache too: with
    /// encoders of its own for the scan the banks hold the map's features, without them its first
    /// stage's response to the map; either way each robot with its own scan, batched as alone.
    #[test]
    fn pfnet_likelihood_caches_what_of_a_scan_laid_network_the_map_alone_decides() {
        for own_encoder in [true, false] {
            let dir = tempfile::tempdir().unwrap();
            let (model, checkpoint) = saved_scan_network(dir.path(), own_encoder);
            let params =
                PfNetLikelihoodParams { checkpoint, features: MapFeatures::Cached, ..Default::default() };
            params.check().expect("the feature cache holds what the map decides");
            let grids = [grid(0), grid(1)];
            let (mut world, robots) = world_with_robots(&grids, MapFeatures::Cached);
            world.insert_resource(params.clone());
            world.run_system_once(pfnet_likelihood).expect("system runs");
            for (robot, grid) in robots.iter().zip(&grids) {
                let weights = world.get::<ParticleSet>(*robot).unwrap().weights();
                let want = expected_cached_weights(&model, &grid.values, &params.cache_spec());
                let close = weights.iter().zip(&want).all(|(w, e)| (w - e).abs() < 1e-5);
                assert!(close, "own encoder {own_encoder}: {weights:?} vs {want:?}");
            }
        }
    }

    /// Scaled by ½ the weights are ∝ √ the network's likelihoods; with a converged scale, the
    /// scale of the belief's spread (`POSES` are 0.4–0.8 m from their mean).
    #[test]
    fn pfnet_likelihood_scale_tempers_the_weights() {
        let model =
            shared_model(&PfNetLikelihoodParams { config: "compact".into(), ..Default::default() }).unwrap();
        let full = expected_weights(&model, &grid(0).values);
        let half = |spread_m: f32, likelihood_scale: f32| PfNetLikelihoodParams {
            likelihood_scale,
            converged: (spread_m > 0.0)
                .then_some(ConvergedScale { spread_m, likelihood_scale: 1.5 - likelihood_scale }),
            ..PfNetLikelihoodParams { config: "compact".into(), ..Default::default() }
        };
        // No converged scale; spread above it; spread below it.
        for params in [half(0.0, 0.5), half(0.2, 0.5), half(5.0, 1.0)] {
            let (mut world, robots) = world_with_robots(&[grid(0)], MapFeatures::Exact);
            params.check().expect("valid");
            world.insert_resource(params.clone());
            world.run_system_once(pfnet_likelihood).expect("system runs");
            let total: f32 = full.iter().map(|w| w.sqrt()).sum();
            let weights = world.get::<ParticleSet>(robots[0]).unwrap().weights();
            for (w, f) in weights.iter().zip(&full) {
                assert!(
                    (w - f.sqrt() / total).abs() < 1e-5,
                    "{params:?}: weights {weights:?} are not ∝ √{full:?}"
                );
            }
        }
        let converged = Some(ConvergedScale { spread_m: -1.0, likelihood_scale: 2.0 });
        let bad = PfNetLikelihoodParams { converged, ..half(0.0, 1.0) };
        assert!(bad.check().unwrap_err().contains("converged.spread_m"), "{:?}", bad.check());
    }

    #[test]
    fn pfnet_likelihood_reads_the_depth_strip_when_the_network_observes_it() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("grid_and_depth.safetensors");
        let model = PfNet::new(PfNetConfig::compact().observing(Observation::GridAndDepth), 4).unwrap();
        model.save(&path).unwrap();
        let mut world = World::new();
        let checkpoint = Some(path.display().to_string());
        world.insert_resource(PfNetLikelihoodParams { checkpoint, ..Default::default() });
        let map = world.spawn(NetworkMap::from_fine(&tiny_room(), 0.1)).id();
        let strip = DepthStrip { depths_m: (0..56).map(|c| 0.3 + 0.05 * c as f32).collect() };
        let robot = (grid(0), OnMap(map), ParticleSet::from_poses(&POSES));
        let seeing = world.spawn((robot.clone(), strip.clone())).id();
        let blind = world.spawn(robot).id();
        world.run_system_once(pfnet_likelihood).expect("system runs");

        let mut obs = grid(0).values;
        obs.resize(2 * 56 * 56, f32::NAN);
        depth_image(&strip.depths_m, 56, &mut obs[56 * 56..]);
        let (weights, want) =
            (world.get::<ParticleSet>(seeing).unwrap().weights(), expected_weights(&model, &obs));
        assert!(weights.iter().zip(&want).all(|(w, e)| (w - e).abs() < 1e-5), "{weights:?} vs {want:?}");
        let (weights, stats) = (
            world.get::<ParticleSet>(blind).unwrap().weights(),
            world.get::<LikelihoodStats>(blind).unwrap(),
        );
        assert!(weights.iter().all(|&w| (w - 1.0 / 3.0).abs() < 1e-6), "no strip, no update: {weights:?}");
        assert_eq!(stats.updates, 0, "nothing booked for a robot the network cannot see through");
    }

    /// A checkpoint whose local map has wider pixels is cropped at its own pixel size.
    #[test]
    fn pfnet_likelihood_crops_the_local_map_the_checkpoint_names() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("wide.safetensors");
        let mut model = PfNet::new(PfNetConfig::compact(), 4).unwrap();
        model.config.local_map.cell_m = 0.18;
        model.save(&path).unwrap();
        let mut world = World::new();
        let checkpoint = Some(path.display().to_string());
        world.insert_resource(PfNetLikelihoodParams { checkpoint, ..Default::default() });
        let map = world.spawn(NetworkMap::from_fine(&tiny_room(), 0.1)).id();
        let robot = world.spawn((grid(0), OnMap(map), ParticleSet::from_poses(&POSES))).id();
        world.run_system_once(pfnet_likelihood).expect("system runs");

        let weights = world.get::<ParticleSet>(robot).unwrap().weights();
        let want = expected_weights(&model, &grid(0).values);
        assert!(weights.iter().zip(&want).all(|(w, e)| (w - e).abs() < 1e-5), "{weights:?} vs {want:?}");
        model.config.local_map.cell_m = 0.1;
        let narrow = expected_weights(&model, &grid(0).values);
        assert!(
            weights.iter().zip(&narrow).any(|(w, n)| (w - n).abs() > 1e-4),
            "the 0.1 m crop must weigh differently: {weights:?} vs {narrow:?}"
        );
    }

    /// A network with a wide view reads the wide grid and crops both local maps; a robot whose wide
    /// grid spans another window is left unweighed, and the feature cache is refused by name.
    #[test]
    fn pfnet_likelihood_feeds_a_wide_view_both_windows() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("wide_view.safetensors");
        let view = WideView { map_cell_m: 0.2, grid_extent_m: 10.0, own_map_encoder: false };
        let model = PfNet::new(PfNetConfig::compact().with_wide_view(Some(view)), 4).unwrap();
        model.save(&path).unwrap();
        let mut world = World::new();
        let checkpoint = Some(path.display().to_string());
        world.insert_resource(PfNetLikelihoodParams { checkpoint: checkpoint.clone(), ..Default::default() });
        let map = world.spawn(NetworkMap::from_fine(&tiny_room(), 0.1)).id();
        let with_wide = |extent_m: f32| LocalGrid {
            wide: Some(WideGrid { extent_m, values: grid(5).values }),
            ..grid(0)
        };
        let robot = |g: LocalGrid| (g, OnMap(map), ParticleSet::from_poses(&POSES));
        let seeing = world.spawn(robot(with_wide(10.0))).id();
        let other_window = world.spawn(robot(with_wide(8.0))).id();
        world.run_system_once(pfnet_likelihood).expect("system runs");

        let obs = [grid(0).values, grid(5).values].concat();
        let (weights, want) =
            (world.get::<ParticleSet>(seeing).unwrap().weights(), expected_weights(&model, &obs));
        assert!(weights.iter().zip(&want).all(|(w, e)| (w - e).abs() < 1e-5), "{weights:?} vs {want:?}");
        assert_eq!(
            world.get::<LikelihoodStats>(other_window).unwrap().updates,
            0,
            "8 m is not the network's 10 m"
        );

        let cached =
            PfNetLikelihoodParams { checkpoint, features: MapFeatures::Cached, ..Default::default() };
        let err = cached.check().unwrap_err();
        assert!(
            err.starts_with("features: the checkpoint") && err.contains("wide_view.safetensors"),
            "{err}"
        );
    }

    /// A wide view read by a map encoder of its own is cached like the paper's view: the
    /// system's weights are the training path's on both encoders' bank features, the banks
    /// built as the parameters say (here with every pool phase).
    #[test]
    fn pfnet_likelihood_caches_a_wide_view_of_its_own_encoder() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("own_wide_view.safetensors");
        let view = WideView { map_cell_m: 0.2, grid_extent_m: 10.0, own_map_encoder: true };
        let model = PfNet::new(PfNetConfig::compact().with_wide_view(Some(view)), 4).unwrap();
        model.save(&path).unwrap();
        let checkpoint = Some(path.display().to_string());
        let params = PfNetLikelihoodParams {
            checkpoint,
            features: MapFeatures::Cached,
            pool_phases: true,
            ..Default::default()
        };
        params.check().expect("a cacheable wide view");
        let mut world = World::new();
        world.insert_resource(params.clone());
        let map = world.spawn(NetworkMap::from_fine(&tiny_room(), 0.1)).id();
        let wide_grid =
            LocalGrid { wide: Some(WideGrid { extent_m: 10.0, values: grid(5).values }), ..grid(0) };
        let robot = world.spawn((wide_grid, OnMap(map), ParticleSet::from_poses(&POSES))).id();
        world.run_system_once(pfnet_likelihood).expect("system runs");

        let weights = world.get::<ParticleSet>(robot).unwrap().weights();
        let obs = [grid(0).values, grid(5).values].concat();
        let want = expected_cached_weights(&model, &obs, &params.cache_spec());
        assert!(weights.iter().zip(&want).all(|(w, e)| (w - e).abs() < 1e-5), "{weights:?} vs {want:?}");
        let one_phase = expected_cached_weights(&model, &obs, &FeatureCacheSpec::default());
        assert!(
            want.iter().zip(&one_phase).any(|(a, b)| (a - b).abs() > 1e-6),
            "the pool phases change what the particles see"
        );
        assert!(weights.iter().any(|&w| (w - 1.0 / 3.0).abs() > 1e-4), "the network tells particles apart");
    }

    /// The feature banks follow the robots: a robot moved to another map is weighed through that
    /// map's banks, and the map it left, where no robot stands any more, loses its own.
    #[test]
    fn pfnet_likelihood_keeps_feature_banks_only_for_maps_robots_stand_on() {
        let (mut world, robots) = world_with_robots(&[grid(3)], MapFeatures::Cached);
        let robot = robots[0];
        let first = world.get::<OnMap>(robot).expect("on a map").0;
        // The tiny room with a second pillar on its other side.
        let mut other_room = tiny_room();
        for (i, j) in (5..8).flat_map(|i| (8..11).map(move |j| (i, j))) {
            other_room.set(i, j, Cell::Occupied);
        }
        let second = world.spawn(NetworkMap::from_fine(&other_room, 0.1)).id();
        type Params = (Res<'static, PfNetLikelihoodParams>, Query<'static, 'static, &'static NetworkMap>);
        let mut system = SystemState::<(Params, PfNetRobots, Local<PfNetState>)>::new(&mut world);
        let mut step = |world: &mut World| {
            let ((params, maps), robots, state) = system.get_mut(world).expect("valid parameters");
            pfnet_likelihood(params, maps, robots, state);
            let (_, _, state) = system.get_mut(world).expect("valid parameters");
            state.banks.keys().copied().collect::<Vec<_>>()
        };
        assert_eq!(step(&mut world), [first], "the first map's banks are built on first use");
        world.entity_mut(robot).insert((OnMap(second), ParticleSet::from_poses(&POSES)));
        assert_eq!(step(&mut world), [second], "the map left behind loses its banks");

        let model =
            shared_model(&PfNetLikelihoodParams { config: "compact".into(), ..Default::default() }).unwrap();
        let spec = FeatureCacheSpec::default();
        let weights = world.get::<ParticleSet>(robot).unwrap().weights();
        let want = expected_cached_weights_on(&other_room, &model, &grid(3).values, &spec);
        assert!(weights.iter().zip(&want).all(|(w, e)| (w - e).abs() < 1e-5), "{weights:?} vs {want:?}");
        let first_room = expected_cached_weights(&model, &grid(3).values, &spec);
        assert!(
            want.iter().zip(&first_room).any(|(a, b)| (a - b).abs() > 1e-4),
            "the two rooms must weigh the particles differently"
        );
    }

    #[test]
    fn pfnet_likelihood_cached_features_keep_weights_normalised() {
        let (mut world, robots) = world_with_robots(&[grid(2)], MapFeatures::Cached);
        world.run_system_once(pfnet_likelihood).expect("system runs");
        let weights = world.get::<ParticleSet>(robots[0]).unwrap().weights();
        assert!((weights.iter().sum::<f32>() - 1.0).abs() < 1e-5, "weights sum to one: {weights:?}");
        assert!(
            weights.iter().any(|&w| (w - 1.0 / 3.0).abs() > 1e-4),
            "the network must tell particles apart"
        );
    }

    #[test]
    fn pfnet_likelihood_rejects_a_missing_checkpoint_naming_it() {
        let params = PfNetLikelihoodParams {
            checkpoint: Some("no/such/pfnet.safetensors".into()),
            ..Default::default()
        };
        let err = params.check().unwrap_err();
        assert!(err.contains("no/such/pfnet.safetensors"), "the error must name the file: {err}");
    }
}
