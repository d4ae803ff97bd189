//! The fine occupancy grid the simulator drives, senses and plans on.

use crate::world::pose::Pose2;
use bevy::prelude::Component;

/// State of one grid cell. Unknown cells stop LiDAR rays and are not traversable (as in nav2).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[repr(u8)]
pub enum Cell {
    Free,
    Occupied,
    Unknown,
}

/// A 2D occupancy grid. Cell (0, 0) is the bottom-left one, its corner at `origin`; row `j`
/// grows along the map's +y. `cells[j * width + i]`.
#[derive(Component, Clone, Debug, PartialEq)]
pub struct OccupancyMap {
    /// Cell side, metres.
    pub resolution_m: f32,
    /// World pose of the bottom-left corner of cell (0, 0); yaw rotates the whole grid.
    pub origin: Pose2,
    pub width: usize,
    pub height: usize,
    pub cells: Vec<Cell>,
}

impl OccupancyMap {
    /// A map of `width × height` cells all set to `fill`.
    pub fn filled(width: usize, height: usize, resolution_m: f32, fill: Cell) -> Self {
        Self { resolution_m, origin: Pose2::default(), width, height, cells: vec![fill; width * height] }
    }

    /// Parses an ASCII drawing: `#` occupied, `.` free, `?` unknown; the first line is the top row.
    /// Meant for tests and examples; panics on ragged rows or other characters.
    pub fn from_ascii(resolution_m: f32, drawing: &str) -> Self {
        let rows: Vec<&str> = drawing.lines().map(str::trim).filter(|l| !l.is_empty()).collect();
        let height = rows.len();
        let width = rows.first().map_or(0, |r| r.len());
        let mut map = Self::filled(width, height, resolution_m, Cell::Unknown);
        for (top_row, line) in rows.iter().enumerate() {
            assert_eq!(line.len(), width, "ragged ASCII map row {top_row}");
            for (i, ch) in line.chars().enumerate() {
                let cell = match ch {
                    '#' => Cell::Occupied,
                    '.' => Cell::Free,
                    '?' => Cell::Unknown,
                    other => panic!("unexpected ASCII map character {other:?}"),
                };
                map.set(i, height - 1 - top_row, cell);
            }
        }
        map
    }

    pub fn index(&self, i: usize, j: usize) -> usize {
        j * self.width + i
    }

    pub fn get(&self, i: usize, j: usize) -> Cell {
        self.cells[self.index(i, j)]
    }

    pub fn set(&mut self, i: usize, j: usize, cell: Cell) {
        let k = self.index(i, j);
        self.cells[k] = cell;
    }

    /// Width and height in metres.
    pub fn size_m(&self) -> (f32, f32) {
        (self.width as f32 * self.resolution_m, self.height as f32 * self.resolution_m)
    }

    /// Continuous grid coordinates of a world point, in cells (cell (i, j) spans [i, i+1) × [j, j+1)).
    pub fn world_to_grid(&self, x: f32, y: f32) -> (f32, f32) {
        let (dx, dy) = (x - self.origin.x, y - self.origin.y);
        let (s, c) = self.origin.yaw.sin_cos();
        ((c * dx + s * dy) / self.resolution_m, (-s * dx + c * dy) / self.resolution_m)
    }

    /// World coordinates of a point given in continuous grid coordinates.
    pub fn grid_to_world(&self, gx: f32, gy: f32) -> (f32, f32) {
        self.origin.transform_point(gx * self.resolution_m, gy * self.resolution_m)
    }

    /// The cell containing a world point, if it lies on the map.
    pub fn cell_at(&self, x: f32, y: f32) -> Option<(usize, usize)> {
        let (gx, gy) = self.world_to_grid(x, y);
        (gx >= 0.0 && gy >= 0.0 && (gx as usize) < self.width && (gy as usize) < self.height)
            .then_some((gx as usize, gy as usize))
    }

    /// World coordinates of a cell's centre.
    pub fn cell_center(&self, i: usize, j: usize) -> (f32, f32) {
        self.grid_to_world(i as f32 + 0.5, j as f32 + 0.5)
    }

    /// The cell at a world point; points off the map read as unknown.
    pub fn cell_at_point(&self, x: f32, y: f32) -> Cell {
        self.cell_at(x, y).map_or(Cell::Unknown, |(i, j)| self.get(i, j))
    }

    /// Number of cells in each state: (free, occupied, unknown).
    pub fn counts(&self) -> (usize, usize, usize) {
        self.cells.iter().fold((0, 0, 0), |(f, o, u), c| match c {
            Cell::Free => (f + 1, o, u),
            Cell::Occupied => (f, o + 1, u),
            Cell::Unknown => (f, o, u + 1),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ascii_top_row_is_highest_j() {
        let map = OccupancyMap::from_ascii(0.5, "#..\n...\n..?");
        assert_eq!((map.width, map.height), (3, 3));
        assert_eq!(map.get(0, 2), Cell::Occupied, "first line is the top row");
        assert_eq!(map.get(2, 0), Cell::Unknown);
        assert_eq!(map.counts(), (7, 1, 1));
    }

    #[test]
    fn world_grid_round_trip_with_rotated_origin() {
        let mut map = OccupancyMap::filled(10, 10, 0.1, Cell::Free);
        map.origin = Pose2::new(1.0, 2.0, 0.5);
        let (x, y) = map.cell_center(3, 7);
        assert_eq!(map.cell_at(x, y), Some((3, 7)));
        assert_eq!(map.cell_at(-5.0, -5.0), None);
    }
}
