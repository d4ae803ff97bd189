//! What PF-net observes: the LiDAR occupancy grid (the paper's LiDAR setting), the depth strip
//! (its RGB-D setting, reduced to our one-row camera), or both as two channels of one image; and
//! how the depth strip becomes an image the convolutional observation encoder can read.

use serde::{Deserialize, Serialize};

/// Depth covered by one row of a depth image, metres: the LiDAR grid's cell, so that both
/// channels see 5.6 m ahead at the same scale.
pub const DEPTH_BIN_M: f32 = 0.1;

/// The sensor behind the observation image.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Observation {
    /// The 56 × 56 LiDAR occupancy grid around the robot (`local_grid`).
    #[default]
    Grid,
    /// The depth camera's strip (`depth`) as a depth image, see [`depth_image`].
    Depth,
    /// The grid, then the depth image: two channels.
    GridAndDepth,
}

impl Observation {
    /// Channels of the observation image.
    pub fn channels(self) -> usize {
        match self {
            Self::Grid | Self::Depth => 1,
            Self::GridAndDepth => 2,
        }
    }

    /// The name a RON file gives it.
    pub fn name(self) -> &'static str {
        match self {
            Self::Grid => "grid",
            Self::Depth => "depth",
            Self::GridAndDepth => "grid_and_depth",
        }
    }

    pub fn uses_grid(self) -> bool {
        self != Self::Depth
    }

    pub fn uses_depth(self) -> bool {
        self != Self::Grid
    }

    /// One observation image `[channels][cells²]` split into the grid's channel and the depth
    /// image's, each present when observed.
    pub fn split(self, image: &mut [f32]) -> (Option<&mut [f32]>, Option<&mut [f32]>) {
        match self {
            Self::Grid => (Some(image), None),
            Self::Depth => (None, Some(image)),
            Self::GridAndDepth => {
                let (grid, depth) = image.split_at_mut(image.len() / 2);
                (Some(grid), Some(depth))
            }
        }
    }
}

/// The depth strip (one depth per camera column, left to right) as a `cells × cells` image in the
/// grid's encoding: image column j is the camera column under it, image row r the depth bin
/// `[(cells − 1 − r)·DEPTH_BIN_M, (cells − r)·DEPTH_BIN_M)` — far at the top, near at the bottom,
/// as the grid puts what lies ahead at the top. A pixel is 1 (free) where its bin lies wholly in
/// front of the column's depth, 0 from the surface on. A polar image (the camera's angle × depth),
/// not a top-down one: it keeps the sensor's own geometry, the convolutions learn the rest.
///
/// # Panics
/// If `depths_m` is empty or `out` is not `cells²` long.
pub fn depth_image(depths_m: &[f32], cells: usize, out: &mut [f32]) {
    assert!(!depths_m.is_empty(), "a depth strip has at least one column");
    assert_eq!(out.len(), cells * cells, "a depth image is cells² values");
    for (r, row) in out.chunks_exact_mut(cells).enumerate() {
        let far_edge = (cells - r) as f32 * DEPTH_BIN_M;
        for (j, pixel) in row.iter_mut().enumerate() {
            let depth = depths_m[j * depths_m.len() / cells];
            *pixel = if far_edge <= depth { 1.0 } else { 0.0 };
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn depth_image_by_hand() {
        // 4 × 4 image, bins of 0.1 m: rows reach 0.4, 0.3, 0.2, 0.1 m. Two camera columns per
        // image column pair: depths 0.25 m (left) and 10 m (right, nothing in range).
        let mut image = [f32::NAN; 16];
        depth_image(&[0.25, 10.0], 4, &mut image);
        #[rustfmt::skip]
        let want = [
            0.0, 0.0, 1.0, 1.0, // 0.3–0.4 m: behind the left surface
            0.0, 0.0, 1.0, 1.0, // 0.2–0.3 m: the left surface is in this bin
            1.0, 1.0, 1.0, 1.0, // 0.1–0.2 m: free
            1.0, 1.0, 1.0, 1.0, // 0.0–0.1 m: free
        ];
        assert_eq!(image, want);
    }

    #[test]
    fn channels_split_in_order() {
        let mut image: Vec<f32> = (0..8).map(|i| i as f32).collect();
        let (grid, depth) = Observation::GridAndDepth.split(&mut image);
        assert_eq!((grid.unwrap()[0], depth.unwrap()[0]), (0.0, 4.0), "grid first, then depth");
        assert!(
            Observation::Grid.split(&mut image).1.is_none()
                && Observation::Depth.split(&mut image).0.is_none()
        );
        assert_eq!(
            [Observation::Grid, Observation::Depth, Observation::GridAndDepth].map(|o| o.channels()),
            [1, 1, 2]
        );
    }
}
