//! Augmented MCL (Thrun, Burgard, Fox, Probabilistic Robotics, Table 8.3; nav2 AMCL's
//! `recovery_alpha_slow` / `recovery_alpha_fast`): a long-term (w_slow) and a short-term
//! (w_fast) exponential average of the mean observation likelihood; when the short-term average
//! falls below the long-term one — the scans stopped fitting the belief, e.g. after a kidnapping —
//! each particle is replaced with probability max(0, 1 − w_fast/w_slow) by a uniform draw over
//! the traversable map.
//!
//! Differences from the book, and why:
//! - It runs right after the observation update, before resampling, and weighs each injected
//!   particle with the *current* scan as if it had held weight 1/N before the update. The book
//!   injects during resampling with uniform weight, which is harmless there because AMCL's
//!   estimate is its best cluster; our estimate is the weighted mean over every particle, so
//!   unweighted random particles would drag it across the map.
//! - The averages live in log space (a 60-beam likelihood is ≈ e⁻³⁰ or less and underflows f32).
//! - They start at the first update of each episode (nav2 does the same when they are 0) and are
//!   not reset after an injection (nav2 resets them, which caps injections at one step in two).
//!
//! `recovery_before_update` makes the same injection before the update instead, with the prior
//! weight 1/N, for a model that only its own step can evaluate (PF-net's network).

use crate::episode::EpisodeStart;
use crate::params::{StepParams, expect_param};
use crate::particles::beam_model::{BeamModelParams, add_log_beam_likelihoods};
use crate::particles::likelihood_field::{LikelihoodFieldParams, add_log_likelihoods};
use crate::particles::set::{FilterHealth, LikelihoodStats, ObservationModel, ParticleError, ParticleSet};
use crate::sense::{LidarScan, RayGrid};
use crate::world::map::{DistanceField, TraversableMap};
use crate::world::{FilterRng, OccupancyMap, OnMap, Pose2};
use bevy::prelude::*;
use rand::Rng;
use serde::{Deserialize, Serialize};

/// The averaging rates of augmented MCL.
#[derive(Resource, Serialize, Deserialize, Clone, Debug, PartialEq)]
#[serde(default, deny_unknown_fields)]
pub struct RecoveryParams {
    /// Rate of the long-term average w_slow per observation update, unitless in [0, 1]
    /// (Probabilistic Robotics / the common AMCL recovery setting: 0.001; nav2 defaults it to
    /// 0.0 = recovery off).
    pub alpha_slow: f32,
    /// Rate of the short-term average w_fast, unitless in [0, 1], at least `alpha_slow`
    /// (Probabilistic Robotics / the common AMCL recovery setting: 0.1; nav2 default 0.0 = off).
    pub alpha_fast: f32,
}

impl Default for RecoveryParams {
    fn default() -> Self {
        Self { alpha_slow: 0.001, alpha_fast: 0.1 }
    }
}

impl StepParams for RecoveryParams {
    fn check(&self) -> Result<(), String> {
        let rate = |a: f32| (0.0..=1.0).contains(&a);
        expect_param(
            rate(self.alpha_slow) && rate(self.alpha_fast),
            "alpha_slow, alpha_fast",
            "rates in [0, 1]",
        )?;
        expect_param(
            self.alpha_fast >= self.alpha_slow,
            "alpha_fast",
            "a rate ≥ alpha_slow (the short-term average)",
        )
    }
}

/// A robot's augmented-MCL averages, natural logs of likelihoods. Inserted by `augmented_recovery`
/// on its first run and reset at every `EpisodeStart`.
#[derive(Component, Clone, Copy, Debug, Default, PartialEq)]
pub struct RecoveryState {
    /// (log w_slow, log w_fast); `None` until the episode's first observation update.
    pub log_w: Option<(f64, f64)>,
    /// `LikelihoodStats::updates` last averaged, so a stale update is never counted twice.
    pub seen_updates: u32,
    /// max(0, 1 − w_fast/w_slow) at the last update: the per-particle injection probability.
    pub injection_probability: f32,
}

