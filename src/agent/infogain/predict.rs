//! The look-ahead of `infogain_policy`: for each candidate motion, imagine it under H poses drawn
//! from the belief, let the filter's own models say what the belief would become, and score the
//! candidate by the expected entropy of that belief plus its costs.
//!
//! Per hypothesis and step of a plan (`plans.rs`): drive the imagined robot on the traversable
//! map, move a weighted subsample of the particles by the odometry this reports (the filter's
//! transition: with its noise for a primitive, exact for a reach plan), cast the scan the robot would see there (the LiDAR's ray caster), and weigh
//! the moved particles against it with the filter's likelihood field. Only the map and the
//! belief are read, never the true pose.

use crate::act::{DriveCommand, PhysicsParams, command_for};
use crate::agent::Action;
use crate::agent::infogain::entropy::histogram_entropy;
use crate::agent::infogain::params::InfogainParams;
use crate::agent::infogain::plans::candidate_plans;
use crate::particles::{
    BeamTerms, LikelihoodFieldParams, ParticleError, ParticleSet, TransitionParams, propagate,
    systematic_indices,
};
use crate::sense::{LidarParams, LidarScan, RayGrid, cast_scan};
use crate::world::map::{DistanceField, TraversableMap};
use crate::world::rng::stream;
use crate::world::{OccupancyMap, Pose2, RobotParams};
use rand::Rng;

/// The layers of the robot's map the prediction reads.
#[derive(Clone, Copy)]
pub struct MapView<'a> {
    pub map: &'a OccupancyMap,
    pub grid: &'a RayGrid,
    pub field: &'a DistanceField,
    pub traversable: &'a TraversableMap,
}

/// The models of the running pipeline, so the prediction imagines what the sensor, the filter
/// and the drive will actually do.
#[derive(Clone, Copy)]
pub struct Models<'a> {
    pub lidar: &'a LidarParams,
    pub likelihood: &'a LikelihoodFieldParams,
    pub transition: &'a TransitionParams,
    pub robot: &'a RobotParams,
    pub physics: &'a PhysicsParams,
}

/// What the look-ahead predicts for one candidate.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CandidateScore {
    pub action: Action,
    /// Posterior entropy after the horizon, averaged over the hypotheses, nats.
    pub expected_entropy: f32,
    /// Share of the hypotheses under which the motion runs into the map.
    pub collision_probability: f32,
    /// Distance driven, averaged over the hypotheses, metres.
    pub distance_m: f32,
    /// expected_entropy + collision_cost · collision_probability + distance_cost_per_m · distance_m.
    pub cost: f32,
}

/// Stream tags under the policy's per-step key.
const SUBSAMPLE_STREAM: u64 = 0;
const HYPOTHESIS_STREAM: u64 = 1;
const TRANSITION_STREAM: u64 = 2;

/// The transition of a plan imagined without odometry noise.
const EXACT_MOTION: TransitionParams = TransitionParams { trans_noise_m: 0.0, rot_noise_deg: 0.0 };

