//! The classical particle filter (MCL with the likelihood-field or the beam model) on logged data,
//! without the simulator: a plain struct that owns the map layers, the particle set and its RNG,
//! and runs the same kernels as the ECS systems, in the same order — transition → observation
//! model → soft resampling → estimate.
//!
//! ```no_run
//! use apfn::replay::{InitialGuess, Localizer, LocalizerParams};
//! use apfn::world::{map::load_ros_map, Pose2};
//! # fn scans() -> Vec<(Pose2, apfn::sense::LidarScan)> { Vec::new() }
//! let map = load_ros_map("office.yaml".as_ref())?;
//! let guess = InitialGuess::Pose(Pose2::new(2.0, 1.5, 0.0));
//! let mut filter = Localizer::new(map, LocalizerParams::default(), guess, 7)?;
//! for (odom_delta, scan) in scans() {
//!     let estimate = filter.update(odom_delta, &scan); // motion since the previous scan
//!     println!("{:?}", estimate.pose);
//! }
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```
//!
//! Use [`Localizer::observe`] for the first scan (nothing has moved yet), [`Localizer::update`]
//! after. Same map, params, guess, seed and inputs → identical estimates, on any thread count.

use crate::particles::{
    BeamModelParams, FilterHealth, Guard, InitParams, LikelihoodFieldParams, ParticleSet, PoseEstimate,
    ResampleParams, Task, TransitionParams, draw_around_guess, draw_initial_set, estimate_pose, propagate,
    resample_with, should_resample, weigh_beam_model, weigh_likelihood_field,
};
use crate::replay::error::ReplayError;
use crate::replay::fit::scan_fit;
use crate::replay::log::{EstimateLine, LogLine};
use crate::sense::{LidarScan, RayGrid};
use crate::world::map::{DistanceField, TraversableMap};
use crate::world::rng::stream;
use crate::world::{OccupancyMap, Pose2, RobotParams};
use rand::Rng;
use rand_pcg::Pcg64Mcg;
use serde::{Deserialize, Serialize};
use std::time::Instant;

/// Everything the filter is configured by; defaults are the ECS systems' defaults.
#[derive(Serialize, Deserialize, Clone, Debug, PartialEq)]
#[serde(default, deny_unknown_fields)]
pub struct LocalizerParams {
    /// Task, particle count and the spread of the initial set.
    pub init: InitParams,
    /// Motion noise added to every odometry delta.
    pub transition: TransitionParams,
    /// Which observation model weighs the particles.
    pub model: ReplayModel,
    /// AMCL's likelihood-field observation model (used when `model` is `likelihood_field`).
    pub likelihood_field: LikelihoodFieldParams,
    /// AMCL's beam model (used when `model` is `beam`).
    pub beam_model: BeamModelParams,
    /// Soft resampling (α) and its ESS policy.
    pub resample: ResampleParams,
    /// Robot radius used to erode free space into the traversable map, metres (default: the
    /// simulated robot's 0.18 m). Uniform draws (semi-global, global) use traversable cells only.
    pub robot_radius_m: f32,
}

impl Default for LocalizerParams {
    fn default() -> Self {
        Self {
            init: InitParams::default(),
            transition: TransitionParams::default(),
            model: ReplayModel::default(),
            likelihood_field: LikelihoodFieldParams::default(),
            beam_model: BeamModelParams::default(),
            resample: ResampleParams::default(),
            robot_radius_m: RobotParams::default().radius_m,
        }
    }
}

/// The observation models the replay filter offers, as nav2's AMCL does (`laser_model_type`).
/// Spelled `likelihood_field` and `beam` in RON, JSON and on the command line.
#[derive(Serialize, Deserialize, clap::ValueEnum, Clone, Copy, Debug, Default, PartialEq, Eq)]
#[serde(rename_all = "snake_case")]
#[value(rename_all = "snake_case")]
pub enum ReplayModel {
    /// One distance lookup per beam endpoint: fast, AMCL's default.
    #[default]
    LikelihoodField,
    /// One ray cast per beam, scoring the measured range against the expected one.
    Beam,
}

impl LocalizerParams {
    /// Checks the ranges a caller could get wrong.
    pub fn validate(&self) -> Result<(), ReplayError> {
        if let Some(n) = self.init.particles
            && !crate::limits::PARTICLES.contains(n)
        {
            return Err(ReplayError::InvalidParam {
                field: "particles",
                expected: crate::limits::PARTICLES.expected,
            });
        }
        if !(self.robot_radius_m >= 0.0 && self.robot_radius_m.is_finite()) {
            return Err(ReplayError::InvalidParam { field: "robot_radius_m", expected: "a radius ≥ 0 m" });
        }
        self.resample.validate()?;
        Ok(())
    }
}

/// What the filter is told about the start pose.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum InitialGuess {
    /// A pose the user believes in (like AMCL's initial pose): tracking draws a Gaussian
    /// (σ = `tracking_sigma_m` / `tracking_sigma_deg`) around it, semi-global draws uniformly over
    /// traversable cells in the box around it. The pose is used as it is.
    Pose(Pose2),
    /// The true start pose of a simulated log: perturbed as the task prescribes (paper §V), then
    /// drawn around, exactly as `init_particles` does in the simulator.
    PerturbedTruth(Pose2),
    /// Nothing known: only task global can start from this.
    Unknown,
}

/// A particle filter over one map, fed one scan at a time.
pub struct Localizer {
    map: OccupancyMap,
    field: DistanceField,
    /// Built only for the beam model, which ray-casts through it.
    rays: Option<RayGrid>,
    traversable: TraversableMap,
    set: ParticleSet,
    params: LocalizerParams,
    rng: Pcg64Mcg,
    health: FilterHealth,
    estimate: PoseEstimate,
    /// What the initial set was drawn around (`None`: uniform over the map).
    start_centre: Option<Pose2>,
    fell_back_to_global: bool,
}

impl Localizer {
    /// Builds the map layers and draws the initial set for `params.init.task` from `init`.
    /// Errors on invalid params, a map without traversable space, or a tracking / semi-global
    /// task with [`InitialGuess::Unknown`]. A semi-global box without a traversable cell falls back
    /// to a global draw ([`Localizer::fell_back_to_global`] tells).
    pub fn new(
        map: OccupancyMap,
        params: LocalizerParams,
        init: InitialGuess,
        seed: u64,
    ) -> Result<Self, ReplayError> {
        params.validate()?;
        let traversable = TraversableMap::build(&map, params.robot_radius_m)?;
        let field = DistanceField::build(&map);
        let rays = (params.model == ReplayModel::Beam).then(|| RayGrid::from_map(&map));
        let mut rng = stream(&[seed]);
        let task = params.init.task;
        let drawn = match (task, init) {
            (Task::Global, _) => draw_around_guess(&params.init, None, &map, &traversable, &mut rng)?,
            (_, InitialGuess::Unknown) => return Err(ReplayError::NoInitialPose { task }),
            (_, InitialGuess::PerturbedTruth(truth)) => {
                draw_initial_set(&params.init, &truth, &map, &traversable, &mut rng)?
            }
            (_, InitialGuess::Pose(guess)) => {
                draw_around_guess(&params.init, Some(guess), &map, &traversable, &mut rng)?
            }
        };
        let (set, start_centre, fell_back_to_global) = (drawn.set, drawn.guess, drawn.fell_back_to_global);
        let estimate = estimate_pose(&set).unwrap_or_default();
        let health = FilterHealth { reinitialisations: u32::from(fell_back_to_global), ..Default::default() };
        Ok(Self {
            map,
            field,
            rays,
            traversable,
            set,
            params,
            rng,
            health,
            estimate,
            start_centre,
            fell_back_to_global,
        })
    }

    /// One filter step: moves every particle by `odom_delta` (the odometry motion since the
    /// previous scan, in the previous robot frame, as `prev.between(&curr)` gives) plus noise,
    /// then [`observe`](Self::observe)s `scan`.
    pub fn update(&mut self, odom_delta: Pose2, scan: &LidarScan) -> PoseEstimate {
        let key: u64 = self.rng.random();
        propagate(&mut self.set, &odom_delta, &self.params.transition, key);
        self.observe(scan)
    }

    /// The observation half of a step, without motion (for the first scan): weighs the particles
    /// by the chosen model (each skips or maps unusable readings its own way), resamples when the
    /// ESS policy fires, and returns the new estimate.
    pub fn observe(&mut self, scan: &LidarScan) -> PoseEstimate {
        let weighed = match &self.rays {
            Some(rays) => weigh_beam_model(&mut self.set, scan, rays, &self.params.beam_model),
            None => {
                let lf = &self.params.likelihood_field;
                weigh_likelihood_field(&mut self.set, scan, &self.field, &self.map.origin, lf)
            }
        };
        match weighed {
            Ok((Guard::ResetToUniform, _)) => self.health.degeneracies += 1,
            Ok(_) => {}
            // The layers are built from the map in `new`; what remains is a scan with a bad
            // range_max, which the beam model refuses.
            Err(e) => tracing::warn!("replay localizer: {e}"),
        }
        if should_resample(&self.set, self.params.resample.ess_threshold) {
            resample_with(&mut self.set, &self.params.resample, &mut self.rng);
        }
        if let Some(estimate) = estimate_pose(&self.set) {
            self.estimate = estimate;
        }
        self.estimate
    }

    /// Runs the whole log: [`observe`](Self::observe) on the first line, [`update`](Self::update)
    /// with the odometry motion between consecutive lines after. `after_line` is called once per
    /// line (for progress bars).
    pub fn replay(&mut self, lines: &[LogLine], mut after_line: impl FnMut()) -> Vec<EstimateLine> {
        let mut out = Vec::with_capacity(lines.len());
        for (k, line) in lines.iter().enumerate() {
            let started = Instant::now();
            let scan = line.scan();
            let estimate = match k.checked_sub(1).map(|p| &lines[p]) {
                None => self.observe(&scan),
                Some(previous) => self.update(previous.odom_pose().between(&line.odom_pose()), &scan),
            };
            let update_ms = started.elapsed().as_secs_f64() * 1e3;
            let (p, c) = (estimate.pose, estimate.cov);
            let cov = [c[0][0], c[0][1], c[0][2], c[1][0], c[1][1], c[1][2], c[2][0], c[2][1], c[2][2]];
            out.push(EstimateLine { t: line.t, pose: [p.x, p.y, p.yaw], cov, update_ms });
            after_line();
        }
        out
    }

    /// The latest estimate (that of the initial set before any scan).
    pub fn estimate(&self) -> PoseEstimate {
        self.estimate
    }

    /// The particle set.
    pub fn particles(&self) -> &ParticleSet {
        &self.set
    }

    /// Guard events so far: weights reset to uniform, and semi-global draws that fell back to global.
    pub fn health(&self) -> FilterHealth {
        self.health
    }

    /// The pose the initial set was drawn around (for a perturbed truth, after the perturbation);
    /// `None` for a draw over the whole map.
    pub fn start_centre(&self) -> Option<Pose2> {
        self.start_centre
    }

    /// Whether the semi-global box held no traversable cell and the set was drawn globally.
    pub fn fell_back_to_global(&self) -> bool {
        self.fell_back_to_global
    }

    pub fn map(&self) -> &OccupancyMap {
        &self.map
    }

    /// How well `scan` fits the map seen from `pose` ([`scan_fit`]).
    pub fn scan_fit(&self, scan: &LidarScan, pose: &Pose2) -> Option<f32> {
        scan_fit(scan, pose, &self.map, &self.field)
    }

    pub fn traversable(&self) -> &TraversableMap {
        &self.traversable
    }

    pub fn params(&self) -> &LocalizerParams {
        &self.params
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sense::{LidarParams, RayGrid, cast_scan};
    use crate::testing::tiny_room;

    fn scan_at(map: &OccupancyMap, pose: Pose2) -> LidarScan {
        let mut scan = LidarScan::default();
        cast_scan(&RayGrid::from_map(map), pose, &[], &LidarParams::default(), &mut scan);
        scan
    }

    fn small_radius() -> LocalizerParams {
        LocalizerParams { robot_radius_m: 0.05, ..Default::default() }
    }

    #[test]
    fn localizer_tracking_draws_around_the_given_pose() {
        let guess = Pose2::new(1.0, 0.7, 0.2);
        let filter =
            Localizer::new(tiny_room(), small_radius(), InitialGuess::Pose(guess), 1).expect("filter");
        let e = filter.estimate();
        assert_eq!(filter.particles().len(), 300, "tracking default: 300 particles");
        assert!(e.pose.distance(&guess) < 0.06, "300 draws of σ 0.3 m average near the guess: {e:?}");
        assert!((e.cov[0][0].sqrt() - 0.3).abs() < 0.05, "spread ≈ 0.3 m: {:?}", e.cov);
    }

    #[test]
    fn localizer_observe_pulls_towards_the_scan_pose_with_either_model() {
        let map = tiny_room();
        let truth = Pose2::new(0.6, 0.6, 0.3);
        let start = InitialGuess::Pose(Pose2::new(0.75, 0.5, 0.3));
        for model in [ReplayModel::LikelihoodField, ReplayModel::Beam] {
            let params = LocalizerParams { model, ..small_radius() };
            let mut filter = Localizer::new(map.clone(), params, start, 2).expect("filter");
            let before = filter.estimate().pose.distance(&truth);
            let scan = scan_at(&map, truth);
            let mut estimate = filter.observe(&scan);
            for _ in 0..5 {
                estimate = filter.update(Pose2::default(), &scan);
            }
            let after = estimate.pose.distance(&truth);
            assert!(after < 0.1 && after < before, "{model:?}: error {before} m → {after} m after six scans");
        }
    }

    #[test]
    fn localizer_rejects_missing_guess_and_zero_particles() {
        let r = Localizer::new(tiny_room(), small_radius(), InitialGuess::Unknown, 3);
        assert!(
            matches!(r, Err(ReplayError::NoInitialPose { task: Task::Tracking })),
            "no guess for tracking"
        );
        let mut params = small_radius();
        params.init.particles = Some(0);
        let r = Localizer::new(tiny_room(), params, InitialGuess::Pose(Pose2::default()), 3);
        assert!(matches!(r, Err(ReplayError::InvalidParam { field: "particles", .. })), "zero particles");
    }

    #[test]
    fn localizer_semi_global_and_global_use_traversable_cells() {
        let mut params = small_radius();
        params.init.task = Task::SemiGlobal;
        params.init.semi_global_box_m = 0.4;
        let guess = Pose2::new(1.0, 0.7, 0.0);
        let filter =
            Localizer::new(tiny_room(), params.clone(), InitialGuess::Pose(guess), 4).expect("filter");
        let set = filter.particles();
        assert!(!filter.fell_back_to_global());
        let in_box = (0..set.len()).all(|k| (set.x[k] - 1.0).abs() <= 0.25 && (set.y[k] - 0.7).abs() <= 0.25);
        assert!(in_box, "semi-global particles stay in the 0.4 m box around the guess");
        params.init.task = Task::Global;
        let filter =
            Localizer::new(tiny_room(), params, InitialGuess::Unknown, 4).expect("global needs no guess");
        assert_eq!(filter.particles().len(), 3000, "global default: 3,000 particles");
    }
}
