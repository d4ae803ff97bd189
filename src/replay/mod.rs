//! Offline replay: localize recorded data without the simulator. `log` reads and writes the JSON
//! Lines formats (ROS LaserScan fields + odometry pose in, one estimate per line out);
//! `localizer` is the classical particle filter as a plain struct (`Localizer::new`, `update`);
//! `fit` tells whether a log's scans belong to the map; `bag` reads the same lines from a ROS 2
//! bag (MCAP).

pub mod bag;
mod error;
mod fit;
mod localizer;
mod log;

pub use error::ReplayError;
pub use fit::{FIT_TOLERANCE_M, MIN_FIT, scan_fit};
pub use localizer::{InitialGuess, Localizer, LocalizerParams, ReplayModel};
pub use log::{EstimateLine, LogLine, parse_line, parse_log, read_log, to_jsonl};
