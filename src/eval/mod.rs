//! Evaluation: crosses schedules (localizer × policy) with tasks and map groups, runs each cell's
//! episodes in a batched world, and writes the paper-style tables
//! and episode figures.

mod cell;
mod config;
mod curves;
mod episodes;
mod figure;
mod font;
mod paired;
mod row;
mod steps;
mod table;

pub use cell::{CellOutcome, CellSpec, cell_steps, cells, labels, run_cell, schedule_labels};
pub use config::{EvalConfig, LoadedEval, MapGroup};
pub use curves::curve_figures;
pub use episodes::EpisodeRow;
pub use figure::{FigureError, encode_png, episode_figure, figure_file_name, figure_title};
pub use font::register_sans_serif;
pub use paired::{PairedRow, paired_markdown, paired_rows};
pub use row::ResultRow;
pub use steps::StepRow;
pub use table::{csv, markdown, write_results};
