//! Offline replay: localize recorded data with no simulated robot. `log` reads and writes the JSON
//! Lines formats (ROS LaserScan fields + odometry pose in, one estimate per line out);
//! `localizer` runs the simulator's filter systems on them (`Localizer::new`, `update`), fed by
//! `feed`'s `log_feed` system in place of the simulated sensors;
//! `fit` tells whether a log's scans belong to the map; `bag` reads the same lines from a ROS 2
//! bag (MCAP).

pub mod bag;
mod error;
mod feed;
mod fit;
mod localizer;
mod log;

pub use error::ReplayError;
pub use feed::{LogFeed, Reading, log_feed};
pub use fit::{FIT_TOLERANCE_M, MIN_FIT, scan_fit};
pub use localizer::{InitialGuess, Localizer, LocalizerParams, ReplayModel, SHIPPED_PFNET};
pub use log::{EstimateLine, LogLine, parse_line, parse_log, read_log, to_jsonl};
