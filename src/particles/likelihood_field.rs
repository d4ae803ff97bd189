//! AMCL's likelihood-field observation model (Thrun et al., Probabilistic Robotics §6.4; nav2
//! `nav2_amcl` `likelihood_field`): each used beam's endpoint, projected from a particle, costs
//! one look-up of the distance to the nearest surface where rays end, d, and scores
//! p = z_hit·exp(−d²/2σ²) + z_rand/range_max. Unlike AMCL, the borders of unknown areas count as
//! such surfaces (rays stop there, in nav2's beam model as in our LiDAR), and d is interpolated
//! between cell centres and measured to the cell's face ([`DistanceField::surface_distance`]):
//! both matter on 0.1 m maps (`docs/results/coarse_maps.md`).
//!
//! Accumulation ([`BeamCombination`]): by default we add Σ log p to the particle's log-weight — the
//! model's actual likelihood under independent beams. AMCL instead multiplies the weight by
//! 1 + Σ p³, a heuristic that flattens the posterior so that a few hundred particles keep
//! hypotheses alive in self-similar places (long aisles); `combine: amcl_cube_sum` reproduces it.
//! The LiDAR is taken to sit at the robot centre, facing ahead.

use crate::params::{StepParams, expect_param};
use crate::particles::set::{
    FilterHealth, Guard, LikelihoodStats, ObservationModel, ParticleError, ParticleSet, record_observation,
};
use crate::sense::LidarScan;
use crate::world::map::DistanceField;
use crate::world::{OccupancyMap, OnMap, Pose2};
use bevy::prelude::*;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// Particles per parallel task (fixed; results never depend on the thread count).
pub const LIKELIHOOD_CHUNK: usize = 64;

/// Entries of the per-call log p(d) table over [0, laser_likelihood_max_dist]. Looking log p up
/// instead of evaluating exp + ln per beam is what makes `benches/likelihood_field.rs` reach
/// > 100 M beams/s; the quantisation step (2 mm at the default 2 m) moves log p by < 0.05.
pub const LOG_P_TABLE_LEN: usize = 1024;

/// The likelihood-field parameters, with nav2 AMCL's names and defaults.
#[derive(Resource, Serialize, Deserialize, Clone, Debug, PartialEq)]
#[serde(default, deny_unknown_fields)]
pub struct LikelihoodFieldParams {
    /// Mixture weight of the Gaussian "hit" part, unitless (nav2 `z_hit`: 0.5).
    pub z_hit: f32,
    /// Mixture weight of the uniform "random measurement" part, unitless; divided by the scan's
    /// range_max (nav2 `z_rand`: 0.5).
    pub z_rand: f32,
    /// Std-dev of the hit Gaussian, metres (nav2 `sigma_hit`: 0.2).
    pub sigma_hit: f32,
    /// Beams used per scan, evenly sub-sampled from the scan (nav2 `max_beams`: 60).
    pub max_beams: usize,
    /// Distances to the nearest obstacle are clamped to this, metres; endpoints off the map count
    /// as this far (nav2 `laser_likelihood_max_dist`: 2.0).
    pub laser_likelihood_max_dist: f32,
    /// How the per-beam p combine into one particle likelihood.
    pub combine: BeamCombination,
    /// Read the distance field interpolated to cell faces (`true`: a few cm more accurate on
    /// 0.1 m maps, see `docs/results/coarse_maps.md`) or at the endpoint's cell (`false`: nav2's
    /// lookup, one read per beam instead of four: 0.43 against 0.81 ms in `benches/likelihood_field.rs`
    /// when measured, before the beam loop was monomorphised on the read).
    pub interpolate: bool,
}

/// How per-beam likelihoods p_i combine into a particle's likelihood.
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Eq, Default)]
#[serde(rename_all = "snake_case")]
pub enum BeamCombination {
    /// Π p_i: the likelihood of independent beams (Probabilistic Robotics' `likelihood_field`).
    #[default]
    Product,
    /// 1 + Σ p_i³: nav2 AMCL's and Beluga's heuristic, far flatter than the product.
    AmclCubeSum,
}

impl Default for LikelihoodFieldParams {
    fn default() -> Self {
        Self {
            z_hit: 0.5,
            z_rand: 0.5,
            sigma_hit: 0.2,
            max_beams: 60,
            laser_likelihood_max_dist: 2.0,
            combine: BeamCombination::Product,
            interpolate: true,
        }
    }
}