/// Scores every candidate of `params` for the belief `set` (at least one particle). Every draw
/// comes from streams keyed by `key` (subsample, hypotheses, and one per hypothesis and step
/// for the transition noise, shared by all candidates), so the result depends on nothing else.
pub fn score_candidates(
    set: &ParticleSet,
    view: MapView,
    models: Models,
    params: &InfogainParams,
    key: u64,
) -> Result<Vec<CandidateScore>, ParticleError> {
    if set.is_empty() {
        return Err(ParticleError::ZeroParticles);
    }
    let q: Vec<f64> = set.log_w.iter().map(|&l| f64::from(l).exp()).collect();
    let draw = |n: usize, tag: u64| systematic_indices(&q, n, &mut stream(&[key, tag]));
    let subsample: Vec<Pose2> =
        draw(params.particles, SUBSAMPLE_STREAM).into_iter().map(|k| set.pose(k)).collect();
    let hypotheses: Vec<Pose2> =
        draw(params.hypotheses, HYPOTHESIS_STREAM).into_iter().map(|k| set.pose(k)).collect();
    let belief = ParticleSet::from_poses(&subsample);
    let lidar = LidarParams { rays: params.beams, ..models.lidar.clone() };
    // The look-ahead reads the field at the endpoint's cell: half the cost of the interpolated
    // read, and 24 beams on 200 particles do not resolve the few cm it adds.
    let likelihood =
        LikelihoodFieldParams { max_beams: params.beams, interpolate: false, ..models.likelihood.clone() };
    let terms = BeamTerms::new(&likelihood, lidar.range_max_m)?;
    let bin_rad = params.bin_size_deg.to_radians();
    let mut scan = LidarScan::default();
    let h_count = hypotheses.len() as f32;
    candidate_plans(params, models.robot, models.physics)
        .into_iter()
        .map(|plan| {
            let (mut entropy, mut collisions, mut distance) = (0.0f32, 0usize, 0.0f32);
            for (h, &start) in hypotheses.iter().enumerate() {
                let (mut pose, mut collided) = (start, false);
                let mut moved = belief.clone();
                let transition = if plan.noisy { models.transition } else { &EXACT_MOTION };
                for (s, &action) in plan.actions.iter().enumerate() {
                    let step = drive_on_map(pose, command_for(action, models.robot), models.physics, view);
                    // The same noise for every candidate (common random numbers): candidates differ
                    // by their motion, not by their draws.
                    let transition_key: u64 = stream(&[key, TRANSITION_STREAM, h as u64, s as u64]).random();
                    propagate(&mut moved, &pose.between(&step.pose), transition, transition_key);
                    cast_scan(view.grid, step.pose, &[], &lidar, &mut scan);
                    terms.add_log_likelihoods(&mut moved, &scan, view.field, &view.map.origin)?;
                    (pose, collided, distance) =
                        (step.pose, collided | step.collided, distance + step.distance_m);
                }
                // The starting log-weights are all equal, so scaling them all tempers the likelihood.
                moved.log_w.iter_mut().for_each(|l| *l *= params.likelihood_scale);
                let (m, bin_m) = (&moved, params.bin_size_m);
                entropy += histogram_entropy(&m.x, &m.y, &m.yaw, &m.log_w, pose, bin_m, bin_rad);
                collisions += usize::from(collided);
            }
            let (expected_entropy, distance_m) = (entropy / h_count, distance / h_count);
            let collision_probability = collisions as f32 / h_count;
            let cost = expected_entropy
                + params.collision_cost * collision_probability
                + params.distance_cost_per_m * distance_m;
            Ok(CandidateScore {
                action: plan.actions[0],
                expected_entropy,
                collision_probability,
                distance_m,
                cost,
            })
        })
        .collect()
}

/// The candidate of lowest cost (the first one on ties); stop when there is none.
pub fn best_action(scores: &[CandidateScore]) -> Action {
    let best = scores.iter().reduce(|best, s| if s.cost < best.cost { s } else { best });
    best.map_or(Action::default(), |s| s.action)
}

/// One imagined agent step of driving.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ImaginedStep {
    pub pose: Pose2,
    /// Some sub-step would have left the traversable map.
    pub collided: bool,
    /// Path length driven, metres.
    pub distance_m: f32,
}

