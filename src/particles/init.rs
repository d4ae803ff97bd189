//! Initial particle sets for the paper's three tasks: tracking (Gaussian around a perturbed true
//! pose), semi-global (uniform over traversable cells in a box around such a guess) and global
//! (uniform over every traversable cell).
//!
//! Contract: a robot's filter starts afresh when it carries [`NeedsInit`] (spawned with it, and
//! `episode_reset` inserts it); `init_particles` draws those robots' sets, removes the marker and
//! leaves every other set alone, so it can run every step at no cost. A set that is empty
//! *without* the marker lost its particles mid-episode: that is reported, never redrawn (a
//! redraw would centre the new set on the true pose).

use crate::params::{StepParams, expect_param};
use crate::particles::set::{FilterHealth, ParticleError, ParticleSet};
use crate::world::map::TraversableMap;
use crate::world::{FilterRng, OccupancyMap, OnMap, Pose2, TruePose, wrap_angle};
use bevy::prelude::*;
use rand::Rng;
use rand_distr::StandardNormal;
use serde::{Deserialize, Serialize};
use std::f32::consts::PI;

/// How much the filter knows about the start pose (paper §V). Spelled `tracking`, `semi_global`
/// and `global` in RON, JSON, tables and on the command line.
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Eq)]
#[serde(rename_all = "snake_case")]
pub enum Task {
    Tracking,
    SemiGlobal,
    Global,
}

impl Task {
    pub const ALL: [Task; 3] = [Task::Tracking, Task::SemiGlobal, Task::Global];

    /// The task's name in files and tables.
    pub fn name(self) -> &'static str {
        match self {
            Task::Tracking => "tracking",
            Task::SemiGlobal => "semi_global",
            Task::Global => "global",
        }
    }

    /// The paper's particle counts: tracking 300, semi-global 500, global 3,000.
    pub fn default_particles(self) -> usize {
        match self {
            Task::Tracking => 300,
            Task::SemiGlobal => 500,
            Task::Global => 3000,
        }
    }
}

/// How `init_particles` draws a fresh set.
#[derive(Resource, Serialize, Deserialize, Clone, Debug, PartialEq)]
#[serde(default, deny_unknown_fields)]
pub struct InitParams {
    /// Which task's initial belief to draw (default: tracking).
    pub task: Task,
    /// Number of particles; `None` = the task's paper default (300 / 500 / 3,000).
    pub particles: Option<usize>,
    /// Std-dev of the guess around the true pose and of particles around the guess, metres (paper: 0.3).
    pub tracking_sigma_m: f32,
    /// Same, for the heading, degrees (paper: 30).
    pub tracking_sigma_deg: f32,
    /// Side of the semi-global box centred on the guess, metres (paper text: 3.3; authors' code: 2.1).
    pub semi_global_box_m: f32,
    /// Training on several tasks at once: when not empty, every fresh set draws its task
    /// uniformly from this list with the robot's filter RNG (repeat a task to weigh it more), and
    /// `task` is unused. Evaluation cells name their task, so they clear it. Default: empty.
    pub mix: Vec<Task>,
}

impl Default for InitParams {
    fn default() -> Self {
        Self {
            task: Task::Tracking,
            particles: None,
            tracking_sigma_m: 0.3,
            tracking_sigma_deg: 30.0,
            semi_global_box_m: 3.3,
            mix: Vec::new(),
        }
    }
}

impl StepParams for InitParams {
    fn check(&self) -> Result<(), String> {
        if let Some(n) = self.particles {
            crate::limits::PARTICLES.check("particles", n)?;
        }
        expect_param(self.tracking_sigma_m >= 0.0, "tracking_sigma_m", "a std-dev ≥ 0 m")?;
        expect_param(self.tracking_sigma_deg >= 0.0, "tracking_sigma_deg", "a std-dev ≥ 0°")?;
        expect_param(self.semi_global_box_m > 0.0, "semi_global_box_m", "a box side > 0 m")
    }
}

