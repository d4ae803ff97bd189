//! Maps: the fine occupancy grid, its ROS map_server I/O, procedural apartments, derived layers
//! (network map, traversable map, distance field) and an A* planner on the traversable map.

mod astar;
mod coarsen;
mod edt;
mod error;
mod layers;
mod occupancy;
pub mod procedural;
mod render;
mod ros_io;

pub use astar::{plan_cells, plan_path};
pub use coarsen::CoarsenRule;
pub use error::MapError;
pub use layers::{DistanceField, NetworkMap, START_POSE_TRIES, TraversableMap};
pub use occupancy::{Cell, OccupancyMap};
pub use render::render;
pub use ros_io::{
    MapMode, RosMapYaml, classify_pixel, load_ros_map, occupancy_from_image, read_ros_yaml, save_ros_map,
    write_atomically,
};