/// log((1 − α)·e^a + α·e^b) without leaving log space.
fn log_mix(a: f64, b: f64, alpha: f64) -> f64 {
    let (x, y) = ((1.0 - alpha).ln() + a, alpha.ln() + b);
    let max = x.max(y);
    if max == f64::NEG_INFINITY { max } else { max + ((x - max).exp() + (y - max).exp()).ln() }
}

/// Folds one mean log-likelihood into the averages and returns the injection probability
/// max(0, 1 − w_fast/w_slow). The first update sets both averages to it (probability 0); a NaN
/// likelihood is skipped. Rates are clamped to [0, 1].
pub fn update_averages(state: &mut RecoveryState, mean_log_likelihood: f32, params: &RecoveryParams) -> f32 {
    if mean_log_likelihood.is_nan() {
        return state.injection_probability;
    }
    let m = mean_log_likelihood as f64;
    let (slow, fast) = match state.log_w {
        None => (m, m),
        Some((slow, fast)) => (
            log_mix(slow, m, params.alpha_slow.clamp(0.0, 1.0) as f64),
            log_mix(fast, m, params.alpha_fast.clamp(0.0, 1.0) as f64),
        ),
    };
    state.log_w = Some((slow, fast));
    let ratio = if slow == f64::NEG_INFINITY { 1.0 } else { (fast - slow).exp() };
    state.injection_probability = (1.0 - ratio).clamp(0.0, 1.0) as f32;
    state.injection_probability
}

/// Replaces each particle with probability `probability` by a pose drawn uniformly over the
/// traversable map, sets the newcomers' log-weights with `log_weights` (given them at 0, it writes
/// each relative to the old set's normalised ones) and renormalises. Returns how many particles
/// were replaced. Errors, leaving the set untouched, when there is no traversable cell or
/// `log_weights` fails.
fn replace_uniform(
    set: &mut ParticleSet,
    probability: f32,
    (map, traversable): (&OccupancyMap, &TraversableMap),
    rng: &mut impl Rng,
    log_weights: impl FnOnce(&mut ParticleSet) -> Result<(), ParticleError>,
) -> Result<usize, ParticleError> {
    let n = set.len();
    if probability <= 0.0 || n == 0 {
        return Ok(0);
    }
    if traversable.cells.is_empty() {
        return Err(ParticleError::NoTraversableCells);
    }
    let picks: Vec<usize> = (0..n).filter(|_| rng.random::<f32>() < probability).collect();
    let poses: Vec<Pose2> = picks.iter().map(|_| traversable.sample_pose(map, rng)).collect();
    let mut fresh = ParticleSet::from_poses(&poses);
    fresh.log_w.fill(0.0);
    log_weights(&mut fresh)?;
    for (k, &i) in picks.iter().enumerate() {
        (set.x[i], set.y[i], set.yaw[i], set.log_w[i]) =
            (fresh.x[k], fresh.y[k], fresh.yaw[k], fresh.log_w[k]);
    }
    set.normalise_guarded();
    Ok(picks.len())
}

/// Replaces each particle with probability `probability` by a pose drawn uniformly over the
/// traversable map, weighs the newcomers by `log_likelihood` (which adds log p(z | x) to the
/// log-weights of the set it is given) as if each had held weight 1/N before the update whose
/// log mean likelihood was `mean_log_likelihood`, and renormalises. Returns how many particles
/// were replaced. Errors, leaving the set untouched, when there is no traversable cell or the
/// likelihood fails.
pub fn inject_uniform(
    set: &mut ParticleSet,
    probability: f32,
    mean_log_likelihood: f32,
    layers: (&OccupancyMap, &TraversableMap),
    rng: &mut impl Rng,
    log_likelihood: impl FnOnce(&mut ParticleSet) -> Result<(), ParticleError>,
) -> Result<usize, ParticleError> {
    let log_n = (set.len() as f32).ln();
    replace_uniform(set, probability, layers, rng, |fresh| {
        log_likelihood(fresh)?;
        // Newcomer weight relative to the normalised old ones: (1/N)·p(z|x) / Σ_k w_k·p(z|x_k).
        let reference = match mean_log_likelihood.is_finite() {
            true => mean_log_likelihood,
            false => fresh.log_total_weight(),
        };
        fresh.log_w.iter_mut().for_each(|l| *l -= log_n + reference);
        Ok(())
    })
}

