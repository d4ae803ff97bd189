//! Localization error per step, collected per episode, and the paper's summary metrics.
//!
//! Definitions (DESIGN §5): per step, position error ‖(x̂, ŷ) − (x, y)‖, heading error |θ̂ − θ|
//! wrapped to [0, π], and the PF-net loss L = Δx² + Δy² + 0.36·Δθ². Per table cell: the mean
//! position error over all steps of all episodes (what the paper's tables call "RMSE"), the true
//! RMSE, the mean |heading error|, final-step errors, and success = error < 1 m at every step of
//! the last 25 % of the episode.

use crate::act::Collided;
use crate::belief::BeliefCrop;
use crate::episode::reset::{Episode, EpisodeParams};
use crate::particles::{ParticleSet, PoseEstimate};
use crate::world::{OnMap, Pose2, RobotId, TruePose, angle_error, wrap_angle};
use bevy::prelude::*;
use serde::{Deserialize, Serialize};

/// Weight of the squared heading error in the loss (paper: β = 0.36, metres and radians).
pub const LOSS_BETA: f32 = 0.36;

/// A position error below this, at every step of the last quarter, counts as success (metres).
pub const SUCCESS_RADIUS_M: f32 = 1.0;

/// The error of one estimate against the truth.
#[derive(Component, Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct StepError {
    pub pos_err_m: f32,
    pub orient_err_rad: f32,
    /// L = Δx² + Δy² + β·Δθ²; the RL reward is −L (minus 0.1 on collision).
    pub loss: f32,
}

impl StepError {
    pub fn between(estimate: &Pose2, truth: &Pose2) -> Self {
        let (dx, dy) = (estimate.x - truth.x, estimate.y - truth.y);
        let dyaw = wrap_angle(estimate.yaw - truth.yaw);
        Self {
            pos_err_m: dx.hypot(dy),
            orient_err_rad: angle_error(estimate.yaw, truth.yaw),
            loss: dx * dx + dy * dy + LOSS_BETA * dyaw * dyaw,
        }
    }
}

/// What a robot's current episode has logged so far; moved into an `EpisodeRecord` when it ends.
#[derive(Component, Clone, Debug, Default, PartialEq)]
pub struct EpisodeLog {
    pub errors: Vec<StepError>,
    /// True and estimated pose at each step (what figures draw).
    pub truth: Vec<Pose2>,
    pub estimates: Vec<Pose2>,
    /// Positions of up to `FIGURE_PARTICLES` particles after the episode's first filter update.
    pub first_particles: Vec<(f32, f32)>,
    /// How many particles the set held then (more than `first_particles` when subsampled).
    pub first_particle_count: usize,
    /// Collisions seen at this episode's steps 2…T, i.e. caused by its first T − 1 actions
    /// (the last action's outcome is only seen after the episode ends).
    pub collisions: u32,
    /// The estimate's belief crop at `FIGURE_CROPS` evenly spaced steps, when the schedule makes
    /// one (`belief_crop`): what the agent saw, for figures.
    pub crops: Vec<CropSnapshot>,
}

/// Particles kept per episode for figures; a stride subsample of larger sets.
pub const FIGURE_PARTICLES: usize = 1000;

/// Belief crops kept per episode for figures: the first step, the last and evenly between.
pub const FIGURE_CROPS: usize = 5;

/// The free-space and particle-weight channels of one belief crop, in bytes (weights relative to
/// the crop's heaviest cell), in the crop's layout: the estimate at the centre facing up.
#[derive(Clone, Debug, PartialEq)]
pub struct CropSnapshot {
    pub step: u32,
    pub cells: usize,
    pub free: Vec<u8>,
    pub weight: Vec<u8>,
}

