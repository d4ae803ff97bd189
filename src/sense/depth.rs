//! A one-row depth camera: the paper's 90° depth image reduced to the strip at the sensor's
//! height, cast on the fine grid (the `avoid` baseline and the agent's optional depth input).

use crate::params::{StepParams, expect_param};
use crate::sense::raycast::RayGrid;
use crate::world::{OnMap, Pose2, TruePose};
use bevy::prelude::*;
use serde::{Deserialize, Serialize};

/// The simulated depth camera.
#[derive(Resource, Serialize, Deserialize, Clone, Debug, PartialEq)]
#[serde(default, deny_unknown_fields)]
pub struct DepthParams {
    /// Horizontal field of view, degrees (paper: 90).
    pub fov_deg: f32,
    /// Image width, pixels (paper: 56).
    pub columns: usize,
    /// Nearest reported depth, metres (paper: 0.1).
    pub min_m: f32,
    /// Farthest reported depth, metres (paper: 10).
    pub max_m: f32,
}

impl Default for DepthParams {
    fn default() -> Self {
        Self { fov_deg: 90.0, columns: 56, min_m: 0.1, max_m: 10.0 }
    }
}

impl StepParams for DepthParams {
    fn check(&self) -> Result<(), String> {
        crate::limits::DEPTH_COLUMNS.check("columns", self.columns)?;
        expect_param(self.fov_deg > 0.0 && self.fov_deg < 180.0, "fov_deg", "a field of view in (0, 180)")?;
        expect_param(self.min_m >= 0.0 && self.min_m < self.max_m, "min_m, max_m", "0 ≤ min_m < max_m")
    }
}

/// Depth per image column, left to right, metres. Pinhole depth: the distance along the optical
/// axis (the robot's heading), not along the ray, so a wall facing the camera reads flat.
/// Clamped to [min_m, max_m]: nothing within `max_m` reads `max_m`, anything nearer than `min_m`
/// reads `min_m`.
#[derive(Component, Clone, Debug, Default, PartialEq)]
pub struct DepthStrip {
    pub depths_m: Vec<f32>,
}

/// Angle of column `c` from the optical axis (CCW, so the left half is positive): the ray through
/// the pixel centre of a pinhole camera, `atan(tan(fov/2) · (1 − (2c + 1)/columns))`.
pub fn column_angle(params: &DepthParams, c: usize) -> f32 {
    let half = (params.fov_deg.to_radians() / 2.0).tan();
    (half * (1.0 - (2 * c + 1) as f32 / params.columns as f32)).atan()
}

/// Fills `out` (one value per column) with the depth seen from `pose`: the kernel of [`depth`].
/// Depth = range · cos(column angle), casting each ray to `max_m / cos` so the far limit is a
/// depth limit.
pub fn depth_strip(grid: &RayGrid, pose: Pose2, params: &DepthParams, out: &mut [f32]) {
    for (c, d) in out.iter_mut().enumerate() {
        let a = column_angle(params, c);
        let cos = a.cos();
        let limit = params.max_m / cos;
        let range = grid.cast(pose.x, pose.y, pose.yaw + a, limit);
        let depth = if range >= limit { params.max_m } else { range * cos };
        *d = depth.clamp(params.min_m, params.max_m.max(params.min_m));
    }
}

/// Reads TruePose, OnMap, the map's RayGrid. Writes DepthStrip.
pub fn depth(
    params: Res<DepthParams>,
    maps: Query<&RayGrid>,
    mut robots: Query<(&TruePose, &OnMap, &mut DepthStrip)>,
) {
    for (pose, on, mut strip) in robots.iter_mut() {
        let Ok(grid) = maps.get(on.0) else {
            tracing::warn!("depth: map entity {:?} has no RayGrid; depth strip not updated", on.0);
            continue;
        };
        strip.depths_m.resize(params.columns, params.max_m);
        depth_strip(grid, pose.0, &params, &mut strip.depths_m);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::world::{Cell, OccupancyMap};
    use bevy::ecs::system::RunSystemOnce;

    /// 8 m × 8 m free map at 0.05 m with an occupied column (a flat wall) at x ∈ [6.0, 6.05).
    fn wall_map() -> OccupancyMap {
        let mut map = OccupancyMap::filled(160, 160, 0.05, Cell::Free);
        for j in 0..160 {
            map.set(120, j, Cell::Occupied);
        }
        map
    }

    fn run(pose: Pose2, params: DepthParams) -> Vec<f32> {
        let mut world = World::new();
        world.insert_resource(params);
        let map = world.spawn(RayGrid::from_map(&wall_map())).id();
        let robot = world.spawn((TruePose(pose), OnMap(map), DepthStrip::default())).id();
        world.run_system_once(depth).unwrap();
        world.get::<DepthStrip>(robot).unwrap().depths_m.clone()
    }

    #[test]
    fn depth_of_a_flat_wall_is_flat() {
        let depths = run(Pose2::new(4.0, 4.0, 0.0), DepthParams::default());
        assert_eq!(depths.len(), 56, "paper: 56 columns");
        for (c, d) in depths.iter().enumerate() {
            assert!((d - 2.0).abs() < 1e-3, "column {c}: depth {d}, the wall is 2 m ahead");
        }
    }

    #[test]
    fn depth_clamps_and_orders_left_to_right() {
        let params = DepthParams::default();
        assert!(column_angle(&params, 0) > 0.7 && column_angle(&params, 55) < -0.7, "left first");
        // Facing away from the wall: the map edge is 4 m behind, the robot faces −x (map edge 4 m).
        let near = run(Pose2::new(5.95, 4.0, 0.0), params.clone());
        assert!(near.iter().all(|&d| d == 0.1), "wall 0.05 m ahead clamps to min: {near:?}");
        let far = run(Pose2::new(4.0, 4.0, 0.0), DepthParams { max_m: 1.5, ..params });
        assert!(far.iter().all(|&d| d == 1.5), "beyond max reads max: {far:?}");
    }
}