impl InitParams {
    pub fn particle_count(&self) -> usize {
        self.particles.unwrap_or(self.task.default_particles())
    }

    /// These parameters for one fresh set: `mix` resolved to one task drawn from it, or `None`
    /// when there is no mix (use `self` as it is; nothing is drawn, so runs without a mix keep
    /// their random streams).
    fn drawn_from_mix(&self, rng: &mut impl Rng) -> Option<InitParams> {
        if self.mix.is_empty() {
            return None;
        }
        let task = self.mix[rng.random_range(0..self.mix.len())];
        Some(InitParams { task, mix: Vec::new(), ..self.clone() })
    }
}

/// Marks a robot whose particle set is to be drawn by the next `init_particles`.
#[derive(Component, Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct NeedsInit;

/// A start pose someone told the filter (like AMCL's initial pose): `init_particles` draws around
/// it as it is, instead of around the true pose perturbed as the task prescribes.
#[derive(Component, Clone, Copy, Debug, PartialEq)]
pub struct StartGuess(pub Pose2);

/// A freshly drawn set, with what the draw was centred on.
#[derive(Clone, Debug, PartialEq)]
pub struct Initialised {
    pub set: ParticleSet,
    /// The perturbed true pose the set is centred on (`None` for a global draw).
    pub guess: Option<Pose2>,
    /// The semi-global box held no traversable cell, so the set was drawn globally instead.
    pub fell_back_to_global: bool,
}

/// `pose` perturbed by N(0, σ) on x, y and yaw.
fn gaussian_around(pose: &Pose2, sigma_m: f32, sigma_rad: f32, rng: &mut impl Rng) -> Pose2 {
    Pose2::new(
        pose.x + sigma_m * rng.sample::<f32, _>(StandardNormal),
        pose.y + sigma_m * rng.sample::<f32, _>(StandardNormal),
        wrap_angle(pose.yaw + sigma_rad * rng.sample::<f32, _>(StandardNormal)),
    )
}

/// `n` poses uniform within the given cells (a cell, then a point inside it), uniform heading.
fn uniform_in_cells(cells: &[(u32, u32)], n: usize, map: &OccupancyMap, rng: &mut impl Rng) -> Vec<Pose2> {
    (0..n)
        .map(|_| {
            let (i, j) = cells[rng.random_range(0..cells.len())];
            let (x, y) = map.grid_to_world(i as f32 + rng.random::<f32>(), j as f32 + rng.random::<f32>());
            Pose2::new(x, y, wrap_angle(rng.random_range(-PI..PI)))
        })
        .collect()
}

/// Draws the initial set for `params.task` around the true pose `truth`, as the paper does: the
/// guess is `truth` perturbed by the tracking spread, then [`draw_around_guess`]. Errors on zero
/// particles, or when a uniform draw is needed and the traversable map is empty.
pub fn draw_initial_set(
    params: &InitParams,
    truth: &Pose2,
    map: &OccupancyMap,
    traversable: &TraversableMap,
    rng: &mut impl Rng,
) -> Result<Initialised, ParticleError> {
    let guess = match params.task {
        Task::Global => None,
        Task::Tracking | Task::SemiGlobal => {
            let (sigma_m, sigma_rad) = tracking_sigmas(params);
            Some(gaussian_around(truth, sigma_m, sigma_rad, rng))
        }
    };
    draw_around_guess(params, guess, map, traversable, rng)
}

