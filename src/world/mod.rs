//! What exists before anything runs: poses, maps, robots, seeded randomness.

pub mod map;
pub mod pose;
pub mod rng;
pub mod robot;

pub use map::{Cell, OccupancyMap};
pub use pose::{Pose2, angle_error, circular_mean, wrap_angle};
pub use rng::{FilterRng, RobotRngs, ScenarioRng, SensorRng};
pub use robot::{OnMap, PreviousPose, Robot, RobotId, RobotParams, TruePose, in_id_order};