impl CropSnapshot {
    fn of(crop: &BeliefCrop, step: u32) -> Self {
        let to_byte = |v: f32| (v.clamp(0.0, 1.0) * 255.0).round() as u8;
        let weight = crop.channel(0, 1);
        let heaviest = weight.iter().copied().fold(0.0f32, f32::max).max(f32::MIN_POSITIVE);
        CropSnapshot {
            step,
            cells: crop.cells,
            free: crop.channel(0, 0).iter().map(|&v| to_byte(v)).collect(),
            weight: weight.iter().map(|&w| to_byte(w / heaviest)).collect(),
        }
    }
}

/// Whether step `step` (1-based) of a `steps`-step episode is one of its `FIGURE_CROPS` snapshots.
fn is_snapshot_step(step: u32, steps: u32) -> bool {
    let last = (FIGURE_CROPS - 1) as u32;
    (0..=last).any(|k| 1 + ((k * steps.saturating_sub(1)) as f32 / last as f32).round() as u32 == step)
}

/// One finished episode, as the evaluation harness aggregates and draws it.
#[derive(Clone, Debug, PartialEq)]
pub struct EpisodeRecord {
    pub robot: Entity,
    pub map: Entity,
    pub episode: u32,
    pub log: EpisodeLog,
}

/// Episodes finished so far in this world, in completion order; episodes that finish at the
/// same step are in `RobotId` order.
#[derive(Resource, Clone, Debug, Default)]
pub struct CompletedEpisodes(pub Vec<EpisodeRecord>);

/// Reads TruePose, PoseEstimate, Episode, EpisodeParams, Collided, ParticleSet, BeliefCrop,
/// RobotId. Writes StepError, EpisodeLog, CompletedEpisodes (when an episode's last step is
/// logged, in RobotId order).
pub fn step_metrics(
    params: Res<EpisodeParams>,
    mut completed: ResMut<CompletedEpisodes>,
    mut robots: Query<(
        (Entity, &RobotId),
        &OnMap,
        (&TruePose, &PoseEstimate, &Episode),
        (Option<&Collided>, Option<&ParticleSet>, Option<&BeliefCrop>),
        &mut StepError,
        &mut EpisodeLog,
    )>,
) {
    let mut finished = Vec::new();
    for ((robot, id), on_map, (truth, estimate, episode), (collided, particles, crop), mut error, mut log) in
        &mut robots
    {
        *error = StepError::between(&estimate.pose, &truth.0);
        if episode.step == 1 {
            *log = EpisodeLog::default();
            if let Some(set) = particles {
                let stride = set.len().div_ceil(FIGURE_PARTICLES).max(1);
                log.first_particles = (0..set.len()).step_by(stride).map(|k| (set.x[k], set.y[k])).collect();
                log.first_particle_count = set.len();
            }
        } else if collided.is_some_and(|c| c.0) {
            log.collisions += 1;
        }
        log.errors.push(*error);
        log.truth.push(truth.0);
        log.estimates.push(estimate.pose);
        if let Some(crop) = crop.filter(|c| c.cells > 0 && is_snapshot_step(episode.step, params.steps)) {
            log.crops.push(CropSnapshot::of(crop, episode.step));
        }
        if episode.step == params.steps {
            let log = std::mem::take(&mut *log);
            finished.push((*id, EpisodeRecord { robot, map: on_map.0, episode: episode.index, log }));
        }
    }
    finished.sort_unstable_by_key(|(id, _)| *id);
    completed.0.extend(finished.into_iter().map(|(_, record)| record));
}

/// The summary of many episodes: one cell of a results table.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct CellMetrics {
    pub episodes: usize,
    /// Mean position error over all steps of all episodes (the paper's "RMSE" column), metres.
    pub mean_pos_err_m: f32,
    /// √(mean squared position error) over all steps, metres.
    pub rmse_pos_m: f32,
    pub final_pos_err_m: f32,
    pub mean_orient_err_rad: f32,
    pub final_orient_err_rad: f32,
    /// Fraction of episodes with position error < 1 m at every step of the last 25 %.
    pub success_rate: f32,
}