impl StepParams for LikelihoodFieldParams {
    fn check(&self) -> Result<(), String> {
        expect_param(self.z_hit >= 0.0 && self.z_rand >= 0.0, "z_hit, z_rand", "mixture weights ≥ 0")?;
        expect_param(self.z_hit + self.z_rand > 0.0, "z_hit + z_rand", "> 0")?;
        expect_param(self.sigma_hit > 0.0, "sigma_hit", "a std-dev > 0 m")?;
        crate::limits::BEAMS.check("max_beams", self.max_beams)?;
        expect_param(self.laser_likelihood_max_dist > 0.0, "laser_likelihood_max_dist", "a distance > 0 m")?;
        self.check_far_beams_keep_a_likelihood()
    }
}

impl LikelihoodFieldParams {
    /// Without `z_rand`, a beam `laser_likelihood_max_dist` from any obstacle scores
    /// z_hit·exp(−d²/2σ²), which a small `sigma_hit` rounds to 0 in f32: log −∞ on every particle
    /// such a beam touches, and the weights reset to uniform. Rejected here, with the smallest
    /// `sigma_hit` that keeps the score a normal f32.
    fn check_far_beams_keep_a_likelihood(&self) -> Result<(), String> {
        if self.combine != BeamCombination::Product || self.z_rand > 0.0 {
            return Ok(());
        }
        let (d, floor) = (self.laser_likelihood_max_dist, f32::MIN_POSITIVE.ln());
        let log_p_far = self.z_hit.ln() - d * d / (2.0 * self.sigma_hit * self.sigma_hit);
        let sigma_min = d / (2.0 * (self.z_hit.ln() - floor)).sqrt();
        expect_param(
            log_p_far >= floor,
            "sigma_hit",
            &format!(
                "at least {sigma_min:.3} m when z_rand = 0 (or z_rand > 0): with sigma_hit = {} m a beam \
                 laser_likelihood_max_dist = {d} m from any obstacle has likelihood 0 in f32 (log −∞), \
                 which would reset the weights to uniform",
                self.sigma_hit
            ),
        )
    }
}

/// Indices of `max_beams` beams spread evenly over `n` (first and last included); all beams when
/// `max_beams ≥ n`, the middle one when `max_beams = 1`. (AMCL steps by ⌊(n−1)/(max_beams−1)⌋,
/// which can use more beams than asked; rounding keeps the count exact.)
pub fn beam_indices(n: usize, max_beams: usize) -> Vec<usize> {
    match max_beams {
        _ if n == 0 || max_beams == 0 => Vec::new(),
        m if m >= n => (0..n).collect(),
        1 => vec![n / 2],
        m => (0..m).map(|k| (k * (n - 1) + (m - 1) / 2) / (m - 1)).collect(),
    }
}

/// The beams an observation model reads: [`beam_indices`] of the scan as (bearing in the robot
/// frame, rad; measured range, m), unfiltered; each model decides what a reading means.
pub fn selected_beams(scan: &LidarScan, max_beams: usize) -> impl Iterator<Item = (f32, f32)> + '_ {
    beam_indices(scan.ranges_m.len(), max_beams)
        .into_iter()
        .map(|i| (scan.angle_min_rad + i as f32 * scan.angle_increment_rad, scan.ranges_m[i]))
}

/// Sub-sampled usable beams as endpoint offsets in the robot frame, in grid cells of `resolution_m`.
/// Skips NaN/±∞ readings, readings at or beyond range_max (AMCL ignores max-range returns) and
/// readings below range_min (AMCL maps them to max range).
fn beam_offsets(scan: &LidarScan, max_beams: usize, resolution_m: f32) -> Vec<(f32, f32)> {
    selected_beams(scan, max_beams)
        .filter(|&(_, r)| r.is_finite() && r >= scan.range_min_m && r < scan.range_max_m)
        .map(|(bearing, r)| {
            let (s, c) = bearing.sin_cos();
            (r * c / resolution_m, r * s / resolution_m)
        })
        .collect()
}

/// The per-beam terms of one parameter set for scans of one `range_max_m`: each beam's summand
/// at d_k = k·max_dist/(LEN−1) — log p(d) for the product, p(d)³ for AMCL's sum — in a table
/// built once (1,024 exp + ln) and read by every particle and beam of every scan it weighs. A
/// caller weighing many scans (the information-gain look-ahead: 160 per decision) builds it once.
pub struct BeamTerms {
    params: LikelihoodFieldParams,
    range_max_m: f32,
    table: Vec<f32>,
}

