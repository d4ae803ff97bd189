//! Axis-aligned rectangles of grid cells: the unit floor plans and furniture are drawn in.

/// Cells `x0..x1` × `y0..y1` (half-open, grid indices; `y` grows upwards like the map's rows).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) struct CellRect {
    pub x0: i32,
    pub y0: i32,
    pub x1: i32,
    pub y1: i32,
}

impl CellRect {
    pub fn new(x0: i32, y0: i32, x1: i32, y1: i32) -> Self {
        Self { x0, y0, x1, y1 }
    }

    pub fn width(&self) -> i32 {
        self.x1 - self.x0
    }

    pub fn height(&self) -> i32 {
        self.y1 - self.y0
    }

    /// Number of cells (0 for an empty rectangle).
    pub fn area(&self) -> i64 {
        i64::from(self.width().max(0)) * i64::from(self.height().max(0))
    }

    /// Whether the two rectangles share at least one cell.
    pub fn intersects(&self, other: &CellRect) -> bool {
        self.x0 < other.x1 && other.x0 < self.x1 && self.y0 < other.y1 && other.y0 < self.y1
    }

    /// Whether every cell of `other` lies in `self`.
    pub fn contains(&self, other: &CellRect) -> bool {
        other.x0 >= self.x0 && other.x1 <= self.x1 && other.y0 >= self.y0 && other.y1 <= self.y1
    }

    /// Euclidean width of the free gap between two rectangles, cells (0 if they touch or overlap).
    pub fn gap(&self, other: &CellRect) -> f32 {
        let gx = (other.x0 - self.x1).max(self.x0 - other.x1).max(0) as f32;
        let gy = (other.y0 - self.y1).max(self.y0 - other.y1).max(0) as f32;
        gx.hypot(gy)
    }

    /// The rectangle shrunk by `left_bottom` cells on its left and bottom sides and `right_top`
    /// cells on its right and top sides.
    pub fn inset(&self, left_bottom: i32, right_top: i32) -> CellRect {
        CellRect::new(self.x0 + left_bottom, self.y0 + left_bottom, self.x1 - right_top, self.y1 - right_top)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn gap_counts_free_cells_between_rectangles() {
        let a = CellRect::new(0, 0, 5, 5);
        assert_eq!(a.gap(&CellRect::new(7, 0, 9, 5)), 2.0, "cells 5 and 6 lie between");
        assert_eq!(a.gap(&CellRect::new(5, 5, 6, 6)), 0.0, "diagonal neighbours touch");
        assert_eq!(a.gap(&CellRect::new(8, 9, 9, 10)), 5.0, "3-4-5 diagonal gap");
        assert!(a.intersects(&CellRect::new(4, 4, 6, 6)) && !a.intersects(&CellRect::new(5, 0, 6, 5)));
    }

    #[test]
    fn inset_and_contains() {
        let a = CellRect::new(0, 0, 10, 8);
        let inner = a.inset(1, 2);
        assert_eq!(inner, CellRect::new(1, 1, 8, 6));
        assert!(a.contains(&inner) && !inner.contains(&a));
        assert_eq!(inner.area(), 35);
    }
}