/// Aggregates finished episodes; `None` when there are none.
pub fn summarize(records: &[EpisodeRecord]) -> Option<CellMetrics> {
    let steps: Vec<&StepError> = records.iter().flat_map(|r| &r.log.errors).collect();
    if steps.is_empty() {
        return None;
    }
    let n = steps.len() as f64;
    let mean = |f: &dyn Fn(&StepError) -> f32| steps.iter().map(|e| f(e) as f64).sum::<f64>() / n;
    let finals: Vec<&StepError> = records.iter().filter_map(|r| r.log.errors.last()).collect();
    let final_mean =
        |f: &dyn Fn(&StepError) -> f32| finals.iter().map(|e| f(e) as f64).sum::<f64>() / finals.len() as f64;
    let successes = records.iter().filter(|r| succeeded(&r.log.errors)).count();
    Some(CellMetrics {
        episodes: records.len(),
        mean_pos_err_m: mean(&|e| e.pos_err_m) as f32,
        rmse_pos_m: mean(&|e| e.pos_err_m * e.pos_err_m).sqrt() as f32,
        final_pos_err_m: final_mean(&|e| e.pos_err_m) as f32,
        mean_orient_err_rad: mean(&|e| e.orient_err_rad) as f32,
        final_orient_err_rad: final_mean(&|e| e.orient_err_rad) as f32,
        success_rate: successes as f32 / records.len() as f32,
    })
}

/// Success: position error below 1 m at every step of the episode's last quarter.
pub fn succeeded(errors: &[StepError]) -> bool {
    let last_quarter = errors.len().div_ceil(4);
    !errors.is_empty() && errors[errors.len() - last_quarter..].iter().all(|e| e.pos_err_m < SUCCESS_RADIUS_M)
}

#[cfg(test)]
mod tests {
    use super::*;
    use bevy::ecs::system::RunSystemOnce;
    use std::f32::consts::PI;

    fn err(pos: f32) -> StepError {
        StepError { pos_err_m: pos, orient_err_rad: 0.1, loss: pos * pos }
    }

    #[test]
    fn crop_snapshots_span_the_episode_and_scale_weights_to_the_heaviest_cell() {
        let steps: Vec<u32> = (1..=50).filter(|&s| is_snapshot_step(s, 50)).collect();
        assert_eq!(steps, [1, 13, 26, 38, 50]);
        assert_eq!((1..=3).filter(|&s| is_snapshot_step(s, 3)).count(), 3, "short episodes: every step");
        let cells = 2;
        let mut values = vec![0.0; crate::belief::BELIEF_CHANNELS * cells * cells];
        values[..4].copy_from_slice(&[1.0, 0.0, 0.5, 1.0]); // free space
        values[4..8].copy_from_slice(&[0.1, 0.4, 0.0, 0.2]); // particle weight
        let crop = BeliefCrop { cells, centres: vec![Pose2::default()], values };
        let snapshot = CropSnapshot::of(&crop, 7);
        assert_eq!(snapshot.free, [255, 0, 128, 255]);
        assert_eq!(snapshot.weight, [64, 255, 0, 128]);
    }

    #[test]
    fn step_error_wraps_heading_and_weights_it() {
        let e = StepError::between(&Pose2::new(3.0, 4.0, PI - 0.05), &Pose2::new(0.0, 0.0, -PI + 0.05));
        assert!((e.pos_err_m - 5.0).abs() < 1e-5);
        assert!(
            (e.orient_err_rad - 0.1).abs() < 1e-4,
            "across ±π the error is 0.1 rad, got {}",
            e.orient_err_rad
        );
        assert!((e.loss - (25.0 + LOSS_BETA * 0.01)).abs() < 1e-3);
    }