impl BeamTerms {
    /// Errors when a summand is not finite (log 0: parameters `StepParams::check` rejects,
    /// reaching the kernel unchecked), rather than letting it reset the weights.
    pub fn new(params: &LikelihoodFieldParams, range_max_m: f32) -> Result<Self, ParticleError> {
        let sigma = params.sigma_hit.max(1e-6);
        let rand = if range_max_m > 0.0 { params.z_rand / range_max_m } else { 0.0 };
        let max_dist = params.laser_likelihood_max_dist.max(1e-6);
        let table = (0..LOG_P_TABLE_LEN)
            .map(|k| {
                let d = k as f32 * max_dist / (LOG_P_TABLE_LEN - 1) as f32;
                let p = params.z_hit * (-d * d / (2.0 * sigma * sigma)).exp() + rand;
                match params.combine {
                    BeamCombination::Product => p.ln(),
                    BeamCombination::AmclCubeSum => p * p * p,
                }
            })
            .collect::<Vec<f32>>();
        match table.iter().all(|t| t.is_finite()) {
            true => Ok(Self { params: params.clone(), range_max_m, table }),
            false => Err(ParticleError::InvalidParam {
                field: "sigma_hit, z_rand",
                expected: "a likelihood above 0 at laser_likelihood_max_dist (raise sigma_hit or z_rand)",
            }),
        }
    }

    /// Adds each particle's log-likelihood of `scan` to its log-weight, as
    /// [`add_log_likelihoods`] does. Errors (leaving the set untouched) when the scan's range_max
    /// is not the one the terms were built for, or the field is malformed.
    pub fn add_log_likelihoods(
        &self,
        set: &mut ParticleSet,
        scan: &LidarScan,
        field: &DistanceField,
        origin: &Pose2,
    ) -> Result<(), ParticleError> {
        if scan.range_max_m != self.range_max_m {
            return Err(ParticleError::InvalidParam {
                field: "range_max_m",
                expected: "the scan range the likelihood terms were built for",
            });
        }
        let cells = field.width * field.height;
        if field.distances_m.len() < cells {
            let found = field.distances_m.len();
            return Err(ParticleError::MalformedLayer { layer: "DistanceField", expected: cells, found });
        }
        let params = &self.params;
        let inv_res = 1.0 / field.resolution_m;
        let beams = beam_offsets(scan, params.max_beams, field.resolution_m);
        let finish = match params.combine {
            BeamCombination::Product => |sum: f32| sum,
            BeamCombination::AmclCubeSum => |sum: f32| sum.ln_1p(),
        };
        let sum_over_beams = match params.interpolate {
            true => beam_sum::<true>,
            false => beam_sum::<false>,
        };
        let (so, co) = origin.yaw.sin_cos();
        let ParticleSet { x, y, yaw, log_w } = set;
        let chunks = log_w.par_chunks_mut(LIKELIHOOD_CHUNK).zip(x.par_chunks(LIKELIHOOD_CHUNK));
        let chunks = chunks.zip(y.par_chunks(LIKELIHOOD_CHUNK)).zip(yaw.par_chunks(LIKELIHOOD_CHUNK));
        chunks.for_each(|(((lws, xs), ys), yaws)| {
            for (((lw, &px), &py), &pyaw) in lws.iter_mut().zip(xs).zip(ys).zip(yaws) {
                if !(px.is_finite() && py.is_finite() && pyaw.is_finite()) {
                    *lw = f32::NAN;
                    continue;
                }
                // Particle pose in the grid frame, in cells; the origin's yaw is folded in once here.
                let (dx, dy) = (px - origin.x, py - origin.y);
                let grid_xy = ((co * dx + so * dy) * inv_res, (-so * dx + co * dy) * inv_res);
                let sin_cos = (pyaw - origin.yaw).sin_cos();
                *lw += finish(sum_over_beams(self, field, &beams, grid_xy, sin_cos));
            }
        });
        Ok(())
    }
}

/// Σ of `terms`' table over the endpoints of `beams` (robot-frame offsets in cells) seen from a
/// particle at `grid_xy` (cells) with heading `(sin, cos)` in the grid frame. Monomorphised on
/// the read so the hot loop holds no branch on it and keeps every invariant in a register.
#[inline(always)]
fn beam_sum<const INTERPOLATE: bool>(
    terms: &BeamTerms,
    field: &DistanceField,
    beams: &[(f32, f32)],
    (gx0, gy0): (f32, f32),
    (s, c): (f32, f32),
) -> f32 {
    let (table, distances) = (&terms.table[..LOG_P_TABLE_LEN], &field.distances_m[..]);
    let far = table[LOG_P_TABLE_LEN - 1];
    let max_dist = terms.params.laser_likelihood_max_dist;
    let scale = (LOG_P_TABLE_LEN - 1) as f32 / max_dist.max(1e-6);
    let (w, wf, hf) = (field.width, field.width as f32, field.height as f32);
    let mut sum = 0.0f32;
    for &(bx, by) in beams {
        let gx = gx0 + c * bx - s * by;
        let gy = gy0 + s * bx + c * by;
        // `as i32` (not `as usize`): f32→u64 is a slow multi-instruction sequence on x86-64.
        sum += if gx >= 0.0 && gy >= 0.0 && gx < wf && gy < hf {
            // No clamp to max_dist on the cell read: the index clamp below does it (∞ saturates).
            let d = match INTERPOLATE {
                true => field.surface_distance(gx, gy, max_dist),
                false => distances[gy as i32 as usize * w + gx as i32 as usize],
            };
            table[((d * scale + 0.5) as i32 as usize).min(LOG_P_TABLE_LEN - 1)]
        } else {
            far
        };
    }
    sum
}

