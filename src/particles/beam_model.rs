//! AMCL's beam (ray-cast) observation model (Thrun et al., Probabilistic Robotics §6.3, Table
//! 6.1; nav2 `nav2_amcl` `beam`): each used beam is ray-cast from the particle through the map's
//! `RayGrid` to its expected range z*, and the measured range z scores
//!
//! p = z_hit·exp(−(z − z*)²/2σ²) + z_short·λ·e^{−λz}·𝟙(z < z*) + z_max·𝟙(z = range_max)
//!     + z_rand/range_max·𝟙(z < range_max).
//!
//! As in AMCL, the hit Gaussian is neither normalised nor truncated to [0, range_max] (peak 1,
//! the same convention as `likelihood_field.rs`), the short exponential is not renormalised over
//! [0, z*], and the uniform part covers only non-max readings. Unlike the likelihood field, a
//! max-range reading is evidence here (z_max explains it; a particle that expects a wall nearby
//! is penalised through the missing hit).
//!
//! Accumulation: Σ log p is added to the log-weight, as in `likelihood_field.rs` (AMCL uses the
//! heuristic 1 + Σ p³). Readings: NaN and −∞ are skipped; +∞, readings beyond range_max and
//! readings below range_min count as range_max (nav2 `amcl_node` maps both to max range). The
//! LiDAR sits at the robot centre, facing ahead.

use crate::params::{StepParams, expect_param};
use crate::particles::likelihood_field::selected_beams;
use crate::particles::set::{
    FilterHealth, Guard, LikelihoodStats, ObservationModel, ParticleError, ParticleSet, record_observation,
};
use crate::sense::{LidarScan, RayGrid};
use crate::world::OnMap;
use bevy::prelude::*;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// Particles per parallel task (fixed; results never depend on the thread count). Smaller than
/// `LIKELIHOOD_CHUNK`: a particle costs `max_beams` ray casts here, not lookups.
pub const BEAM_CHUNK: usize = 16;

/// The beam-model parameters, with nav2 AMCL's names and defaults
/// (docs.nav2.org, "Configuring AMCL").
#[derive(Resource, Serialize, Deserialize, Clone, Debug, PartialEq)]
#[serde(default, deny_unknown_fields)]
pub struct BeamModelParams {
    /// Mixture weight of the Gaussian "hit" part, unitless (nav2 `z_hit`: 0.5).
    pub z_hit: f32,
    /// Mixture weight of the exponential "unexpected short obstacle" part, unitless
    /// (nav2 `z_short`: 0.05).
    pub z_short: f32,
    /// Mixture weight of the "max-range reading" part, unitless (nav2 `z_max`: 0.05).
    pub z_max: f32,
    /// Mixture weight of the uniform "random measurement" part, unitless; divided by the scan's
    /// range_max (nav2 `z_rand`: 0.5).
    pub z_rand: f32,
    /// Std-dev of the hit Gaussian, metres (nav2 `sigma_hit`: 0.2).
    pub sigma_hit: f32,
    /// Decay rate of the short-reading exponential, 1/metre (nav2 `lambda_short`: 0.1).
    pub lambda_short: f32,
    /// Beams used per scan, evenly sub-sampled from the scan (nav2 `max_beams`: 60).
    pub max_beams: usize,
}

impl Default for BeamModelParams {
    fn default() -> Self {
        Self {
            z_hit: 0.5,
            z_short: 0.05,
            z_max: 0.05,
            z_rand: 0.5,
            sigma_hit: 0.2,
            lambda_short: 0.1,
            max_beams: 60,
        }
    }
}

impl StepParams for BeamModelParams {
    fn check(&self) -> Result<(), String> {
        let weights = [self.z_hit, self.z_short, self.z_max, self.z_rand];
        expect_param(weights.iter().all(|&z| z >= 0.0), "z_hit, z_short, z_max, z_rand", "weights ≥ 0")?;
        expect_param(weights.iter().sum::<f32>() > 0.0, "z_hit + z_short + z_max + z_rand", "> 0")?;
        expect_param(self.sigma_hit > 0.0, "sigma_hit", "a std-dev > 0 m")?;
        expect_param(self.lambda_short > 0.0, "lambda_short", "a rate > 0")?;
        crate::limits::BEAMS.check("max_beams", self.max_beams)
    }
}