/// One robot's recovery step: folds in the last observation update (once; a stale `stats`
/// changes nothing) and calls `inject` with the resulting per-particle probability. Returns how
/// many particles it replaced.
pub fn recover(
    state: &mut RecoveryState,
    stats: &LikelihoodStats,
    params: &RecoveryParams,
    inject: impl FnOnce(f32) -> Result<usize, ParticleError>,
) -> Result<usize, ParticleError> {
    if stats.updates == state.seen_updates {
        return Ok(0);
    }
    state.seen_updates = stats.updates;
    inject(update_averages(state, stats.mean_log_likelihood, params))
}

/// Writes a robot's recovery state back, inserting it on the system's first run for the robot.
fn keep_state(
    commands: &mut Commands,
    robot: Entity,
    state: Option<Mut<RecoveryState>>,
    next: RecoveryState,
) {
    match state {
        Some(mut state) => *state = next,
        None => {
            commands.entity(robot).insert(next);
        }
    }
}

/// Reads LikelihoodStats (and its model), EpisodeStart, LidarScan, the map's OccupancyMap,
/// TraversableMap and DistanceField or RayGrid, RecoveryParams, the model's params. Writes
/// RecoveryState, ParticleSet, FilterRng, FilterHealth.injected.
pub fn augmented_recovery(
    params: Res<RecoveryParams>,
    (field_params, beam_params): (Option<Res<LikelihoodFieldParams>>, Option<Res<BeamModelParams>>),
    maps: Query<(&OccupancyMap, &TraversableMap, &DistanceField, &RayGrid)>,
    mut commands: Commands,
    mut robots: Query<(
        Entity,
        (&OnMap, &LidarScan, &LikelihoodStats, Has<EpisodeStart>),
        Option<&mut RecoveryState>,
        (&mut ParticleSet, &mut FilterRng, &mut FilterHealth),
    )>,
) {
    let field_params = field_params.map(|p| p.clone()).unwrap_or_default();
    let beam_params = beam_params.map(|p| p.clone()).unwrap_or_default();
    for (robot, (on_map, scan, stats, start), state, (mut set, mut rng, mut health)) in &mut robots {
        let Ok((map, traversable, field, rays)) = maps.get(on_map.0) else { continue };
        let mut next = state.as_deref().copied().unwrap_or_default();
        if start {
            next.log_w = None; // a new episode: the averages restart at its first update
        }
        // Newcomers are weighed by the model that weighed the rest of the set.
        let weigh = |s: &mut ParticleSet| match stats.model {
            ObservationModel::LikelihoodField => {
                add_log_likelihoods(s, scan, field, &map.origin, &field_params)
            }
            ObservationModel::BeamModel => add_log_beam_likelihoods(s, scan, rays, &beam_params),
            ObservationModel::PfNet => Err(ParticleError::InvalidParam {
                field: "augmented_recovery",
                expected: "a classical observation model before it (with PF-net, `recovery_before_update`)",
            }),
        };
        let inject =
            |p| inject_uniform(&mut set, p, stats.mean_log_likelihood, (map, traversable), &mut rng.0, weigh);
        match recover(&mut next, stats, &params, inject) {
            Ok(count) => health.injected += count as u32,
            Err(e) => tracing::warn!("augmented_recovery: {e}"),
        }
        keep_state(&mut commands, robot, state, next);
    }
}