/// Draws the initial set for `params.task` around `guess`, used as it is (a user's initial
/// pose): tracking is Gaussian around it, semi-global uniform over the traversable cells in the
/// box around it (global when the box holds none), global (or no guess) uniform over the map.
pub fn draw_around_guess(
    params: &InitParams,
    guess: Option<Pose2>,
    map: &OccupancyMap,
    traversable: &TraversableMap,
    rng: &mut impl Rng,
) -> Result<Initialised, ParticleError> {
    let n = params.particle_count();
    if n == 0 {
        return Err(ParticleError::ZeroParticles);
    }
    let global = |rng: &mut _| match traversable.cells.is_empty() {
        true => Err(ParticleError::NoTraversableCells),
        false => Ok(ParticleSet::from_poses(&uniform_in_cells(&traversable.cells, n, map, rng))),
    };
    match (params.task, guess) {
        (Task::Tracking, Some(guess)) => {
            let (sigma_m, sigma_rad) = tracking_sigmas(params);
            let poses: Vec<Pose2> =
                (0..n).map(|_| gaussian_around(&guess, sigma_m, sigma_rad, rng)).collect();
            Ok(Initialised {
                set: ParticleSet::from_poses(&poses),
                guess: Some(guess),
                fell_back_to_global: false,
            })
        }
        (Task::SemiGlobal, Some(guess)) => {
            let half = params.semi_global_box_m.abs() / 2.0;
            let in_box: Vec<(u32, u32)> = (traversable.cells.iter().copied())
                .filter(|&(i, j)| {
                    let (x, y) = map.cell_center(i as usize, j as usize);
                    (x - guess.x).abs() <= half && (y - guess.y).abs() <= half
                })
                .collect();
            if in_box.is_empty() {
                return Ok(Initialised { set: global(rng)?, guess: Some(guess), fell_back_to_global: true });
            }
            let set = ParticleSet::from_poses(&uniform_in_cells(&in_box, n, map, rng));
            Ok(Initialised { set, guess: Some(guess), fell_back_to_global: false })
        }
        (Task::Global, _) | (_, None) => {
            Ok(Initialised { set: global(rng)?, guess: None, fell_back_to_global: false })
        }
    }
}

/// The tracking spread (σ position in metres, σ heading in radians).
fn tracking_sigmas(params: &InitParams) -> (f32, f32) {
    (params.tracking_sigma_m.abs(), params.tracking_sigma_deg.abs().to_radians())
}