/// p(z | z*) of one beam, the formula in the module doc. `z` must already be mapped into
/// [0, range_max] (see [`beam_readings`]).
pub fn beam_probability(z: f32, z_star: f32, range_max_m: f32, params: &BeamModelParams) -> f32 {
    let d = z - z_star;
    let hit = params.z_hit * (-d * d / (2.0 * params.sigma_hit * params.sigma_hit)).exp();
    let short = if z < z_star {
        params.z_short * params.lambda_short * (-params.lambda_short * z).exp()
    } else {
        0.0
    };
    let max_or_rand = if z >= range_max_m { params.z_max } else { params.z_rand / range_max_m };
    hit + short + max_or_rand
}

/// The sub-sampled readings the model uses, as (bearing in the robot frame, rad; range, m):
/// NaN/−∞ skipped, +∞, > range_max and < range_min mapped to range_max.
pub fn beam_readings(scan: &LidarScan, max_beams: usize) -> Vec<(f32, f32)> {
    let (lo, hi) = (scan.range_min_m, scan.range_max_m);
    selected_beams(scan, max_beams)
        .filter(|&(_, r)| !r.is_nan() && r != f32::NEG_INFINITY)
        .map(|(bearing, r)| (bearing, if r < lo || r > hi { hi } else { r }))
        .collect()
}

/// Adds each particle's Σ log p over the used beams to its log-weight (no normalisation),
/// ray-casting z* through `grid` from the particle's pose. Particles with a non-finite pose get a
/// NaN log-weight, for the guard to drop. Errors (leaving the set untouched) on a non-positive
/// `sigma_hit` or scan range_max.
pub fn add_log_beam_likelihoods(
    set: &mut ParticleSet,
    scan: &LidarScan,
    grid: &RayGrid,
    params: &BeamModelParams,
) -> Result<(), ParticleError> {
    if !(params.sigma_hit > 0.0 && params.sigma_hit.is_finite()) {
        return Err(ParticleError::InvalidParam { field: "sigma_hit", expected: "a std-dev > 0 m" });
    }
    let range_max = scan.range_max_m;
    if !(range_max > 0.0 && range_max.is_finite()) {
        return Err(ParticleError::InvalidParam {
            field: "LidarScan.range_max_m",
            expected: "a range > 0 m",
        });
    }
    let beams = beam_readings(scan, params.max_beams);
    let ParticleSet { x, y, yaw, log_w } = set;
    let chunks = log_w.par_chunks_mut(BEAM_CHUNK).zip(x.par_chunks(BEAM_CHUNK));
    let chunks = chunks.zip(y.par_chunks(BEAM_CHUNK)).zip(yaw.par_chunks(BEAM_CHUNK));
    chunks.for_each(|(((lws, xs), ys), yaws)| {
        for (((lw, &px), &py), &pyaw) in lws.iter_mut().zip(xs).zip(ys).zip(yaws) {
            if !(px.is_finite() && py.is_finite() && pyaw.is_finite()) {
                *lw = f32::NAN;
                continue;
            }
            let sum: f32 = beams
                .iter()
                .map(|&(bearing, z)| {
                    let z_star = grid.cast(px, py, pyaw + bearing, range_max);
                    beam_probability(z, z_star, range_max, params).ln()
                })
                .sum();
            *lw += sum;
        }
    });
    Ok(())
}

/// The full observation update: adds the log-likelihoods, then normalises through the guard
/// ([`ParticleSet::weigh_with`]); returns the guard's verdict and the log mean likelihood.
pub fn weigh_beam_model(
    set: &mut ParticleSet,
    scan: &LidarScan,
    grid: &RayGrid,
    params: &BeamModelParams,
) -> Result<(Guard, f32), ParticleError> {
    set.weigh_with(|set| add_log_beam_likelihoods(set, scan, grid, params))
}