/// The parameters of `recovery_before_update`: augmented MCL's rates, as a type of their own
/// because a step's parameters are a resource keyed by type. The two placements share
/// `RecoveryState`, so a schedule runs one of them.
#[derive(Resource, Serialize, Deserialize, Clone, Debug, Default, PartialEq)]
#[serde(transparent)]
pub struct RecoveryBeforeUpdateParams(pub RecoveryParams);

impl StepParams for RecoveryBeforeUpdateParams {
    fn check(&self) -> Result<(), String> {
        self.0.check()
    }
}

/// Augmented MCL's injection made before the observation update (inserted after `transition`)
/// instead of after it: the averages through the last update set the probability and newcomers
/// enter with the prior weight 1/N, so the update that follows weighs them with the rest under
/// whatever model it runs — PF-net included, whose network `augmented_recovery` cannot call. The
/// price is one step of lag: the injection answers the last scan, not the current one.
///
/// Reads LikelihoodStats (of the last update), EpisodeStart, the map's OccupancyMap and
/// TraversableMap, RecoveryBeforeUpdateParams. Writes RecoveryState, ParticleSet, FilterRng,
/// FilterHealth.injected.
pub fn recovery_before_update(
    params: Res<RecoveryBeforeUpdateParams>,
    maps: Query<(&OccupancyMap, &TraversableMap)>,
    mut commands: Commands,
    mut robots: Query<(
        Entity,
        (&OnMap, &LikelihoodStats, Has<EpisodeStart>),
        Option<&mut RecoveryState>,
        (&mut ParticleSet, &mut FilterRng, &mut FilterHealth),
    )>,
) {
    for (robot, (on_map, stats, start), state, (mut set, mut rng, mut health)) in &mut robots {
        let Ok(layers) = maps.get(on_map.0) else { continue };
        let mut next = state.as_deref().copied().unwrap_or_default();
        if start {
            // The last update belongs to the episode before: the averages restart at this one's first.
            next = RecoveryState { seen_updates: stats.updates, ..RecoveryState::default() };
        }
        let log_prior = set.log_total_weight() - (set.len() as f32).ln();
        let inject = |p| {
            replace_uniform(&mut set, p, layers, &mut rng.0, |fresh| {
                fresh.log_w.fill(log_prior);
                Ok(())
            })
        };
        match recover(&mut next, stats, &params.0, inject) {
            Ok(count) => health.injected += count as u32,
            Err(e) => tracing::warn!("recovery_before_update: {e}"),
        }
        keep_state(&mut commands, robot, state, next);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::particles::mcl_likelihood_field;
    use crate::sense::{LidarParams, RayGrid, cast_scan};
    use crate::testing::tiny_room;
    use crate::world::rng::stream;
    use bevy::ecs::system::RunSystemOnce;

    const TRUTH: Pose2 = Pose2 { x: 0.5, y: 1.0, yaw: 0.3 };
    /// Where the collapsed beliefs of the tests sit, far from `TRUTH`.
    const WRONG: Pose2 = Pose2 { x: 1.6, y: 0.4, yaw: -2.0 };

    /// tiny_room with its layers, and a robot at `TRUTH` whose 200 particles sit at `particles`.
    fn world_with_robot(
        particles: Pose2,
        stats: LikelihoodStats,
        state: Option<RecoveryState>,
    ) -> (World, Entity) {
        let map = tiny_room();
        let mut scan = LidarScan::default();
        cast_scan(&RayGrid::from_map(&map), TRUTH, &[], &LidarParams::default(), &mut scan);
        let layers = (TraversableMap::build(&map, 0.1).expect("room has space"), DistanceField::build(&map));
        let mut world = World::new();
        world.insert_resource(RecoveryParams::default());
        world.insert_resource(RecoveryBeforeUpdateParams::default());
        let rays = RayGrid::from_map(&map);
        let m = world.spawn((map, layers.0, layers.1, rays)).id();
        let set = ParticleSet::from_poses(&[particles; 200]);
        let robot = world.spawn((OnMap(m), scan, set, FilterRng::seeded(3))).id();
        world.entity_mut(robot).insert(stats);
        if let Some(state) = state {
            world.entity_mut(robot).insert(state);
        }
        (world, robot)
    }

    fn moved(set: &ParticleSet, from: Pose2) -> usize {
        (0..set.len()).filter(|&k| set.pose(k) != from).count()
    }

    /// A robot whose particles all sit at WRONG, with w_fast already e³ below w_slow and a new
    /// update (the second) whose scan fits far worse still.
    fn collapsing_at_wrong_pose() -> (World, Entity) {
        let stats = LikelihoodStats { mean_log_likelihood: -80.0, updates: 2, ..Default::default() };
        let state = RecoveryState { log_w: Some((-30.0, -33.0)), seen_updates: 1, ..Default::default() };
        world_with_robot(WRONG, stats, Some(state))
    }

    #[test]
    fn augmented_recovery_injects_when_the_likelihood_collapses() {
        let (mut world, robot) = collapsing_at_wrong_pose();
        world.run_system_once(augmented_recovery).expect("system runs");
        let p = world.get::<RecoveryState>(robot).expect("state").injection_probability;
        let expected = 1.0 - (0.9 * (-3.0f32).exp()) / 0.999;
        assert!((p - expected).abs() < 1e-3, "p = 1 − w_fast/w_slow = {expected}, got {p}");
        let set = world.get::<ParticleSet>(robot).expect("set");
        let injected = world.get::<FilterHealth>(robot).expect("health").injected as usize;
        assert_eq!(injected, moved(set, WRONG), "the counter matches the particles replaced");
        assert!((175..=200).contains(&injected), "≈ 200·{p:.3} = {:.0} injected, got {injected}", 200.0 * p);
        assert!((set.weights().iter().sum::<f32>() - 1.0).abs() < 1e-4, "weights stay normalised");
        let map = tiny_room();
        let t = TraversableMap::build(&map, 0.1).expect("room");
        let on_map = (0..set.len())
            .filter(|&k| set.pose(k) != WRONG)
            .all(|k| map.cell_at(set.x[k], set.y[k]).is_some_and(|(i, j)| t.is_traversable(i, j)));
        assert!(on_map, "injected particles lie on traversable cells");
    }

    #[test]
    fn augmented_recovery_weighs_newcomers_by_the_scan_with_either_model() {
        // Every old particle is wrong and the scan says so: the newcomers, weighed by the current
        // scan with the model that weighed the set, must carry the weight, each in proportion to
        // its likelihood under that model.
        let (field, rays) = (DistanceField::build(&tiny_room()), RayGrid::from_map(&tiny_room()));
        let mut scan = LidarScan::default();
        cast_scan(&rays, TRUTH, &[], &LidarParams::default(), &mut scan);
        for model in [ObservationModel::LikelihoodField, ObservationModel::BeamModel] {
            // Each pose's log-likelihood under `model`, computed independently of the system.
            let log_likelihoods = |poses: &[Pose2]| {
                let mut probe = ParticleSet::from_poses(poses);
                probe.log_w.iter_mut().for_each(|l| *l = 0.0);
                match model {
                    ObservationModel::LikelihoodField => {
                        add_log_likelihoods(&mut probe, &scan, &field, &Pose2::default(), &Default::default())
                    }
                    ObservationModel::BeamModel => {
                        add_log_beam_likelihoods(&mut probe, &scan, &rays, &Default::default())
                    }
                    ObservationModel::PfNet => unreachable!("only the classical models are looped over"),
                }
                .expect("valid layers");
                probe.log_w
            };
            let stats =
                LikelihoodStats { mean_log_likelihood: log_likelihoods(&[WRONG])[0], updates: 2, model };
            let state = RecoveryState { log_w: Some((-30.0, -33.0)), seen_updates: 1, ..Default::default() };
            let (mut world, robot) = world_with_robot(WRONG, stats, Some(state));
            world.run_system_once(augmented_recovery).expect("system runs");
            let set = world.get::<ParticleSet>(robot).expect("set");
            let w = set.weights();
            let old_mass: f32 = (0..set.len()).filter(|&k| set.pose(k) == WRONG).map(|k| w[k]).sum();
            assert!(old_mass < 0.01, "{model:?}: the wrong particles keep {old_mass} of the mass");
            let newcomers: Vec<usize> = (0..set.len()).filter(|&k| set.pose(k) != WRONG).collect();
            let poses: Vec<Pose2> = newcomers.iter().map(|&k| set.pose(k)).collect();
            let offsets: Vec<f32> =
                newcomers.iter().zip(log_likelihoods(&poses)).map(|(&k, l)| set.log_w[k] - l).collect();
            let spread = offsets.iter().fold(f32::MIN, |a, &b| a.max(b))
                - offsets.iter().fold(f32::MAX, |a, &b| a.min(b));
            assert!(
                spread < 1e-2,
                "{model:?}: newcomers' log-weights = log-likelihood + a constant (spread {spread})"
            );
        }
    }

    #[test]
    fn augmented_recovery_injects_nothing_when_steady() {
        let at = Pose2::new(0.5, 1.0, 0.3);
        let stats = LikelihoodStats { mean_log_likelihood: -30.0, updates: 2, ..Default::default() };
        let state = RecoveryState { log_w: Some((-30.0, -30.0)), seen_updates: 1, ..Default::default() };
        let (mut world, robot) = world_with_robot(at, stats, Some(state));
        world.run_system_once(augmented_recovery).expect("system runs");
        world.run_system_once(augmented_recovery).expect("a second run sees a stale update");
        let set = world.get::<ParticleSet>(robot).expect("set");
        assert_eq!(moved(set, at), 0, "steady likelihood: no particle replaced");
        assert_eq!(world.get::<FilterHealth>(robot).expect("health").injected, 0);
        let state = world.get::<RecoveryState>(robot).expect("state");
        assert_eq!(state.injection_probability, 0.0, "w_fast = w_slow → probability 0");
        assert_eq!(state.seen_updates, 2);
    }

    /// A robot whose averages collapsed in the last episode, at the first step of a new one whose
    /// first update (stats) has run: its pose, those stats, the world and the robot.
    fn collapsed_at_episode_start() -> (Pose2, LikelihoodStats, World, Entity) {
        let at = Pose2::new(0.5, 1.0, 0.3);
        let stats = LikelihoodStats { mean_log_likelihood: -80.0, updates: 9, ..Default::default() };
        let collapsed = RecoveryState { log_w: Some((-30.0, -60.0)), seen_updates: 8, ..Default::default() };
        let (mut world, robot) = world_with_robot(at, stats, Some(collapsed));
        world.entity_mut(robot).insert(EpisodeStart);
        (at, stats, world, robot)
    }

    #[test]
    fn augmented_recovery_restarts_at_episode_start_and_inserts_its_state() {
        let (at, stats, mut world, robot) = collapsed_at_episode_start();
        world.run_system_once(augmented_recovery).expect("system runs");
        let state = world.get::<RecoveryState>(robot).expect("state");
        assert_eq!(state.log_w, Some((-80.0, -80.0)), "averages restart at the episode's first update");
        assert_eq!(moved(world.get::<ParticleSet>(robot).expect("set"), at), 0, "no injection at a start");
        let (mut world, robot) = world_with_robot(at, stats, None);
        world.run_system_once(augmented_recovery).expect("system runs");
        let state = world.get::<RecoveryState>(robot).expect("inserted on first run");
        assert_eq!(state.log_w, Some((-80.0, -80.0)));
    }

    #[test]
    fn recovery_before_update_injects_at_prior_weight_for_the_next_update_to_weigh() {
        let (mut world, robot) = collapsing_at_wrong_pose();
        world.run_system_once(recovery_before_update).expect("system runs");
        let set = world.get::<ParticleSet>(robot).expect("set").clone();
        let injected = world.get::<FilterHealth>(robot).expect("health").injected as usize;
        assert_eq!(injected, moved(&set, WRONG), "the counter matches the particles replaced");
        assert!(
            (175..=200).contains(&injected),
            "the averages of the last update set p ≈ 0.91, got {injected}"
        );
        let uniform = -(200.0f32).ln();
        assert!(
            set.log_w.iter().all(|&l| (l - uniform).abs() < 1e-4),
            "newcomers enter at 1/N, like the rest"
        );
        world.run_system_once(recovery_before_update).expect("a second run sees a stale update");
        assert_eq!(
            moved(world.get::<ParticleSet>(robot).expect("set"), WRONG),
            injected,
            "one injection per update"
        );

        // The update that follows weighs the newcomers with the rest: the wrong particles lose the mass.
        world.insert_resource(LikelihoodFieldParams::default());
        world.run_system_once(mcl_likelihood_field).expect("system runs");
        let set = world.get::<ParticleSet>(robot).expect("set");
        let w = set.weights();
        let old_mass: f32 = (0..set.len()).filter(|&k| set.pose(k) == WRONG).map(|k| w[k]).sum();
        assert!(old_mass < 0.01, "the wrong particles keep {old_mass} of the mass after the update");
    }

    #[test]
    fn recovery_before_update_leaves_the_last_episode_behind_at_a_start() {
        let (at, stats, mut world, robot) = collapsed_at_episode_start();
        world.run_system_once(recovery_before_update).expect("system runs");
        let state = *world.get::<RecoveryState>(robot).expect("state");
        assert_eq!(
            state,
            RecoveryState { seen_updates: 9, ..Default::default() },
            "the last episode's update is not averaged"
        );
        assert_eq!(moved(world.get::<ParticleSet>(robot).expect("set"), at), 0, "no injection at a start");
        world.entity_mut(robot).remove::<EpisodeStart>();
        world.entity_mut(robot).insert(LikelihoodStats { mean_log_likelihood: -20.0, updates: 10, ..stats });
        world.run_system_once(recovery_before_update).expect("system runs");
        let state = world.get::<RecoveryState>(robot).expect("state");
        assert_eq!(state.log_w, Some((-20.0, -20.0)), "the averages start at the episode's first update");
        assert_eq!(moved(world.get::<ParticleSet>(robot).expect("set"), at), 0);
    }

    #[test]
    fn augmented_recovery_probability_follows_the_averages() {
        let params = RecoveryParams::default();
        let mut state = RecoveryState::default();
        for _ in 0..100 {
            let p = update_averages(&mut state, -20.0, &params);
            assert_eq!(p, 0.0, "a steady likelihood never injects");
        }
        let mut last = 0.0;
        for _ in 0..10 {
            let p = update_averages(&mut state, -60.0, &params);
            assert!(p > last, "the probability grows while the scans stay bad: {p} after {last}");
            last = p;
        }
        // w_fast/w_slow ≈ (0.9 / 0.999)^10 once the bad likelihood is negligible (e⁻⁴⁰).
        let expected = 1.0 - (0.9f32 / 0.999).powi(10);
        assert!((last - expected).abs() < 1e-3, "after 10 bad updates p ≈ {expected}, got {last}");
        let p = update_averages(&mut state, -15.0, &params);
        assert_eq!(p, 0.0, "a scan that fits better than ever stops the injection at once");
        assert_eq!(update_averages(&mut state, f32::NAN, &params), 0.0, "NaN is skipped");
    }

    #[test]
    fn augmented_recovery_inject_errors_without_traversable_cells() {
        let mut map_layers = TraversableMap::build(&tiny_room(), 0.1).expect("room");
        map_layers.cells.clear();
        let mut set = ParticleSet::from_poses(&[TRUTH; 4]);
        let r =
            inject_uniform(&mut set, 1.0, -5.0, (&tiny_room(), &map_layers), &mut stream(&[1]), |_| Ok(()));
        assert_eq!(r, Err(ParticleError::NoTraversableCells));
        assert_eq!(set, ParticleSet::from_poses(&[TRUTH; 4]), "the set is left untouched");
    }
}
