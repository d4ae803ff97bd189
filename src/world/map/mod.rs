//! Maps: the fine occupancy grid, its ROS map_server I/O, procedural apartments, derived layers
//! (network map, traversable map, distance field) and an A* planner on the traversable map.

mod layers;
mod occupancy;
pub mod procedural;

pub use layers::{DistanceField, NetworkMap, TraversableMap};
pub use occupancy::{Cell, OccupancyMap};