/// Holds `command` for one agent step from `pose`, in the physics' sub-steps, each an exact
/// unicycle arc. A sub-step that would carry the centre from a traversable cell into a
/// non-traversable one keeps the position and still turns, as a body pressed against a wall
/// does; a start off the traversable map (a stray hypothesis) moves freely.
pub fn drive_on_map(
    pose: Pose2,
    command: DriveCommand,
    physics: &PhysicsParams,
    view: MapView,
) -> ImaginedStep {
    let traversable =
        |p: &Pose2| view.map.cell_at(p.x, p.y).is_some_and(|(i, j)| view.traversable.is_traversable(i, j));
    let dt = physics.dt_s;
    let (v, w) = (command.linear_mps, command.angular_radps);
    let arc = if (w * dt).abs() < 1e-6 {
        Pose2::new(v * dt, 0.0, 0.0)
    } else {
        Pose2::new(v / w * (w * dt).sin(), v / w * (1.0 - (w * dt).cos()), w * dt)
    };
    let mut step = ImaginedStep { pose, collided: false, distance_m: 0.0 };
    for _ in 0..physics.substeps {
        let next = step.pose.compose(&arc);
        if traversable(&step.pose) && !traversable(&next) {
            step.collided = true;
            step.pose.yaw = next.yaw;
        } else {
            step.pose = next;
            step.distance_m += (v * dt).abs();
        }
    }
    step
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::particles::add_log_likelihoods;
    use crate::testing::tiny_room;
    use crate::world::Cell;

    struct Layers {
        map: OccupancyMap,
        grid: RayGrid,
        field: DistanceField,
        traversable: TraversableMap,
    }

    impl Layers {
        fn of(map: OccupancyMap) -> Self {
            let traversable = TraversableMap::build(&map, RobotParams::default().radius_m).expect("room");
            Layers { grid: RayGrid::from_map(&map), field: DistanceField::build(&map), traversable, map }
        }

        fn view(&self) -> MapView<'_> {
            MapView { map: &self.map, grid: &self.grid, field: &self.field, traversable: &self.traversable }
        }
    }

    /// A 2 m × 1.5 m room at 0.02 m/cell, walls one cell thick, with or without a pillar at
    /// x ∈ [1.1, 1.4), y ∈ [0.8, 1.1) m.
    fn room(pillar: bool) -> OccupancyMap {
        let (w, h) = (100, 75);
        let mut map = OccupancyMap::filled(w, h, 0.02, Cell::Free);
        for j in 0..h {
            for i in 0..w {
                let wall = i == 0 || j == 0 || i == w - 1 || j == h - 1;
                if wall || (pillar && (55..70).contains(&i) && (40..55).contains(&j)) {
                    map.set(i, j, Cell::Occupied);
                }
            }
        }
        map
    }

    /// Expected entropy of standing still for one step, with exact transitions, for a belief of
    /// two particles `a` (weight 3/4) and `b` (1/4): 4 hypotheses and 4 particles are drawn
    /// A, A, A, B by the systematic draw whatever its offset.
    fn stand_still_entropy(layers: &Layers, a: Pose2, b: Pose2, likelihood_scale: f32) -> f32 {
        let mut set = ParticleSet::from_poses(&[a, b]);
        set.log_w = vec![0.75f32.ln(), 0.25f32.ln()];
        let params = InfogainParams {
            candidates: vec![(0.0, 0.0)],
            horizon_steps: 1,
            hypotheses: 4,
            particles: 4,
            likelihood_scale,
            ..Default::default()
        };
        let transition = TransitionParams { trans_noise_m: 0.0, rot_noise_deg: 0.0 };
        let (lidar, likelihood, robot, physics) = Default::default();
        let models = Models {
            lidar: &lidar,
            likelihood: &likelihood,
            transition: &transition,
            robot: &robot,
            physics: &physics,
        };
        let scores = score_candidates(&set, layers.view(), models, &params, 3).expect("valid layers");
        assert_eq!(scores[0].collision_probability, 0.0, "standing still never collides");
        scores[0].expected_entropy
    }

    #[test]
    fn expected_entropy_of_two_hypotheses_matches_the_hand_calculation() {
        // An empty 2 m × 1.5 m room looks the same from a pose and its half-turn image about
        // the centre: the scan cannot tell them apart, each hypothesis leaves the prior
        // (3/4, 1/4), and the expected entropy is −¾ ln ¾ − ¼ ln ¼ = 0.5623 nats.
        // At 2 cm per cell, so that where a beam's endpoint on a wall face rounds to (the wall's
        // cell or the free one before it) moves log p by a negligible amount.
        let a = Pose2::new(0.5, 1.1, 0.3);
        let b = Pose2::new(2.0 - a.x, 1.5 - a.y, crate::world::wrap_angle(a.yaw + std::f32::consts::PI));
        let by_hand = -(0.75f32 * 0.75f32.ln() + 0.25 * 0.25f32.ln());
        let h = stand_still_entropy(&Layers::of(room(false)), a, b, 1.0);
        assert!((h - by_hand).abs() < 0.01, "symmetric room: expected entropy {h}, by hand {by_hand}");
        // With the pillar the scans differ. By hand: hypothesis h's scan z_h gives particle k
        // the log-likelihood l(h, k); the posterior of hypothesis h puts 3·e^(s·l(h,a)) on a's bin
        // and e^(s·l(h,b)) on b's (s = likelihood_scale), and the expected entropy is (3·H(post_a) + H(post_b)) / 4.
        let layers = Layers::of(room(true));
        let log_likelihood = |h: Pose2, k: Pose2| {
            let lidar = LidarParams { rays: 24, ..Default::default() };
            let mut scan = LidarScan::default();
            cast_scan(&layers.grid, h, &[], &lidar, &mut scan);
            let mut one = ParticleSet::from_poses(&[k]);
            let likelihood =
                LikelihoodFieldParams { max_beams: 24, interpolate: false, ..Default::default() };
            add_log_likelihoods(&mut one, &scan, &layers.field, &layers.map.origin, &likelihood)
                .expect("field");
            one.log_w[0] // from ln 1 = 0
        };
        let binary_entropy = |log_mass_a: f32, log_mass_b: f32| {
            let p = 1.0 / (1.0 + (log_mass_b - log_mass_a).exp());
            -(p * p.ln() + (1.0 - p) * (1.0 - p).max(f32::MIN_POSITIVE).ln())
        };
        let by_hand = |s: f32| {
            let posterior =
                |h: Pose2| binary_entropy(3f32.ln() + s * log_likelihood(h, a), s * log_likelihood(h, b));
            (3.0 * posterior(a) + posterior(b)) / 4.0
        };
        for s in [1.0, InfogainParams::default().likelihood_scale] {
            let h = stand_still_entropy(&layers, a, b, s);
            assert!(
                (h - by_hand(s)).abs() < 1e-3,
                "pillar, scale {s}: expected entropy {h}, by hand {}",
                by_hand(s)
            );
        }
        let h = stand_still_entropy(&layers, a, b, 1.0);
        assert!(h < 0.5 * 0.5623, "untempered, the pillar tells the poses apart: {h}");
    }

    #[test]
    fn drive_on_map_follows_arcs_and_stops_at_walls() {
        let layers = Layers::of(tiny_room());
        let physics = PhysicsParams::default();
        let robot = RobotParams::default();
        // Quarter-circle check: 0.5 m/s, π/2 rad/s for 0.6 s turns 54° on a circle of radius 1/π m.
        let step = drive_on_map(
            Pose2::new(0.6, 0.4, 0.0),
            command_for(Action::new(1.0, 1.0), &robot),
            &physics,
            layers.view(),
        );
        let (r, turn) = (1.0 / std::f32::consts::PI, 0.3 * std::f32::consts::PI);
        let expected = Pose2::new(0.6 + r * turn.sin(), 0.4 + r * (1.0 - turn.cos()), turn);
        assert!(
            step.pose.distance(&expected) < 1e-4 && (step.pose.yaw - turn).abs() < 1e-4,
            "{step:?} vs {expected:?}"
        );
        assert!(!step.collided && (step.distance_m - 0.3).abs() < 1e-5, "{step:?}");
        // At the east wall from 0.2 m before the traversable edge (x = 1.8): stops there, still turns.
        let step = drive_on_map(
            Pose2::new(1.6, 0.5, 0.0),
            command_for(Action::new(1.0, 0.2), &robot),
            &physics,
            layers.view(),
        );
        assert!(step.collided && step.pose.x < 1.8, "the body stops at the wall: {step:?}");
        assert!(
            (step.pose.yaw - 0.6 * 0.2 * std::f32::consts::FRAC_PI_2).abs() < 1e-4,
            "and keeps turning: {step:?}"
        );
    }
}
