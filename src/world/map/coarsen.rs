//! Coarsening a map to a larger cell size, for experiments on 0.1 m grids like older ROS maps.
//! Two ways a coarse map comes about: a SLAM mapper run at that resolution (walls stay walls), or
//! a fine map's image shrunk and read back by map_server (thin walls beside unknown space fade
//! into unknown, so free space borders unknown cells that stop the LiDAR's rays).

use crate::world::map::occupancy::{Cell, OccupancyMap};
use crate::world::map::ros_io::{
    PGM_FREE, PGM_OCCUPIED, PGM_UNKNOWN, SAVE_FREE_THRESH, SAVE_OCCUPIED_THRESH,
};

/// How a coarse cell is drawn from the fine cells it covers.
#[derive(clap::ValueEnum, Clone, Copy, Debug, Default, PartialEq, Eq)]
#[value(rename_all = "snake_case")]
pub enum CoarsenRule {
    /// As a mapper at the coarse resolution: occupied when any fine cell is (a scanner hitting any
    /// part of it marks it), else unknown when more fine cells are unknown than free, else free.
    #[default]
    KeepWalls,
    /// As an image editor shrinking the map's PGM (mean grey level of the trinary image `save_ros_map`
    /// writes) and map_server reading it back with the thresholds it writes (occupied p > 0.65,
    /// free p < 0.196).
    AverageImage,
}

impl OccupancyMap {
    /// The map at `resolution_m` per cell (≥ the map's own), same origin. Each fine cell falls into
    /// the coarse cell containing its centre, and `rule` decides each coarse cell. The last row and
    /// column may cover fewer fine cells.
    ///
    /// # Panics
    /// If `resolution_m` is not finite or is below the map's resolution (that would invent cells).
    pub fn coarsened(&self, resolution_m: f32, rule: CoarsenRule) -> OccupancyMap {
        assert!(
            resolution_m.is_finite() && resolution_m >= self.resolution_m,
            "coarsening needs a resolution ≥ the map's {} m, got {resolution_m}",
            self.resolution_m
        );
        let ratio = f64::from(self.resolution_m) / f64::from(resolution_m);
        let coarse_index = |fine: usize| ((fine as f64 + 0.5) * ratio) as usize;
        let (width, height) = (coarse_index(self.width - 1) + 1, coarse_index(self.height - 1) + 1);
        // Per coarse cell: fine-cell counts indexed by `Cell` (free, occupied, unknown).
        let mut counts = vec![[0u32; 3]; width * height];
        for j in 0..self.height {
            for i in 0..self.width {
                counts[coarse_index(j) * width + coarse_index(i)][self.get(i, j) as usize] += 1;
            }
        }
        let p = |grey: u8| (255.0 - f64::from(grey)) / 255.0;
        let cells = counts
            .iter()
            .map(|&[free, occupied, unknown]| match rule {
                CoarsenRule::KeepWalls if occupied > 0 => Cell::Occupied,
                CoarsenRule::KeepWalls if unknown > free => Cell::Unknown,
                CoarsenRule::KeepWalls => Cell::Free,
                CoarsenRule::AverageImage => {
                    let sum = f64::from(free) * p(PGM_FREE)
                        + f64::from(occupied) * p(PGM_OCCUPIED)
                        + f64::from(unknown) * p(PGM_UNKNOWN);
                    match sum / f64::from(free + occupied + unknown) {
                        mean if mean > SAVE_OCCUPIED_THRESH => Cell::Occupied,
                        mean if mean < SAVE_FREE_THRESH => Cell::Free,
                        _ => Cell::Unknown,
                    }
                }
            })
            .collect();
        OccupancyMap { resolution_m, origin: self.origin, width, height, cells }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::world::Pose2;

    #[test]
    fn coarsening_keeps_walls_and_unknown() {
        let mut fine = OccupancyMap::from_ascii(
            0.05,
            "
            ??????
            ???.??
            ....#.
            ......
            ",
        );
        fine.origin = Pose2::new(1.0, -2.0, 0.3);
        let coarse = fine.coarsened(0.1, CoarsenRule::KeepWalls);
        assert_eq!((coarse.width, coarse.height, coarse.resolution_m), (3, 2, 0.1));
        assert_eq!(coarse.origin, fine.origin, "same origin");
        let expected = OccupancyMap::from_ascii(0.1, "???\n..#");
        assert_eq!(
            coarse.cells, expected.cells,
            "one occupied fine cell is enough; 3 of 4 unknown stays unknown"
        );
        let tied = OccupancyMap::from_ascii(0.05, "??\n..").coarsened(0.1, CoarsenRule::KeepWalls);
        assert_eq!(tied.cells, vec![Cell::Free], "half observed counts as observed");
    }

    #[test]
    fn averaging_the_image_turns_thin_walls_beside_unknown_into_unknown() {
        let fine = OccupancyMap::from_ascii(
            0.05,
            "
            ??##??##
            ??##?#..
            ........
            ........
            ",
        );
        // Top blocks' mean p: 0.196 (all unknown), 1, (1 + 3 × 0.196) / 4 = 0.40, (2 + 2 × 0.004) / 4 = 0.50.
        let averaged = fine.coarsened(0.1, CoarsenRule::AverageImage);
        assert_eq!(averaged.cells, OccupancyMap::from_ascii(0.1, "?#??\n....").cells);
        let kept = fine.coarsened(0.1, CoarsenRule::KeepWalls);
        assert_eq!(kept.cells, OccupancyMap::from_ascii(0.1, "?###\n....").cells, "kept walls close the top");
    }

    #[test]
    fn coarsening_to_a_non_integer_ratio_covers_every_fine_cell() {
        let mut fine = OccupancyMap::filled(10, 7, 0.03, Cell::Free);
        fine.set(9, 6, Cell::Occupied);
        let coarse = fine.coarsened(0.1, CoarsenRule::KeepWalls);
        // 0.3 × 0.21 m: the last fine row's centre (0.195 m) lies in the second coarse row.
        assert_eq!((coarse.width, coarse.height), (3, 2));
        assert_eq!(coarse.get(2, 1), Cell::Occupied, "the far corner lands in the last cell");
        assert_eq!(coarse.counts(), (5, 1, 0));
        for rule in [CoarsenRule::KeepWalls, CoarsenRule::AverageImage] {
            assert_eq!(fine.coarsened(0.03, rule), fine, "the same resolution is the same map");
        }
    }
}
