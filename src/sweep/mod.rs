//! Sweeps: an eval config × seeds, split into independent, deterministic jobs (one cell, one
//! seed, one result file each) that any engine can run, then merged into mean ± 95 % CI tables
//! (success rates: pooled over the seeds' episodes, with a Wilson interval).

mod config;
mod error;
mod jobs;
mod merge;
mod proportion;
mod result;
mod stats;
mod table;

pub use config::{LoadedSweep, SweepConfig};
pub use error::SweepError;
pub use jobs::{Job, job_at, job_steps, jobs, list_lines};
pub use merge::{SweepRow, collect, merge};
pub use proportion::Proportion;
pub use result::{JobResult, JobStatus, job_path, job_status, run_job, write_job_result};
pub use stats::{MeanCi, mean_ci, t975};
pub use table::{csv, markdown, write_sweep};