/// Adds each particle's log-likelihood over the used beams — Σ log p, or ln(1 + Σ p³) for
/// [`BeamCombination::AmclCubeSum`] — to its log-weight (no normalisation).
/// `origin` is the world pose of the field's cell (0, 0) corner (the OccupancyMap origin); the
/// field's own width/height/resolution give the rest of the geometry. Particles with a
/// non-finite pose get a NaN log-weight, for the guard to drop. Errors (leaving the set
/// untouched) when the field holds fewer than width × height distances, or when the parameters
/// give a beam likelihood of 0 (see [`LikelihoodFieldParams::check`]).
pub fn add_log_likelihoods(
    set: &mut ParticleSet,
    scan: &LidarScan,
    field: &DistanceField,
    origin: &Pose2,
    params: &LikelihoodFieldParams,
) -> Result<(), ParticleError> {
    BeamTerms::new(params, scan.range_max_m)?.add_log_likelihoods(set, scan, field, origin)
}

/// The full observation update: adds the log-likelihoods, then normalises through the guard
/// ([`ParticleSet::weigh_with`]); returns the guard's verdict and the log mean likelihood.
pub fn weigh_likelihood_field(
    set: &mut ParticleSet,
    scan: &LidarScan,
    field: &DistanceField,
    origin: &Pose2,
    params: &LikelihoodFieldParams,
) -> Result<(Guard, f32), ParticleError> {
    set.weigh_with(|set| add_log_likelihoods(set, scan, field, origin, params))
}