    #[test]
    fn summarize_separates_mean_error_from_rmse() {
        let record = |errors: Vec<StepError>, collisions| EpisodeRecord {
            robot: Entity::PLACEHOLDER,
            map: Entity::PLACEHOLDER,
            episode: 0,
            log: EpisodeLog { errors, collisions, ..default() },
        };
        let records = vec![record(vec![err(0.0), err(2.0)], 1), record(vec![err(0.0), err(0.0)], 0)];
        let m = summarize(&records).unwrap();
        assert!((m.mean_pos_err_m - 0.5).abs() < 1e-6, "mean of 0, 2, 0, 0");
        assert!((m.rmse_pos_m - 1.0).abs() < 1e-6, "√(4/4)");
        assert!((m.final_pos_err_m - 1.0).abs() < 1e-6, "finals 2 and 0");
        assert_eq!(m.success_rate, 0.5, "the first episode ends 2 m off");
        assert!(summarize(&[]).is_none());
    }

    #[test]
    fn success_needs_the_whole_last_quarter_within_one_metre() {
        let mut errors = vec![err(5.0); 6];
        errors.extend([err(0.5), err(0.2)]);
        assert!(succeeded(&errors), "early errors do not matter");
        errors[6] = err(1.5);
        assert!(!succeeded(&errors), "one miss in the last quarter fails");
    }

    #[test]
    fn step_metrics_logs_and_completes_episodes() {
        let mut world = World::new();
        world.insert_resource(EpisodeParams { steps: 2, ..default() });
        world.init_resource::<CompletedEpisodes>();
        let truth = Pose2::new(1.0, 1.0, 0.0);
        let robot = world
            .spawn((
                (RobotId(0), OnMap(Entity::PLACEHOLDER)),
                ParticleSet::from_poses(&[truth; 3]),
                TruePose(truth),
                PoseEstimate { pose: Pose2::new(1.3, 1.4, 0.0), ..default() },
                Episode { index: 0, step: 1 },
                StepError::default(),
                EpisodeLog::default(),
            ))
            .id();
        world.run_system_once(step_metrics).unwrap();
        assert!((world.get::<StepError>(robot).unwrap().pos_err_m - 0.5).abs() < 1e-5);
        assert!(world.resource::<CompletedEpisodes>().0.is_empty(), "episode not over after step 1");
        world.get_mut::<Episode>(robot).unwrap().step = 2;
        world.run_system_once(step_metrics).unwrap();
        let done = &world.resource::<CompletedEpisodes>().0;
        assert_eq!(done.len(), 1, "the last step completes the episode");
        assert_eq!(done[0].log.errors.len(), 2);
        assert_eq!(done[0].log.truth, vec![truth; 2], "truth is logged per step for figures");
        assert_eq!(done[0].log.first_particles.len(), 3, "the first step's particles are kept");
        assert_eq!(done[0].log.first_particle_count, 3, "with their count");
    }

    #[test]
    fn step_metrics_records_simultaneous_endings_in_robot_id_order() {
        #[derive(Component)]
        struct Extra;
        let mut world = World::new();
        world.insert_resource(EpisodeParams { steps: 1, ..default() });
        world.init_resource::<CompletedEpisodes>();
        // Spawned out of id order, and half of them in another archetype.
        for id in [2u32, 0, 3, 1] {
            let pose = Pose2::new(id as f32, 0.0, 0.0);
            let mut robot = world.spawn((
                (RobotId(id), OnMap(Entity::PLACEHOLDER), TruePose(pose)),
                (PoseEstimate { pose, ..default() }, Episode { index: 0, step: 1 }),
                (StepError::default(), EpisodeLog::default()),
            ));
            if id % 2 == 0 {
                robot.insert(Extra);
            }
        }
        world.run_system_once(step_metrics).unwrap();
        let xs: Vec<f32> = world.resource::<CompletedEpisodes>().0.iter().map(|r| r.log.truth[0].x).collect();
        assert_eq!(xs, [0.0, 1.0, 2.0, 3.0], "records follow RobotId, not spawn or archetype order");
    }
}
