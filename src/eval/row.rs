//! One row of the results table: a cell's summary over its episodes.

use crate::particles::Task;
use serde::{Deserialize, Serialize};

/// One row of results.json / results.csv: exactly the keys.
#[derive(Serialize, Deserialize, Clone, Debug, PartialEq)]
pub struct ResultRow {
    pub localizer: String,
    pub policy: String,
    pub task: Task,
    pub split: String,
    pub map: String,
    pub particles: usize,
    pub episodes: usize,
    pub seed: u64,
    pub mean_pos_err_m: f32,
    pub rmse_pos_m: f32,
    pub final_pos_err_m: f32,
    pub mean_orient_err_rad: f32,
    pub final_orient_err_rad: f32,
    pub success_rate: f32,
}
