//! Layers derived from the fine occupancy grid: the filter's coarse network map, the traversable
//! map (free space eroded by the robot radius) and the Euclidean distance field.

use crate::world::pose::Pose2;
use bevy::prelude::Component;

/// The filter's map at 0.1 m/cell: block mean of the fine grid, fractional occupancy in [0, 1].
#[derive(Component, Clone, Debug, PartialEq)]
pub struct NetworkMap {
    pub resolution_m: f32,
    pub origin: Pose2,
    pub width: usize,
    pub height: usize,
    /// `occupancy[j * width + i]`, row 0 at the bottom.
    pub occupancy: Vec<f32>,
}

/// Where the robot's centre may be: free cells of the fine grid farther than the robot radius
/// from anything non-free, restricted to the largest connected component.
#[derive(Component, Clone, Debug, PartialEq)]
pub struct TraversableMap {
    pub width: usize,
    pub height: usize,
    /// Same indexing as the fine grid.
    pub traversable: Vec<bool>,
    /// Every traversable cell (i, j), for uniform sampling.
    pub cells: Vec<(u32, u32)>,
}

/// Distance from each fine cell's centre to the nearest occupied cell's centre, metres.
#[derive(Component, Clone, Debug, PartialEq)]
pub struct DistanceField {
    pub width: usize,
    pub height: usize,
    pub resolution_m: f32,
    pub distances_m: Vec<f32>,
}
