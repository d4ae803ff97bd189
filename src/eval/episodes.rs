//! Per-episode results (`episodes.csv`): the distribution behind each table cell, so that a mean
//! pulled up by a few lost episodes can be told from a uniformly worse localizer.

use crate::episode::{EpisodeRecord, succeeded};
use crate::eval::row::ResultRow;
use crate::particles::Task;
use serde::Serialize;

/// One finished episode of one cell, flat as a CSV line.
#[derive(Serialize, Clone, Debug, PartialEq)]
pub struct EpisodeRow {
    pub localizer: String,
    pub policy: String,
    pub task: Task,
    pub split: String,
    /// Position of the episode in the cell's completion order (0-based).
    pub episode: usize,
    pub start_x: f32,
    pub start_y: f32,
    pub start_yaw: f32,
    pub final_x: f32,
    pub final_y: f32,
    pub final_yaw: f32,
    pub estimate_x: f32,
    pub estimate_y: f32,
    pub estimate_yaw: f32,
    pub mean_pos_err_m: f32,
    pub final_pos_err_m: f32,
    pub final_orient_err_rad: f32,
    pub success: bool,
    pub collisions: u32,
}

impl EpisodeRow {
    /// The `episode`-th record of `cell`; `None` for an episode that logged no step.
    pub fn from_record(cell: &ResultRow, episode: usize, record: &EpisodeRecord) -> Option<Self> {
        let log = &record.log;
        let last = log.errors.last()?;
        let (start, truth, estimate) = (log.truth.first()?, log.truth.last()?, log.estimates.last()?);
        let mean = log.errors.iter().map(|e| e.pos_err_m as f64).sum::<f64>() / log.errors.len() as f64;
        Some(Self {
            localizer: cell.localizer.clone(),
            policy: cell.policy.clone(),
            task: cell.task,
            split: cell.split.clone(),
            episode,
            start_x: start.x,
            start_y: start.y,
            start_yaw: start.yaw,
            final_x: truth.x,
            final_y: truth.y,
            final_yaw: truth.yaw,
            estimate_x: estimate.x,
            estimate_y: estimate.y,
            estimate_yaw: estimate.yaw,
            mean_pos_err_m: mean as f32,
            final_pos_err_m: last.pos_err_m,
            final_orient_err_rad: last.orient_err_rad,
            success: succeeded(&log.errors),
            collisions: log.collisions,
        })
    }
}

#[cfg(test)]
pub(super) mod tests {
    use super::*;
    use crate::episode::{EpisodeLog, StepError};
    use crate::world::Pose2;
    use bevy::prelude::Entity;

    /// An episode with these position errors (heading error 0.1 rad at every step).
    pub(in crate::eval) fn record(errors: &[f32]) -> EpisodeRecord {
        let n = errors.len();
        let log = EpisodeLog {
            errors: errors
                .iter()
                .map(|&e| StepError { pos_err_m: e, orient_err_rad: 0.1, loss: e * e })
                .collect(),
            truth: (0..n).map(|k| Pose2::new(k as f32, 0.0, 0.0)).collect(),
            estimates: (0..n).map(|k| Pose2::new(k as f32, errors[k], 0.0)).collect(),
            collisions: 2,
            ..Default::default()
        };
        EpisodeRecord { robot: Entity::PLACEHOLDER, map: Entity::PLACEHOLDER, episode: 0, log }
    }

    pub(in crate::eval) fn cell() -> ResultRow {
        ResultRow {
            localizer: "mcl".into(),
            policy: "turn".into(),
            task: Task::Tracking,
            split: "depot".into(),
            map: "depot.yaml".into(),
            particles: 300,
            episodes: 2,
            seed: 0,
            mean_pos_err_m: 0.0,
            rmse_pos_m: 0.0,
            final_pos_err_m: 0.0,
            mean_orient_err_rad: 0.0,
            final_orient_err_rad: 0.0,
            success_rate: 1.0,
        }
    }

    #[test]
    fn episode_row_summarises_one_record() {
        let row = EpisodeRow::from_record(&cell(), 3, &record(&[0.4, 0.2, 1.5])).expect("three steps");
        assert!((row.mean_pos_err_m - 0.7).abs() < 1e-6);
        assert_eq!((row.final_pos_err_m, row.episode, row.collisions), (1.5, 3, 2));
        assert_eq!((row.start_x, row.final_x, row.estimate_y), (0.0, 2.0, 1.5));
        assert_eq!((row.policy.as_str(), row.task), ("turn", Task::Tracking));
        assert!(!row.success, "1.5 m off in the last quarter");
        assert!(EpisodeRow::from_record(&cell(), 0, &record(&[])).is_none(), "an empty log has no row");
    }
}