/// Reads LidarScan, OnMap → the map's RayGrid, BeamModelParams. Writes ParticleSet weights,
/// LikelihoodStats, FilterHealth.degeneracies.
pub fn mcl_beam_model(
    params: Res<BeamModelParams>,
    maps: Query<&RayGrid>,
    mut robots: Query<(&LidarScan, &OnMap, &mut ParticleSet, &mut FilterHealth, &mut LikelihoodStats)>,
) {
    for (scan, on_map, mut set, mut health, mut stats) in &mut robots {
        let Ok(grid) = maps.get(on_map.0) else {
            tracing::warn!("mcl_beam_model: map {:?} has no RayGrid", on_map.0);
            continue;
        };
        let outcome = weigh_beam_model(&mut set, scan, grid, &params);
        record_observation(ObservationModel::BeamModel, outcome, &mut health, &mut stats);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sense::{LidarParams, cast_reference, cast_scan};
    use crate::testing::tiny_room;
    use crate::world::{OccupancyMap, Pose2};
    use bevy::ecs::system::RunSystemOnce;

    const TRUTH: Pose2 = Pose2 { x: 0.6, y: 0.6, yaw: 0.3 };

    /// The paper's 228-ray scan, cast with the real RayGrid from `pose`.
    fn scan_from(map: &OccupancyMap, pose: Pose2) -> LidarScan {
        let mut scan = LidarScan::default();
        cast_scan(&RayGrid::from_map(map), pose, &[], &LidarParams::default(), &mut scan);
        scan
    }

    /// One ray straight ahead reading `range_m`, with the given range_max.
    fn one_beam(range_m: f32, range_max_m: f32) -> LidarScan {
        LidarScan { ranges_m: vec![range_m], range_min_m: 0.05, range_max_m, ..Default::default() }
    }

    /// Σ log p for one particle with zero log-weight, through the kernel.
    fn log_likelihood(pose: Pose2, scan: &LidarScan, grid: &RayGrid, params: &BeamModelParams) -> f32 {
        let mut set = ParticleSet::from_poses(&[pose]);
        set.log_w = vec![0.0];
        add_log_beam_likelihoods(&mut set, scan, grid, params).expect("valid params");
        set.log_w[0]
    }

    #[test]
    fn mcl_beam_model_prefers_true_pose() {
        let mut world = World::new();
        world.insert_resource(BeamModelParams::default());
        let map = world.spawn(RayGrid::from_map(&tiny_room())).id();
        let off = Pose2::new(TRUTH.x + 0.3, TRUTH.y, TRUTH.yaw);
        let set = ParticleSet::from_poses(&[TRUTH, off]);
        let robot = world.spawn((scan_from(&tiny_room(), TRUTH), OnMap(map), set)).id();
        world.run_system_once(mcl_beam_model).expect("system runs");
        let w = world.get::<ParticleSet>(robot).expect("set").weights();
        assert!(w[0] > 0.99, "true pose must dominate a pose 0.3 m away, weights {w:?}");
        assert!((w[0] + w[1] - 1.0).abs() < 1e-5, "weights normalised, got {w:?}");
        let stats = *world.get::<LikelihoodStats>(robot).expect("ParticleSet requires LikelihoodStats");
        assert_eq!(stats.updates, 1, "one observation update recorded");
        assert!(stats.mean_log_likelihood.is_finite(), "finite mean likelihood, got {stats:?}");
        assert_eq!(world.get::<FilterHealth>(robot).expect("health").degeneracies, 0);
    }

    #[test]
    fn mcl_beam_model_explains_max_range_by_z_max() {
        let grid = RayGrid::from_map(&tiny_room());
        let params = BeamModelParams::default();
        // Facing +x from (0.5, 0.5): the wall face is at x = 1.9 m, 1.4 m ahead.
        let pose = Pose2::new(0.5, 0.5, 0.0);
        let expects_wall = log_likelihood(pose, &one_beam(5.6, 5.6), &grid, &params);
        assert!(
            (expects_wall - 0.05f32.ln()).abs() < 1e-3,
            "a max reading where the map has a wall at 1.4 m scores log z_max = {}, got {expects_wall}",
            0.05f32.ln()
        );
        let agrees = log_likelihood(pose, &one_beam(1.0, 1.0), &grid, &params);
        assert!(
            (agrees - 0.55f32.ln()).abs() < 1e-4,
            "max reading, map agrees: log(z_hit + z_max), got {agrees}"
        );
        let beyond = log_likelihood(pose, &one_beam(f32::INFINITY, 1.0), &grid, &params);
        assert_eq!(beyond, agrees, "+inf counts as a max-range reading");
        let no_z_max = BeamModelParams { z_max: 0.0, ..params };
        let unexplained = log_likelihood(pose, &one_beam(5.6, 5.6), &grid, &no_z_max);
        assert!(unexplained < -100.0, "without z_max the reading is nearly impossible, got {unexplained}");
    }

    #[test]
    fn mcl_beam_model_skips_nan_beams() {
        let grid = RayGrid::from_map(&tiny_room());
        let params = BeamModelParams::default();
        let pose = Pose2::new(0.5, 0.5, 0.0);
        // Three rays at −90°, 0°, +90°; only the middle one reads.
        let mut scan = one_beam(1.2, 5.6);
        scan.ranges_m = vec![f32::NAN, 1.2, f32::NAN];
        scan.angle_min_rad = -std::f32::consts::FRAC_PI_2;
        scan.angle_increment_rad = std::f32::consts::FRAC_PI_2;
        let got = log_likelihood(pose, &scan, &grid, &params);
        let expected = beam_probability(1.2, grid.cast(0.5, 0.5, 0.0, 5.6), 5.6, &params).ln();
        assert!(
            got.is_finite() && (got - expected).abs() < 1e-6,
            "NaN beams add nothing: {got} vs {expected}"
        );
        scan.ranges_m = vec![f32::NAN; 3];
        assert_eq!(
            log_likelihood(pose, &scan, &grid, &params),
            0.0,
            "an all-NaN scan leaves the weight alone"
        );
    }

    #[test]
    fn beam_model_matches_reference_formula() {
        // Kernel vs. the formula written out with the reference caster, on a rotated map, for
        // more particles than one chunk (so chunking cannot change a result).
        let params = BeamModelParams { max_beams: 40, ..Default::default() };
        let mut map = tiny_room();
        map.origin = Pose2::new(-1.0, 0.5, -0.4);
        let grid = RayGrid::from_map(&map);
        let mut scan = scan_from(&map, map.origin.compose(&TRUTH));
        scan.ranges_m[57] = f32::NAN;
        scan.ranges_m[0] = 0.01;
        let poses: Vec<Pose2> = (0..3 * BEAM_CHUNK + 5)
            .map(|k| {
                let local = Pose2::new(0.15 + 0.03 * k as f32, 0.2 + 0.02 * k as f32, 0.4 * k as f32);
                map.origin.compose(&local)
            })
            .collect();
        let mut set = ParticleSet::from_poses(&poses);
        set.log_w = vec![0.0; poses.len()];
        add_log_beam_likelihoods(&mut set, &scan, &grid, &params).expect("valid params");
        for (k, p) in poses.iter().enumerate() {
            let expected: f32 = selected_beams(&scan, params.max_beams)
                .filter(|(_, r)| !r.is_nan())
                .map(|(bearing, r)| {
                    let z = if r < scan.range_min_m { scan.range_max_m } else { r };
                    let z_star = cast_reference(&map, p.x, p.y, p.yaw + bearing, scan.range_max_m);
                    let hit = 0.5 * (-(z - z_star).powi(2) / (2.0 * 0.04)).exp();
                    let short = if z < z_star { 0.05 * 0.1 * (-0.1 * z).exp() } else { 0.0 };
                    let tail = if z >= scan.range_max_m { 0.05 } else { 0.5 / scan.range_max_m };
                    (hit + short + tail).ln()
                })
                .sum();
            assert!(
                (set.log_w[k] - expected).abs() < 1e-2 * expected.abs().max(1.0),
                "particle {k} at {p:?}: kernel {} vs reference {expected}",
                set.log_w[k]
            );
        }
    }

    #[test]
    fn mcl_beam_model_counts_degeneracy() {
        let mut world = World::new();
        world.insert_resource(BeamModelParams::default());
        let map = world.spawn(RayGrid::from_map(&tiny_room())).id();
        let set = ParticleSet::from_poses(&[Pose2::new(f32::NAN, 0.6, 0.0); 3]);
        let robot = world.spawn((scan_from(&tiny_room(), TRUTH), OnMap(map), set)).id();
        world.run_system_once(mcl_beam_model).expect("system runs");
        let w = world.get::<ParticleSet>(robot).expect("set").weights();
        assert!(w.iter().all(|&v| (v - 1.0 / 3.0).abs() < 1e-6), "all-NaN → uniform, got {w:?}");
        assert_eq!(world.get::<FilterHealth>(robot).expect("health").degeneracies, 1, "guard event counted");
    }

    #[test]
    fn beam_model_rejects_zero_sigma() {
        let grid = RayGrid::from_map(&tiny_room());
        let mut set = ParticleSet::from_poses(&[TRUTH, Pose2::new(1.0, 0.5, 0.0)]);
        let before = set.clone();
        let params = BeamModelParams { sigma_hit: 0.0, ..Default::default() };
        let r = weigh_beam_model(&mut set, &scan_from(&tiny_room(), TRUTH), &grid, &params);
        assert!(matches!(r, Err(ParticleError::InvalidParam { field: "sigma_hit", .. })), "got {r:?}");
        assert_eq!(set, before, "an invalid update leaves the set untouched");
    }
}
