//! The particle filter on logged data: a small bevy `App` holding one map and one robot, fed one
//! recorded reading per step by `log_feed` and running the simulator's own filter systems —
//! `init_particles → transition → likelihood → resample → estimate`, with the likelihood of the
//! likelihood field, the beam model or PF-net (after `local_grid`, which builds its 56×56 input
//! from the scan). Nothing of the filter is written twice: what runs on simulated data runs here.
//!
//! ```no_run
//! use apfn::replay::{InitialGuess, Localizer, LocalizerParams};
//! use apfn::world::{map::load_ros_map, Pose2};
//! # fn scans() -> Vec<(Pose2, apfn::sense::LidarScan)> { Vec::new() }
//! let map = load_ros_map("office.yaml".as_ref())?;
//! let guess = InitialGuess::Pose(Pose2::new(2.0, 1.5, 0.0));
//! let mut filter = Localizer::new(map, LocalizerParams::default(), guess, 7)?;
//! for (odom_delta, scan) in scans() {
//!     let estimate = filter.update(odom_delta, &scan); // motion since the previous scan (zero first)
//!     println!("{:?}", estimate.pose);
//! }
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```
//!
//! Same map, params, guess, seed and inputs → identical estimates, on any thread count.

use crate::compose::{Pipeline, map_layers, standard_registry};
use crate::particles::{
    BeamModelParams, FilterHealth, InitParams, LikelihoodFieldParams, NeedsInit, ParticleSet,
    PfNetLikelihoodParams, PoseEstimate, ResampleParams, StartGuess, Task, TransitionParams, estimate,
    init_particles, local_grid_for, shared_model,
};
use crate::plugin::ApfnPlugin;
use crate::replay::error::ReplayError;
use crate::replay::feed::{LogFeed, Reading};
use crate::replay::fit::scan_fit;
use crate::replay::log::{EstimateLine, LogLine};
use crate::sense::{LidarScan, LocalGrid, LocalGridParams, Odometry, ScanMatchingParams};
use crate::world::map::{DistanceField, TraversableMap};
use crate::world::rng::stream;
use crate::world::{OccupancyMap, OnMap, Pose2, Robot, RobotId, RobotParams, RobotRngs, TruePose};
use bevy::ecs::system::RunSystemOnce;
use bevy::prelude::*;
use rand::Rng;
use serde::{Deserialize, Serialize};
use std::path::Path;
use std::time::Instant;

/// Everything the filter is configured by; defaults are the ECS systems' defaults.
#[derive(Serialize, Deserialize, Clone, Debug, PartialEq)]
#[serde(default, deny_unknown_fields)]
pub struct LocalizerParams {
    /// Task, particle count and the spread of the initial set.
    pub init: InitParams,
    /// Motion noise added to every odometry delta.
    pub transition: TransitionParams,
    /// Aligns each scan with the one before to narrow the odometry's heading change
    /// (`scan_matching`, laser odometry); `None`: the odometry as logged.
    pub scan_matching: Option<ScanMatchingParams>,
    /// Which observation model weighs the particles.
    pub model: ReplayModel,
    /// AMCL's likelihood-field observation model (used when `model` is `likelihood_field`).
    pub likelihood_field: LikelihoodFieldParams,
    /// AMCL's beam model (used when `model` is `beam`).
    pub beam_model: BeamModelParams,
    /// PF-net's learned model (used when `model` is `pfnet`; default: the shipped checkpoint).
    pub pfnet: PfNetLikelihoodParams,
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
            scan_matching: None,
            model: ReplayModel::default(),
            likelihood_field: LikelihoodFieldParams::default(),
            beam_model: BeamModelParams::default(),
            pfnet: PfNetLikelihoodParams {
                checkpoint: Some(SHIPPED_PFNET.into()),
                ..PfNetLikelihoodParams::default()
            },
            resample: ResampleParams::default(),
            robot_radius_m: RobotParams::default().radius_m,
        }
    }
}

/// The shipped PF-net checkpoint, relative to the working directory (the repository's root).
pub const SHIPPED_PFNET: &str = "models/pfnet_compact.safetensors";

/// The observation models the replay filter offers: AMCL's two (`laser_model_type`) and PF-net.
/// Spelled `likelihood_field`, `beam` and `pfnet` in RON, JSON and on the command line.
#[derive(Serialize, Deserialize, clap::ValueEnum, Clone, Copy, Debug, Default, PartialEq, Eq)]
#[serde(rename_all = "snake_case")]
#[value(rename_all = "snake_case")]
pub enum ReplayModel {
    /// One distance lookup per beam endpoint: fast, AMCL's default.
    #[default]
    LikelihoodField,
    /// One ray cast per beam, scoring the measured range against the expected one.
    Beam,
    /// The learned observation model of the paper, on the 56×56 occupancy grid of the scan.
    Pfnet,
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

    /// The filter as a schedule file would spell it: `log_feed` where the simulator senses, then
    /// the simulator's filter systems with these parameters.
    pub fn schedule(&self) -> String {
        fn ron(params: &impl Serialize) -> String {
            ron::to_string(params).expect("filter parameters are plain data and serialise")
        }
        let (grid, likelihood) = match self.model {
            ReplayModel::LikelihoodField => {
                (String::new(), format!("(\"mcl_likelihood_field\", {})", ron(&self.likelihood_field)))
            }
            ReplayModel::Beam => (String::new(), format!("(\"mcl_beam_model\", {})", ron(&self.beam_model))),
            ReplayModel::Pfnet => {
                // The grid the network reads (a wide view's too). A checkpoint that does not
                // load is named when the schedule is checked.
                let model = shared_model(&self.pfnet).ok();
                let grid = model.map_or_else(LocalGridParams::default, |model| local_grid_for(&model.config));
                let grid = format!("(\"local_grid\", {}),", ron(&grid));
                (grid, format!("(\"pfnet_likelihood\", {})", ron(&self.pfnet)))
            }
        };
        let matching = match &self.scan_matching {
            Some(params) => format!("(\"scan_matching\", {}),", ron(params)),
            None => String::new(),
        };
        format!(
            "Schedule(steps: [(\"log_feed\", ()), {matching} {grid} (\"init_particles\", {}), \
             (\"transition\", {}), {likelihood}, (\"resample\", {}), (\"estimate\", ())])",
            ron(&self.init),
            ron(&self.transition),
            ron(&self.resample)
        )
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
    app: App,
    robot: Entity,
    map: Entity,
    params: LocalizerParams,
    systems: Vec<&'static str>,
}

impl Localizer {
    /// Builds the map layers and the filter's schedule, and draws the initial set for
    /// `params.init.task` from `init` (with `init_particles`, as the first step would). Errors on
    /// invalid params, a checkpoint that does not load, a map without traversable space, or a
    /// tracking / semi-global task with [`InitialGuess::Unknown`]. A semi-global box without a
    /// traversable cell falls back to a global draw ([`Localizer::fell_back_to_global`] tells).
    pub fn new(
        map: OccupancyMap,
        params: LocalizerParams,
        init: InitialGuess,
        seed: u64,
    ) -> Result<Self, ReplayError> {
        params.validate()?;
        let task = params.init.task;
        if task != Task::Global && init == InitialGuess::Unknown {
            return Err(ReplayError::NoInitialPose { task });
        }
        let traversable = TraversableMap::build(&map, params.robot_radius_m)?;
        let pipeline =
            Pipeline::parse(&params.schedule(), Path::new("the localize flags"), &standard_registry())
                .map_err(|e| ReplayError::Schedule(e.to_string()))?;
        let systems = pipeline.names();
        let mut app = App::new();
        app.add_plugins(ApfnPlugin { pipeline });
        let world = app.world_mut();
        let map = world.spawn(map_layers(&map, traversable)).id();
        let start = match init {
            InitialGuess::Pose(pose) | InitialGuess::PerturbedTruth(pose) => pose,
            InitialGuess::Unknown => Pose2::default(),
        };
        let rngs = RobotRngs::seeded(stream(&[seed]).random());
        let robot = world
            .spawn((
                (Robot, RobotId(0), TruePose(start), OnMap(map), rngs),
                (LogFeed::default(), Odometry::default(), LidarScan::default(), LocalGrid::default()),
                (ParticleSet::default(), NeedsInit),
            ))
            .id();
        if let InitialGuess::Pose(pose) = init {
            world.entity_mut(robot).insert(StartGuess(pose));
        }
        world.run_system_once(init_particles).expect("the schedule inserted InitParams");
        world.run_system_once(estimate).expect("estimate needs no resource");
        // Particles are validated above and the traversable map is not empty, so the draw succeeded.
        debug_assert!(world.get::<NeedsInit>(robot).is_none(), "the initial set was drawn");
        Ok(Self { app, robot, map, params, systems })
    }

    /// One filter step: moves every particle by `odom_delta` (the odometry motion since the
    /// previous scan, in the previous robot frame, as `prev.between(&curr)` gives; zero for the
    /// first scan) plus the transition noise, weighs them by `scan`, resamples when the ESS policy
    /// fires, and returns the new estimate.
    pub fn update(&mut self, odom_delta: Pose2, scan: &LidarScan) -> PoseEstimate {
        self.step(Reading { odom_delta, scan: scan.clone(), truth: None })
    }

    fn step(&mut self, reading: Reading) -> PoseEstimate {
        self.app
            .world_mut()
            .get_mut::<LogFeed>(self.robot)
            .expect("the robot has a feed")
            .0
            .push_back(reading);
        self.app.update();
        self.estimate()
    }

    /// Runs the whole log, one [`update`](Self::update) per line with the odometry motion since
    /// the previous line. `after_line` is called once per line (for progress bars).
    pub fn replay(&mut self, lines: &[LogLine], mut after_line: impl FnMut()) -> Vec<EstimateLine> {
        let mut out = Vec::with_capacity(lines.len());
        for (k, line) in lines.iter().enumerate() {
            let started = Instant::now();
            let estimate = self.step(Reading::from_line(k.checked_sub(1).map(|p| &lines[p]), line));
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
        *self.robot_part::<PoseEstimate>()
    }

    /// The particle set.
    pub fn particles(&self) -> &ParticleSet {
        self.robot_part()
    }

    /// Guard events so far: weights reset to uniform, and semi-global draws that fell back to global.
    pub fn health(&self) -> FilterHealth {
        *self.robot_part::<FilterHealth>()
    }

    /// Whether the semi-global box held no traversable cell and the set was drawn globally.
    pub fn fell_back_to_global(&self) -> bool {
        self.health().reinitialisations > 0
    }

    pub fn map(&self) -> &OccupancyMap {
        self.map_part()
    }

    /// How well `scan` fits the map seen from `pose` ([`scan_fit`]).
    pub fn scan_fit(&self, scan: &LidarScan, pose: &Pose2) -> Option<f32> {
        scan_fit(scan, pose, self.map(), self.map_part::<DistanceField>())
    }

    pub fn params(&self) -> &LocalizerParams {
        &self.params
    }

    /// The registered systems one update runs, in order.
    pub fn systems(&self) -> &[&'static str] {
        &self.systems
    }

    fn robot_part<C: Component>(&self) -> &C {
        self.app.world().get::<C>(self.robot).expect("the robot was spawned with its filter parts")
    }

    fn map_part<C: Component>(&self) -> &C {
        self.app.world().get::<C>(self.map).expect("the map was spawned with its layers")
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
    fn localizer_runs_the_simulators_filter_systems_behind_log_feed() {
        let guess = InitialGuess::Pose(Pose2::new(1.0, 0.7, 0.2));
        let systems = |model| {
            let params = LocalizerParams { model, ..small_radius() };
            Localizer::new(tiny_room(), params, guess, 1).expect("filter").systems().to_vec()
        };
        let filter = ["init_particles", "transition", "mcl_likelihood_field", "resample", "estimate"];
        assert_eq!(systems(ReplayModel::LikelihoodField), [&["log_feed"][..], &filter].concat());
        assert_eq!(systems(ReplayModel::Beam)[3], "mcl_beam_model");
        let params = LocalizerParams { scan_matching: Some(ScanMatchingParams::default()), ..small_radius() };
        let matched = Localizer::new(tiny_room(), params, guess, 1).expect("filter").systems().to_vec();
        assert_eq!(
            matched[..2],
            ["log_feed", "scan_matching"],
            "the scan is matched before the filter moves"
        );
    }

    /// A PF-net with a wide view gets the wide grid it reads, over its own window, and one laying
    /// the scan on its maps the grid over the window it was trained with.
    #[test]
    fn localizer_feeds_a_wide_view_its_window() {
        use crate::nn::pfnet::{PfNet, PfNetConfig, ScanOnMap, WideView};
        use crate::particles::LikelihoodStats;
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("wide_view.safetensors");
        let view = WideView { map_cell_m: 0.2, grid_extent_m: 9.0, own_map_encoder: true };
        let config = PfNetConfig {
            scan_on_map: Some(ScanOnMap { grid_extent_m: 4.0, own_encoder: false }),
            ..PfNetConfig::compact().with_wide_view(Some(view))
        };
        PfNet::new(config, 1).unwrap().save(&path).unwrap();
        let pfnet = PfNetLikelihoodParams { checkpoint: Some(path.display().to_string()), ..default() };
        let params = LocalizerParams { model: ReplayModel::Pfnet, pfnet, ..small_radius() };
        let guess = InitialGuess::Pose(Pose2::new(1.0, 0.7, 0.2));
        let mut filter = Localizer::new(tiny_room(), params, guess, 1).expect("filter");
        filter.app.update();
        let grid = filter.app.world().get::<LocalGrid>(filter.robot).unwrap();
        assert_eq!(grid.wide.as_ref().map(|wide| wide.extent_m), Some(9.0));
        assert_eq!(grid.extent_m, 4.0);
        let stats = filter.app.world().get::<LikelihoodStats>(filter.robot).unwrap();
        assert_eq!(stats.updates, 1, "the network weighs the grid it was given");
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
            let mut estimate = filter.update(Pose2::default(), &scan);
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