/// Reads NeedsInit, TruePose (or StartGuess), OnMap → the map's OccupancyMap + TraversableMap,
/// InitParams. Writes the ParticleSets of robots marked NeedsInit (and removes the mark),
/// FilterRng, FilterHealth.reinitialisations (semi-global fell back to global) and FilterHealth.emptied (an
/// unmarked set found empty, left so).
pub fn init_particles(
    params: Res<InitParams>,
    maps: Query<(&OccupancyMap, &TraversableMap)>,
    mut commands: Commands,
    mut robots: Query<(
        (Entity, Has<NeedsInit>),
        (&TruePose, Option<&StartGuess>, &OnMap),
        (&mut ParticleSet, &mut FilterRng, &mut FilterHealth),
    )>,
) {
    for ((robot, needs_init), (truth, told, on_map), (mut set, mut rng, mut health)) in &mut robots {
        if !needs_init {
            if set.is_empty() {
                health.emptied += 1;
                tracing::error!(
                    "init_particles: robot {robot:?} lost every particle mid-episode; not redrawn"
                );
            }
            continue;
        }
        let Ok((map, traversable)) = maps.get(on_map.0) else {
            tracing::warn!("init_particles: map {:?} has no OccupancyMap + TraversableMap", on_map.0);
            continue;
        };
        let mixed = params.drawn_from_mix(&mut rng.0);
        let params = mixed.as_ref().unwrap_or(&params);
        let drawn = match told {
            Some(guess) => draw_around_guess(params, Some(guess.0), map, traversable, &mut rng.0),
            None => draw_initial_set(params, &truth.0, map, traversable, &mut rng.0),
        };
        match drawn {
            Ok(init) => {
                health.reinitialisations += u32::from(init.fell_back_to_global);
                *set = init.set;
                commands.entity(robot).remove::<NeedsInit>();
            }
            Err(e) => tracing::warn!("init_particles: {e}"),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::particles::estimate_pose;
    use crate::testing::tiny_room;
    use crate::world::Cell;
    use crate::world::rng::stream;
    use bevy::ecs::system::RunSystemOnce;

    /// Every free cell of the map (no erosion), built by hand.
    fn free_cells(map: &OccupancyMap) -> TraversableMap {
        let traversable: Vec<bool> = map.cells.iter().map(|c| *c == Cell::Free).collect();
        let cells = (0..map.height as u32)
            .flat_map(|j| (0..map.width as u32).map(move |i| (i, j)))
            .filter(|&(i, j)| traversable[j as usize * map.width + i as usize])
            .collect();
        TraversableMap { width: map.width, height: map.height, traversable, cells }
    }

    fn on_traversable(set: &ParticleSet, map: &OccupancyMap, t: &TraversableMap) -> bool {
        (0..set.len())
            .all(|k| map.cell_at(set.x[k], set.y[k]).is_some_and(|(i, j)| t.traversable[j * t.width + i]))
    }

    #[test]
    fn init_particles_fills_only_marked_sets() {
        let mut world = World::new();
        world.insert_resource(InitParams::default());
        let map = tiny_room();
        let traversable = free_cells(&map);
        let m = world.spawn((map, traversable)).id();
        let truth = TruePose(Pose2::new(1.0, 0.5, 0.0));
        let robot = |set: ParticleSet, seed| (truth, OnMap(m), set, FilterRng::seeded(seed));
        let marked = world.spawn((robot(ParticleSet::default(), 1), NeedsInit)).id();
        let kept = ParticleSet::from_weights(&[1.0, 1.0]);
        let full = world.spawn((robot(kept.clone(), 2), NeedsInit)).id();
        let running = world.spawn(robot(kept.clone(), 3)).id();
        world.run_system_once(init_particles).expect("init_particles runs");
        let filled = world.get::<ParticleSet>(marked).expect("set").clone();
        assert_eq!(filled.len(), 300, "tracking default is 300 particles");
        assert!((filled.weights().iter().sum::<f32>() - 1.0).abs() < 1e-4, "uniform, normalised");
        assert_eq!(
            world.get::<ParticleSet>(full).unwrap().len(),
            300,
            "a marked set is redrawn whatever it held"
        );
        assert!(
            world.get::<NeedsInit>(marked).is_none() && world.get::<NeedsInit>(full).is_none(),
            "marks removed"
        );
        assert_eq!(world.get::<ParticleSet>(running), Some(&kept), "unmarked sets are left alone");
        world.run_system_once(init_particles).expect("init_particles runs");
        assert_eq!(world.get::<ParticleSet>(marked), Some(&filled), "drawn once per mark");
    }

    #[test]
    fn init_particles_draws_each_fresh_set_s_task_from_the_mix() {
        let mut world = World::new();
        let mix = vec![Task::SemiGlobal, Task::Global];
        world.insert_resource(InitParams { mix, ..Default::default() });
        let map = tiny_room();
        let traversable = free_cells(&map);
        let m = world.spawn((map, traversable)).id();
        let truth = TruePose(Pose2::new(1.0, 0.5, 0.0));
        let robots: Vec<Entity> = (0..16)
            .map(|seed| {
                world
                    .spawn((truth, OnMap(m), ParticleSet::default(), FilterRng::seeded(seed), NeedsInit))
                    .id()
            })
            .collect();
        world.run_system_once(init_particles).expect("init_particles runs");
        let sizes: Vec<usize> = robots.iter().map(|&r| world.get::<ParticleSet>(r).unwrap().len()).collect();
        assert!(sizes.iter().all(|&n| n == 500 || n == 3000), "each set is one task's default: {sizes:?}");
        assert!(sizes.contains(&500) && sizes.contains(&3000), "16 draws of 2 tasks give both: {sizes:?}");
        let replay = InitParams { mix: vec![Task::SemiGlobal, Task::Global], ..Default::default() };
        let first_task = replay.drawn_from_mix(&mut FilterRng::seeded(0).0).expect("a mix").task;
        assert_eq!(sizes[0], first_task.default_particles(), "the draw comes from the robot's filter RNG");
        assert!(
            InitParams::default().drawn_from_mix(&mut FilterRng::seeded(0).0).is_none(),
            "no mix, no draw"
        );
    }

    #[test]
    fn init_particles_draws_around_a_told_start_as_it_is() {
        let mut world = World::new();
        world.insert_resource(InitParams { tracking_sigma_m: 0.05, ..Default::default() });
        let map = tiny_room();
        let traversable = free_cells(&map);
        let m = world.spawn((map, traversable)).id();
        let (truth, told) = (Pose2::new(0.5, 0.5, 0.0), Pose2::new(1.5, 0.5, 0.0));
        let spawn = |world: &mut World, seed| {
            world
                .spawn((
                    TruePose(truth),
                    OnMap(m),
                    ParticleSet::default(),
                    FilterRng::seeded(seed),
                    NeedsInit,
                ))
                .id()
        };
        let guessed = spawn(&mut world, 1);
        world.entity_mut(guessed).insert(StartGuess(told));
        let simulated = spawn(&mut world, 1);
        world.run_system_once(init_particles).expect("init_particles runs");
        let mean = |robot| estimate_pose(world.get::<ParticleSet>(robot).expect("set")).expect("drawn").pose;
        // σ 0.05 m: 300 draws average within 1 cm of their centre; the perturbed truth (σ 0.05 m
        // per axis) lies anywhere within ~15 cm of it.
        assert!(mean(guessed).distance(&told) < 0.02, "centred on the told start: {:?}", mean(guessed));
        assert!(mean(simulated).distance(&truth) < 0.3, "centred near the truth: {:?}", mean(simulated));
    }

    #[test]
    fn init_particles_reports_a_set_emptied_mid_episode_without_redrawing() {
        let mut world = World::new();
        world.insert_resource(InitParams::default());
        let map = tiny_room();
        let traversable = free_cells(&map);
        let m = world.spawn((map, traversable)).id();
        let truth = TruePose(Pose2::new(1.0, 0.5, 0.0));
        let lost = world.spawn((truth, OnMap(m), ParticleSet::default(), FilterRng::seeded(1))).id();
        world.run_system_once(init_particles).expect("init_particles runs");
        assert!(world.get::<ParticleSet>(lost).unwrap().is_empty(), "no silent redraw around the truth");
        assert_eq!(world.get::<FilterHealth>(lost).unwrap().emptied, 1, "the loss is counted");
    }

    #[test]
    fn init_tracking_spreads_around_guess() {
        let (map, truth) = (tiny_room(), Pose2::new(1.0, 0.5, 3.0));
        let params = InitParams { particles: Some(4000), ..Default::default() };
        let init = draw_initial_set(&params, &truth, &map, &free_cells(&map), &mut stream(&[4]))
            .expect("tracking draw");
        let guess = init.guess.expect("tracking has a guess");
        let n = init.set.len() as f32;
        let sx = (init.set.x.iter().map(|x| (x - guess.x).powi(2)).sum::<f32>() / n).sqrt();
        let syaw = (init.set.yaw.iter().map(|a| wrap_angle(a - guess.yaw).powi(2)).sum::<f32>() / n).sqrt();
        assert!((sx - 0.3).abs() < 0.02, "x spread about the guess ≈ 0.3 m, got {sx}");
        assert!((syaw.to_degrees() - 30.0).abs() < 2.0, "yaw spread ≈ 30°, got {}", syaw.to_degrees());
        assert!(guess.distance(&truth) < 1.5, "guess is a perturbed truth: {guess:?}");
    }

    #[test]
    fn init_semi_global_stays_in_box_on_traversable_cells() {
        let map = tiny_room();
        let t = free_cells(&map);
        let params = InitParams { task: Task::SemiGlobal, semi_global_box_m: 0.6, ..Default::default() };
        let init = draw_initial_set(&params, &Pose2::new(1.0, 0.5, 0.0), &map, &t, &mut stream(&[5]))
            .expect("semi-global draw");
        let g = init.guess.expect("guess");
        assert_eq!(init.set.len(), 500);
        assert!(!init.fell_back_to_global, "the box around {g:?} holds free cells");
        let in_box =
            (0..500).all(|k| (init.set.x[k] - g.x).abs() <= 0.35 && (init.set.y[k] - g.y).abs() <= 0.35);
        assert!(in_box, "particles within box ± half a cell");
        assert!(on_traversable(&init.set, &map, &t), "particles lie on traversable cells");
        let spread = init.set.yaw.iter().fold((f32::MAX, f32::MIN), |(a, b), &y| (a.min(y), b.max(y)));
        assert!(spread.0 < -2.5 && spread.1 > 2.5, "yaw is uniform over the circle: {spread:?}");
    }

    #[test]
    fn init_particles_counts_semi_global_fallback() {
        let mut world = World::new();
        world.insert_resource(InitParams { task: Task::SemiGlobal, ..Default::default() });
        let map = tiny_room();
        let mut t = free_cells(&map);
        t.cells.retain(|&(i, _)| i == 18); // only the far right column is traversable
        let m = world.spawn((map, t)).id();
        // True pose 20 m off, so the 3.3 m box around any plausible guess misses the map.
        let truth = TruePose(Pose2::new(-20.0, 0.5, 0.0));
        let r = world.spawn((truth, OnMap(m), ParticleSet::default(), FilterRng::seeded(3), NeedsInit)).id();
        world.run_system_once(init_particles).expect("init_particles runs");
        assert_eq!(world.get::<FilterHealth>(r).expect("health").reinitialisations, 1, "fallback counted");
        let set = world.get::<ParticleSet>(r).expect("set");
        assert_eq!(set.len(), 500);
        assert!(set.x.iter().all(|&x| (1.8..1.9).contains(&x)), "drawn globally from column 18");
    }

    #[test]
    fn init_rejects_zero_particles_and_empty_maps() {
        let map = tiny_room();
        let mut t = free_cells(&map);
        let zero = InitParams { particles: Some(0), ..Default::default() };
        let err = draw_initial_set(&zero, &Pose2::default(), &map, &t, &mut stream(&[6]));
        assert_eq!(err, Err(ParticleError::ZeroParticles));
        t.cells.clear();
        let global = InitParams { task: Task::Global, ..Default::default() };
        let err = draw_initial_set(&global, &Pose2::default(), &map, &t, &mut stream(&[6]));
        assert_eq!(err, Err(ParticleError::NoTraversableCells));
    }

    #[test]
    fn init_global_covers_traversable_cells() {
        let map = tiny_room();
        let t = free_cells(&map);
        let params = InitParams { task: Task::Global, ..Default::default() };
        let init = draw_initial_set(&params, &Pose2::default(), &map, &t, &mut stream(&[8])).expect("global");
        assert_eq!(init.set.len(), 3000);
        assert!(on_traversable(&init.set, &map, &t), "global particles lie on traversable cells");
        let (xs, ys) = (&init.set.x, &init.set.y);
        let span =
            |v: &[f32]| v.iter().fold(f32::MIN, |a, &b| a.max(b)) - v.iter().fold(f32::MAX, |a, &b| a.min(b));
        assert!(span(xs) > 1.6 && span(ys) > 1.1, "spread over the whole room: {} × {}", span(xs), span(ys));
    }

    #[test]
    fn init_task_names_are_snake_case() {
        let p: InitParams = ron::from_str("(task: semi_global, particles: Some(42))").expect("parses");
        assert_eq!((p.task, p.particle_count()), (Task::SemiGlobal, 42));
        assert!(ron::from_str::<InitParams>("(tsak: global)").is_err(), "unknown fields are rejected");
        for task in Task::ALL {
            let json = serde_json::to_string(&task).expect("serialises");
            assert_eq!(json, format!("\"{}\"", task.name()), "files and tables spell it alike");
        }
    }
}
