//! Error over time (`steps.csv`): per cell and agent step, the mean and median position error and
//! the mean heading error over the cell's episodes — the curves of the paper's figures, and the
//! way to tell a policy that converges sooner from one that loses fewer episodes.

use crate::episode::EpisodeRecord;
use crate::eval::row::ResultRow;
use crate::particles::Task;
use serde::Serialize;

/// One step of one cell, flat as a CSV line.
#[derive(Serialize, Clone, Debug, PartialEq)]
pub struct StepRow {
    pub localizer: String,
    pub policy: String,
    pub task: Task,
    pub split: String,
    /// Agent step within the episode, from 1.
    pub step: usize,
    /// Episodes that logged this step.
    pub episodes: usize,
    pub mean_pos_err_m: f32,
    pub median_pos_err_m: f32,
    pub mean_orient_err_rad: f32,
}

impl StepRow {
    /// One row per step of `cell`'s episodes; a step counts the episodes long enough to reach it.
    pub fn of_cell(cell: &ResultRow, records: &[EpisodeRecord]) -> Vec<Self> {
        let steps = records.iter().map(|r| r.log.errors.len()).max().unwrap_or(0);
        (0..steps)
            .map(|k| {
                let at_step: Vec<_> = records.iter().filter_map(|r| r.log.errors.get(k)).collect();
                let n = at_step.len() as f64;
                let mut positions: Vec<f32> = at_step.iter().map(|e| e.pos_err_m).collect();
                positions.sort_unstable_by(f32::total_cmp);
                Self {
                    localizer: cell.localizer.clone(),
                    policy: cell.policy.clone(),
                    task: cell.task,
                    split: cell.split.clone(),
                    step: k + 1,
                    episodes: at_step.len(),
                    mean_pos_err_m: (positions.iter().map(|&p| p as f64).sum::<f64>() / n) as f32,
                    median_pos_err_m: median(&positions),
                    mean_orient_err_rad: (at_step.iter().map(|e| e.orient_err_rad as f64).sum::<f64>() / n)
                        as f32,
                }
            })
            .collect()
    }
}

/// The median of sorted values (the mean of the middle two for an even count).
fn median(sorted: &[f32]) -> f32 {
    let mid = sorted.len() / 2;
    if sorted.len().is_multiple_of(2) { (sorted[mid - 1] + sorted[mid]) / 2.0 } else { sorted[mid] }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::eval::episodes::tests::{cell, record};

    #[test]
    fn each_step_averages_the_episodes_that_reached_it() {
        let records = [record(&[3.0, 1.0]), record(&[1.0, 0.5]), record(&[2.0, 0.1, 0.4])];
        let rows = StepRow::of_cell(&cell(), &records);
        assert_eq!(rows.iter().map(|r| (r.step, r.episodes)).collect::<Vec<_>>(), [(1, 3), (2, 3), (3, 1)]);
        assert!((rows[0].mean_pos_err_m - 2.0).abs() < 1e-6);
        assert_eq!(rows[0].median_pos_err_m, 2.0);
        assert!((rows[1].mean_pos_err_m - 1.6 / 3.0).abs() < 1e-6);
        assert_eq!(rows[1].median_pos_err_m, 0.5);
        assert!((rows[1].mean_orient_err_rad - 0.1).abs() < 1e-6);
        assert_eq!((rows[2].mean_pos_err_m, rows[2].median_pos_err_m), (0.4, 0.4));
        assert_eq!((rows[0].policy.as_str(), rows[0].task), ("turn", Task::Tracking));
    }

    #[test]
    fn the_median_of_an_even_count_is_the_mean_of_the_middle_two() {
        assert_eq!(median(&[1.0, 2.0, 4.0, 9.0]), 3.0);
        assert_eq!(median(&[5.0]), 5.0);
    }
}
