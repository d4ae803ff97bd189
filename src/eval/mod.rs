//! Evaluation: crosses schedules (localizer × policy) with tasks and map groups, runs each cell's
//! episodes in a batched world, and writes the paper-style tables.

mod cell;
mod config;
mod table;

pub use cell::{CellOutcome, CellSpec, ResultRow, cell_steps, cells, labels, run_cell, schedule_labels};
pub use config::{EvalConfig, LoadedEval, MapGroup};
pub use table::{csv, markdown, task_name, write_results};