/// Reads LidarScan, OnMap → the map's OccupancyMap (origin) and DistanceField,
/// LikelihoodFieldParams. Writes ParticleSet weights, LikelihoodStats, FilterHealth.degeneracies.
pub fn mcl_likelihood_field(
    params: Res<LikelihoodFieldParams>,
    maps: Query<(&OccupancyMap, &DistanceField)>,
    mut robots: Query<(&LidarScan, &OnMap, &mut ParticleSet, &mut FilterHealth, &mut LikelihoodStats)>,
) {
    for (scan, on_map, mut set, mut health, mut stats) in &mut robots {
        let Ok((map, field)) = maps.get(on_map.0) else {
            tracing::warn!("mcl_likelihood_field: map {:?} has no OccupancyMap + DistanceField", on_map.0);
            continue;
        };
        let outcome = weigh_likelihood_field(&mut set, scan, field, &map.origin, &params);
        record_observation(ObservationModel::LikelihoodField, outcome, &mut health, &mut stats);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testing::tiny_room;
    use crate::world::Cell;
    use bevy::ecs::system::RunSystemOnce;

    /// Distance from each cell centre to the nearest centre of a cell where rays end (occupied, or
    /// unknown beside a free cell), by brute force.
    fn brute_field(map: &OccupancyMap) -> DistanceField {
        let free_beside = |i: usize, j: usize| {
            (j.saturating_sub(1)..(j + 2).min(map.height))
                .any(|b| (i.saturating_sub(1)..(i + 2).min(map.width)).any(|a| map.get(a, b) == Cell::Free))
        };
        let blocked: Vec<(usize, usize)> = (0..map.height)
            .flat_map(|j| (0..map.width).map(move |i| (i, j)))
            .filter(|&(i, j)| match map.get(i, j) {
                Cell::Occupied => true,
                Cell::Unknown => free_beside(i, j),
                Cell::Free => false,
            })
            .collect();
        let distances_m = (0..map.height)
            .flat_map(|j| (0..map.width).map(move |i| (i, j)))
            .map(|(i, j)| {
                let d2 = blocked.iter().map(|&(a, b)| (a.abs_diff(i).pow(2) + b.abs_diff(j).pow(2)) as f32);
                d2.fold(f32::INFINITY, f32::min).sqrt() * map.resolution_m
            })
            .collect();
        DistanceField { width: map.width, height: map.height, resolution_m: map.resolution_m, distances_m }
    }

    /// A 228-ray, 240° scan from `pose`, by marching each ray in 2 mm steps to the first non-free cell.
    fn marched_scan(map: &OccupancyMap, pose: Pose2) -> LidarScan {
        let (n, fov, range_max) = (228, 240f32.to_radians(), 5.6);
        let angle_min = -fov / 2.0;
        let increment = fov / (n - 1) as f32;
        let ranges_m = (0..n)
            .map(|i| {
                let (s, c) = (pose.yaw + angle_min + i as f32 * increment).sin_cos();
                let mut r = 0.0;
                while r < range_max && map.cell_at_point(pose.x + r * c, pose.y + r * s) == Cell::Free {
                    r += 0.002;
                }
                r.min(range_max)
            })
            .collect();
        LidarScan {
            ranges_m,
            angle_min_rad: angle_min,
            angle_increment_rad: increment,
            range_min_m: 0.05,
            range_max_m: range_max,
        }
    }

    fn spawn_room(world: &mut World, map: OccupancyMap) -> Entity {
        let field = brute_field(&map);
        world.spawn((map, field)).id()
    }

    #[test]
    fn mcl_likelihood_field_prefers_true_pose() {
        let mut world = World::new();
        world.insert_resource(LikelihoodFieldParams::default());
        let truth = Pose2::new(0.6, 0.6, 0.3);
        let map = spawn_room(&mut world, tiny_room());
        let scan = marched_scan(&tiny_room(), truth);
        let set = ParticleSet::from_poses(&[truth, Pose2::new(1.1, 0.6, 0.3)]);
        let robot = world.spawn((scan, OnMap(map), set)).id();
        world.run_system_once(mcl_likelihood_field).expect("system runs");
        let w = world.get::<ParticleSet>(robot).expect("set").weights();
        assert!(w[0] > 0.99, "true pose must dominate a pose 0.5 m away, weights {w:?}");
        assert!((w[0] + w[1] - 1.0).abs() < 1e-5, "weights normalised");
        assert_eq!(world.get::<FilterHealth>(robot).expect("health").degeneracies, 0);
    }

    #[test]
    fn mcl_likelihood_field_records_mean_likelihood_before_normalising() {
        let mut world = World::new();
        world.insert_resource(LikelihoodFieldParams::default());
        let truth = Pose2::new(0.6, 0.6, 0.3);
        let map = spawn_room(&mut world, tiny_room());
        let scan = marched_scan(&tiny_room(), truth);
        let poses = [truth, Pose2::new(1.1, 0.6, 0.3)];
        // Per-particle log-likelihoods, by the kernel on a copy with zero log-weights.
        let mut raw = ParticleSet::from_poses(&poses);
        raw.log_w = vec![0.0; 2];
        let field = brute_field(&tiny_room());
        add_log_likelihoods(&mut raw, &scan, &field, &Pose2::default(), &Default::default()).expect("field");
        let expected = ((raw.log_w[0].exp() as f64 + raw.log_w[1].exp() as f64) / 2.0).ln() as f32;
        let robot = world.spawn((scan, OnMap(map), ParticleSet::from_poses(&poses))).id();
        world.run_system_once(mcl_likelihood_field).expect("system runs");
        let stats = *world.get::<LikelihoodStats>(robot).expect("ParticleSet requires LikelihoodStats");
        assert_eq!(stats.updates, 1, "one observation update recorded");
        assert!(
            (stats.mean_log_likelihood - expected).abs() < 1e-3,
            "log mean likelihood {} vs log((p0 + p1)/2) = {expected}",
            stats.mean_log_likelihood
        );
    }

    #[test]
    fn mcl_likelihood_field_ignores_nan_and_max_range() {
        let mut world = World::new();
        world.insert_resource(LikelihoodFieldParams::default());
        let map = spawn_room(&mut world, tiny_room());
        let mut scan = marched_scan(&tiny_room(), Pose2::new(0.6, 0.6, 0.0));
        scan.ranges_m.iter_mut().enumerate().for_each(|(i, r)| *r = [f32::NAN, 5.6, 0.01][i % 3]);
        let set = ParticleSet::from_poses(&[Pose2::new(0.6, 0.6, 0.0), Pose2::new(1.5, 0.3, 2.0)]);
        let robot = world.spawn((scan, OnMap(map), set)).id();
        world.run_system_once(mcl_likelihood_field).expect("NaN ranges must not crash");
        let w = world.get::<ParticleSet>(robot).expect("set").weights();
        assert!((w[0] - 0.5).abs() < 1e-6, "no usable beam → weights unchanged, got {w:?}");
    }

    #[test]
    fn mcl_likelihood_field_counts_degeneracy() {
        let mut world = World::new();
        world.insert_resource(LikelihoodFieldParams::default());
        let map = spawn_room(&mut world, tiny_room());
        let scan = marched_scan(&tiny_room(), Pose2::new(0.6, 0.6, 0.0));
        let set = ParticleSet::from_poses(&[Pose2::new(f32::NAN, 0.6, 0.0); 3]);
        let robot = world.spawn((scan, OnMap(map), set)).id();
        world.run_system_once(mcl_likelihood_field).expect("system runs");
        let w = world.get::<ParticleSet>(robot).expect("set").weights();
        assert!(w.iter().all(|&v| (v - 1.0 / 3.0).abs() < 1e-6), "all-NaN → uniform, got {w:?}");
        assert_eq!(world.get::<FilterHealth>(robot).expect("health").degeneracies, 1, "guard event counted");
    }

    #[test]
    fn likelihood_handles_rotated_map_origin() {
        let params = LikelihoodFieldParams::default();
        let (map, truth) = (tiny_room(), Pose2::new(0.6, 0.6, 0.3));
        let (field, scan) = (brute_field(&map), marched_scan(&map, truth));
        let probe = Pose2::new(0.7, 0.5, 0.2);
        let mut plain = ParticleSet::from_poses(&[truth, probe]);
        add_log_likelihoods(&mut plain, &scan, &field, &Pose2::default(), &params).expect("valid field");
        // Same room placed in the world at a rotated origin; particles move with it.
        let origin = Pose2::new(1.0, -2.0, 0.7);
        let moved: Vec<Pose2> = [truth, probe].iter().map(|p| origin.compose(p)).collect();
        let mut rotated = ParticleSet::from_poses(&moved);
        add_log_likelihoods(&mut rotated, &scan, &field, &origin, &params).expect("valid field");
        for k in 0..2 {
            assert!(
                (plain.log_w[k] - rotated.log_w[k]).abs() < 1e-2,
                "particle {k}: {plain:?} vs {rotated:?}"
            );
        }
    }

    #[test]
    fn likelihood_matches_reference_formula() {
        // Reference: per beam, DistanceField::surface_distance_at on the world endpoint and the exact
        // formula, on a map with a rotated origin; the kernel may differ only by its table step.
        let params = LikelihoodFieldParams { max_beams: 40, ..Default::default() };
        let mut map = tiny_room();
        map.origin = Pose2::new(-1.0, 0.5, -0.4);
        let field = DistanceField::build(&map);
        let truth = map.origin.compose(&Pose2::new(0.6, 0.6, 0.3));
        let mut scan = marched_scan(&map, truth);
        scan.ranges_m[100] = f32::NAN;
        let particles = [truth, map.origin.compose(&Pose2::new(1.2, 0.4, -2.0)), Pose2::new(30.0, 0.0, 0.0)];
        let mut set = ParticleSet::from_poses(&particles);
        set.log_w = vec![0.0; 3];
        add_log_likelihoods(&mut set, &scan, &field, &map.origin, &params).expect("valid field");
        for (k, p) in particles.iter().enumerate() {
            let expected: f32 = beam_indices(scan.ranges_m.len(), params.max_beams)
                .into_iter()
                .filter(|&i| scan.ranges_m[i].is_finite() && scan.ranges_m[i] < scan.range_max_m)
                .map(|i| {
                    let r = scan.ranges_m[i];
                    let a = p.yaw + scan.angle_min_rad + i as f32 * scan.angle_increment_rad;
                    let d = field.surface_distance_at(&map, p.x + r * a.cos(), p.y + r * a.sin(), 2.0);
                    (0.5 * (-d * d / (2.0 * 0.04)).exp() + 0.5 / scan.range_max_m).ln()
                })
                .sum();
            assert!(
                (set.log_w[k] - expected).abs() < 0.05,
                "particle {k}: kernel {} vs reference {expected}",
                set.log_w[k]
            );
        }
    }

    #[test]
    fn amcl_cube_sum_matches_its_formula_and_is_flatter() {
        let (map, truth) = (tiny_room(), Pose2::new(0.6, 0.6, 0.3));
        let (field, scan) = (brute_field(&map), marched_scan(&map, truth));
        let poses = [truth, Pose2::new(0.8, 0.5, 0.4)];
        let log_l = |combine| {
            let params = LikelihoodFieldParams { combine, ..Default::default() };
            let mut set = ParticleSet::from_poses(&poses);
            set.log_w = vec![0.0; 2];
            add_log_likelihoods(&mut set, &scan, &field, &Pose2::default(), &params).expect("valid field");
            set.log_w
        };
        let (product, cube) = (log_l(BeamCombination::Product), log_l(BeamCombination::AmclCubeSum));
        for k in 0..2 {
            let p = &poses[k];
            let expected: f32 = beam_indices(scan.ranges_m.len(), 60)
                .into_iter()
                .filter(|&i| scan.ranges_m[i] < scan.range_max_m)
                .map(|i| {
                    let (r, a) =
                        (scan.ranges_m[i], p.yaw + scan.angle_min_rad + i as f32 * scan.angle_increment_rad);
                    let d = field.surface_distance_at(&map, p.x + r * a.cos(), p.y + r * a.sin(), 2.0);
                    (0.5 * (-d * d / (2.0 * 0.04)).exp() + 0.5 / scan.range_max_m).powi(3)
                })
                .sum::<f32>()
                .ln_1p();
            assert!(
                (cube[k] - expected).abs() < 0.02,
                "particle {k}: kernel {} vs 1 + Σp³ = {expected}",
                cube[k]
            );
        }
        assert!(cube[0] > cube[1], "the truth still scores higher");
        assert!(cube[0] - cube[1] < (product[0] - product[1]) / 10.0, "{cube:?} vs {product:?}: far flatter");
    }

    /// A 0.1 m room open to unknown space on three sides, as a coarse SLAM map whose thin walls
    /// faded into unknown: only the left wall is occupied.
    fn room_bounded_by_unknown() -> OccupancyMap {
        let mut drawing = String::from("??????????????????????\n");
        for _ in 0..14 {
            drawing += "#..................???\n";
        }
        drawing += "??????????????????????\n";
        OccupancyMap::from_ascii(0.1, &drawing)
    }

    #[test]
    fn beams_ending_on_unknown_borders_are_hits() {
        let map = room_bounded_by_unknown();
        let truth = Pose2::new(1.03, 0.77, 0.4);
        let scan = marched_scan(&map, truth);
        let field = DistanceField::build(&map);
        assert_eq!(field, brute_field(&map), "the tests' brute force and the field agree");
        let params = LikelihoodFieldParams { max_beams: 228, ..Default::default() };
        let mut set = ParticleSet::from_poses(&[truth]);
        set.log_w = vec![0.0];
        add_log_likelihoods(&mut set, &scan, &field, &map.origin, &params).expect("valid field");
        let hits = scan.ranges_m.iter().filter(|&&r| r < scan.range_max_m).count() as f32;
        let best = (0.5 + 0.5 / scan.range_max_m).ln() * hits;
        assert!(
            set.log_w[0] > best - 0.05 * hits,
            "at the true pose every beam scores about as a hit: {} vs {best} for {hits} beams",
            set.log_w[0]
        );
    }

    #[test]
    fn cell_reads_are_the_endpoint_cells() {
        let map = room_bounded_by_unknown();
        let truth = Pose2::new(1.03, 0.77, 0.4);
        let scan = marched_scan(&map, truth);
        let field = DistanceField::build(&map);
        let score = |interpolate: bool, pose: Pose2| {
            let params = LikelihoodFieldParams { max_beams: 228, interpolate, ..Default::default() };
            let mut set = ParticleSet::from_poses(&[pose]);
            set.log_w = vec![0.0];
            add_log_likelihoods(&mut set, &scan, &field, &map.origin, &params).expect("valid field");
            set.log_w[0]
        };
        // 3 cm off, endpoints fall inside cells: the two reads differ.
        let off = Pose2::new(truth.x + 0.03, truth.y, truth.yaw);
        let (faces, cells) = (score(true, off), score(false, off));
        assert!((faces - cells).abs() > 1e-3, "interpolated {faces} vs cell reads {cells}");
        // One beam straight ahead, read by hand at its endpoint's cell.
        let ahead = LidarScan { ranges_m: vec![0.5], angle_min_rad: 0.0, angle_increment_rad: 0.0, ..scan };
        let params = LikelihoodFieldParams { interpolate: false, ..Default::default() };
        let mut set = ParticleSet::from_poses(&[truth]);
        set.log_w = vec![0.0];
        add_log_likelihoods(&mut set, &ahead, &field, &map.origin, &params).expect("valid field");
        let (s, c) = truth.yaw.sin_cos();
        let (gx, gy) = map.world_to_grid(truth.x + 0.5 * c, truth.y + 0.5 * s);
        let d = field.distances_m[gy as usize * field.width + gx as usize].min(2.0);
        let p = 0.5 * (-d * d / (2.0 * 0.2 * 0.2)).exp() + 0.5 / ahead.range_max_m;
        assert!((set.log_w[0] - p.ln()).abs() < 0.05, "cell read {} vs by hand {}", set.log_w[0], p.ln());
    }

    #[test]
    fn likelihood_rejects_short_field() {
        let map = tiny_room();
        let mut field = brute_field(&map);
        field.distances_m.truncate(10);
        let mut set = ParticleSet::from_poses(&[Pose2::new(0.6, 0.6, 0.0)]);
        let scan = marched_scan(&map, Pose2::new(0.6, 0.6, 0.0));
        let r = weigh_likelihood_field(&mut set, &scan, &field, &map.origin, &Default::default());
        assert!(matches!(r, Err(ParticleError::MalformedLayer { .. })), "short field is an error, got {r:?}");
    }

    #[test]
    fn beam_terms_weigh_many_scans_as_one_call_each_and_refuse_another_range() {
        let map = tiny_room();
        let field = DistanceField::build(&map);
        let poses = [Pose2::new(0.6, 0.6, 0.0), Pose2::new(1.2, 0.9, 1.0), Pose2::new(0.9, 0.5, -2.0)];
        let params = LikelihoodFieldParams { interpolate: false, ..Default::default() };
        let first = marched_scan(&map, poses[0]);
        let terms = BeamTerms::new(&params, first.range_max_m).expect("valid parameters");
        for truth in poses {
            let scan = marched_scan(&map, truth);
            let (mut once, mut each) = (ParticleSet::from_poses(&poses), ParticleSet::from_poses(&poses));
            terms.add_log_likelihoods(&mut once, &scan, &field, &map.origin).expect("same range");
            add_log_likelihoods(&mut each, &scan, &field, &map.origin, &params).expect("valid");
            assert_eq!(
                once.log_w, each.log_w,
                "terms built once weigh scan from {truth:?} as a fresh call does"
            );
        }
        let shorter = LidarScan { range_max_m: first.range_max_m / 2.0, ..first };
        let mut set = ParticleSet::from_poses(&poses);
        let r = terms.add_log_likelihoods(&mut set, &shorter, &field, &map.origin);
        assert!(matches!(r, Err(ParticleError::InvalidParam { field: "range_max_m", .. })), "got {r:?}");
        assert!(set.log_w.iter().all(|&l| l == set.log_w[0]), "a refused scan leaves the weights alone");
    }

    #[test]
    fn beam_indices_are_even_and_exact() {
        assert_eq!(beam_indices(228, 60).len(), 60);
        assert_eq!(beam_indices(5, 3), vec![0, 2, 4]);
        assert_eq!(beam_indices(4, 60), vec![0, 1, 2, 3], "fewer rays than max_beams → all");
        assert!(beam_indices(10, 0).is_empty());
    }

    #[test]
    fn likelihood_field_check_rejects_a_sigma_that_underflows_without_z_rand() {
        let tight = LikelihoodFieldParams { z_rand: 0.0, sigma_hit: 0.1, ..Default::default() };
        let message = tight.check().expect_err("exp(−2²/(2·0.1²)) = exp(−200) is 0 in f32");
        assert!(message.starts_with("sigma_hit: expected at least 0.152 m when z_rand = 0"), "{message}");
        assert_eq!(LikelihoodFieldParams { z_rand: 0.5, ..tight.clone() }.check(), Ok(()), "z_rand floors p");
        assert_eq!(LikelihoodFieldParams { sigma_hit: 0.153, ..tight.clone() }.check(), Ok(()), "just above");
        let cube = LikelihoodFieldParams { combine: BeamCombination::AmclCubeSum, ..tight.clone() };
        assert_eq!(cube.check(), Ok(()), "1 + Σp³ stays finite when p³ underflows");
        // Unchecked parameters reaching the kernel are an error, not a silent reset to uniform.
        let (map, truth) = (tiny_room(), Pose2::new(0.6, 0.6, 0.3));
        let mut set = ParticleSet::from_poses(&[truth, Pose2::new(30.0, 0.0, 0.0)]);
        let before = set.clone();
        let r = add_log_likelihoods(
            &mut set,
            &marched_scan(&map, truth),
            &brute_field(&map),
            &map.origin,
            &tight,
        );
        assert!(matches!(r, Err(ParticleError::InvalidParam { field: "sigma_hit, z_rand", .. })), "{r:?}");
        assert_eq!(set, before, "the set is left untouched");
        let ok = LikelihoodFieldParams { sigma_hit: 0.153, ..tight };
        add_log_likelihoods(&mut set, &marched_scan(&map, truth), &brute_field(&map), &map.origin, &ok)
            .expect("the smallest accepted sigma_hit keeps every table entry finite");
        assert!(set.log_w.iter().all(|l| l.is_finite()), "{:?}", set.log_w);
    }

    #[test]
    fn likelihood_field_underflow_fails_when_the_schedule_loads() {
        let text = r#"Schedule(steps: [("lidar", ()), ("init_particles", ()),
            ("mcl_likelihood_field", (z_rand: 0.0, sigma_hit: 0.1))])"#;
        let registry = crate::compose::standard_registry();
        let path = std::path::Path::new("tight.ron");
        let Err(err) = crate::compose::Pipeline::parse(text, path, &registry) else { panic!("rejected") };
        let err = err.to_string();
        assert!(err.contains("tight.ron") && err.contains("sigma_hit: expected at least"), "{err}");
    }
}
