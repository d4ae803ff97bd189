//! The LiDAR observation grid of the reference implementation: the scan rasterised into an
//! egocentric occupancy image (0 = occupied, 0.5 = unknown, 1 = free), the input of PF-net's
//! observation encoder and of the agent.

use crate::params::{StepParams, expect_param};
use crate::sense::lidar::LidarScan;
use bevy::prelude::*;
use serde::{Deserialize, Serialize};

/// Value of an occupied cell (reference encoding).
const OCCUPIED: f32 = 0.0;
/// Value of a cell the scan says nothing about (reference encoding).
const UNKNOWN: f32 = 0.5;
/// Value of a cell a ray passed through (reference encoding).
const FREE: f32 = 1.0;

/// Size of the fine raster and of the resized output.
#[derive(Resource, Serialize, Deserialize, Clone, Debug, PartialEq)]
#[serde(default, deny_unknown_fields)]
pub struct LocalGridParams {
    /// Side of the fine raster, cells (reference code: 128).
    pub cells: usize,
    /// Side of the square window centred on the robot, metres (reference code: 5.0).
    pub extent_m: f32,
    /// Side of the output after the box (area) resize, cells (reference code / PF-net input: 56).
    pub out_cells: usize,
    /// Radius of the robot footprint drawn free around the centre, metres (reference code: 0.32).
    pub footprint_radius_m: f32,
    /// Beyond the reference: the same scan rasterised again over this wider window (same cells),
    /// for a PF-net with a wide view (`PfNetConfig::wide_view`). Absent: one grid.
    pub wide_extent_m: Option<f32>,
}

impl Default for LocalGridParams {
    fn default() -> Self {
        Self { cells: 128, extent_m: 5.0, out_cells: 56, footprint_radius_m: 0.32, wide_extent_m: None }
    }
}

impl StepParams for LocalGridParams {
    fn check(&self) -> Result<(), String> {
        crate::limits::RASTER_SIDE.check("cells", self.cells)?;
        crate::limits::RASTER_SIDE.check("out_cells", self.out_cells)?;
        expect_param(self.extent_m > 0.0, "extent_m", "an extent > 0 m")?;
        if let Some(wide) = self.wide_extent_m {
            expect_param(wide.is_finite() && wide > 0.0, "wide_extent_m", "an extent > 0 m")?;
        }
        expect_param(self.footprint_radius_m >= 0.0, "footprint_radius_m", "a radius ≥ 0 m")
    }
}

/// Egocentric occupancy image of the last scan: `cells × cells` values, row-major, row 0 at the
/// top. The robot sits at the centre facing up: row 0 is farthest ahead, the last row farthest
/// behind, column 0 is the robot's far left (+y of the robot frame), the last column its right.
/// Values: 0 = occupied, 0.5 = unknown, 1 = free, fractions where the resize mixes them.
#[derive(Component, Clone, Debug, Default, PartialEq)]
pub struct LocalGrid {
    pub cells: usize,
    /// Side of the window the scan was rasterised over, metres (`LocalGridParams::extent_m`).
    pub extent_m: f32,
    pub values: Vec<f32>,
    /// The same scan over `LocalGridParams::wide_extent_m`, when asked for.
    pub wide: Option<WideGrid>,
}

/// A second raster of the scan over a wider window: same cells and layout as [`LocalGrid`].
#[derive(Clone, Debug, PartialEq)]
pub struct WideGrid {
    pub extent_m: f32,
    pub values: Vec<f32>,
}

/// Rasterises `scan` into `out` (`params.out_cells²` values, layout of [`LocalGrid`]): the
/// kernel of [`local_grid`]. On a `params.cells²` raster over `params.extent_m`, every ray marks
/// the cells it crosses free up to its end point, a reading below `range_max_m` marks its end
/// cell occupied (occupied wins over free), the footprint is drawn free last, and the raster is
/// box-resized (area average, like OpenCV's INTER_AREA) to `out_cells`.
pub fn rasterize_scan(scan: &LidarScan, params: &LocalGridParams, out: &mut [f32]) {
    let n = params.cells;
    let cell_m = params.extent_m / n as f32;
    let mut fine = vec![UNKNOWN; n * n];
    let centre = n as f32 / 2.0;
    // Raster coordinates: u = column (robot's −y), v = row from the top (robot's −x).
    let end_point = |k: usize| {
        let angle = scan.angle_min_rad + k as f32 * scan.angle_increment_rad;
        let r = scan.ranges_m[k] / cell_m;
        (centre - r * angle.sin(), centre - r * angle.cos())
    };
    let mut ends = Vec::with_capacity(scan.ranges_m.len());
    for k in 0..scan.ranges_m.len() {
        let (u, v) = end_point(k);
        let end = trace_free(&mut fine, n, centre, centre, u, v);
        if scan.ranges_m[k] < scan.range_max_m {
            ends.extend(end);
        }
    }
    for k in ends {
        fine[k] = OCCUPIED;
    }
    let r_cells = params.footprint_radius_m / cell_m;
    for (k, value) in fine.iter_mut().enumerate() {
        let (du, dv) = ((k % n) as f32 + 0.5 - centre, (k / n) as f32 + 0.5 - centre);
        if du * du + dv * dv <= r_cells * r_cells {
            *value = FREE;
        }
    }
    box_resize(&fine, n, out, params.out_cells);
}

/// Marks free every raster cell the segment (u0, v0) → (u1, v1) crosses before its end cell and
/// returns the end cell's index if it lies on the raster (the caller decides what it holds).
fn trace_free(fine: &mut [f32], n: usize, u0: f32, v0: f32, u1: f32, v1: f32) -> Option<usize> {
    let on = |i: i32, j: i32| i >= 0 && j >= 0 && (i as usize) < n && (j as usize) < n;
    let (mut i, mut j) = (u0.floor() as i32, v0.floor() as i32);
    let steps = (u1.floor() as i32 - i).abs() + (v1.floor() as i32 - j).abs();
    let (du, dv) = (u1 - u0, v1 - v0);
    let axis = |o: f32, d: f32, cell: i32| -> (i32, f32, f32) {
        if d > 0.0 {
            (1, (cell as f32 + 1.0 - o) / d, 1.0 / d)
        } else if d < 0.0 {
            (-1, (cell as f32 - o) / d, -1.0 / d)
        } else {
            (0, f32::INFINITY, f32::INFINITY)
        }
    };
    let ((si, mut ti, dti), (sj, mut tj, dtj)) = (axis(u0, du, i), axis(v0, dv, j));
    for _ in 0..steps {
        if !on(i, j) {
            return None;
        }
        fine[j as usize * n + i as usize] = FREE;
        if ti < tj {
            ti += dti;
            i += si;
        } else {
            tj += dtj;
            j += sj;
        }
    }
    on(i, j).then(|| {
        let k = j as usize * n + i as usize;
        fine[k] = FREE;
        k
    })
}

/// Area-weighted resize of a square `n_in²` image to `n_out²` (separable box filter).
fn box_resize(input: &[f32], n_in: usize, out: &mut [f32], n_out: usize) {
    let weights = area_weights(n_in, n_out);
    for (r, row_w) in weights.iter().enumerate() {
        for (c, col_w) in weights.iter().enumerate() {
            let mut acc = 0.0;
            for &(a, wa) in row_w {
                for &(b, wb) in col_w {
                    acc += wa * wb * input[a * n_in + b];
                }
            }
            out[r * n_out + c] = acc;
        }
    }
}

/// For each output index, the input indices it overlaps and their weights (summing to 1).
fn area_weights(n_in: usize, n_out: usize) -> Vec<Vec<(usize, f32)>> {
    let scale = n_in as f64 / n_out as f64;
    (0..n_out)
        .map(|o| {
            let (lo, hi) = (o as f64 * scale, (o + 1) as f64 * scale);
            (lo.floor() as usize..(hi.ceil() as usize).min(n_in))
                .map(|k| (k, ((hi.min(k as f64 + 1.0) - lo.max(k as f64)) / scale) as f32))
                .filter(|&(_, w)| w > 0.0)
                .collect()
        })
        .collect()
}

/// Reads LidarScan. Writes LocalGrid.
pub fn local_grid(params: Res<LocalGridParams>, mut robots: Query<(&LidarScan, &mut LocalGrid)>) {
    for (scan, mut grid) in robots.iter_mut() {
        grid.cells = params.out_cells;
        grid.extent_m = params.extent_m;
        grid.values.resize(params.out_cells * params.out_cells, UNKNOWN);
        rasterize_scan(scan, &params, &mut grid.values);
        grid.wide = params.wide_extent_m.map(|extent_m| {
            let mut values = vec![UNKNOWN; params.out_cells * params.out_cells];
            rasterize_scan(scan, &LocalGridParams { extent_m, ..params.clone() }, &mut values);
            WideGrid { extent_m, values }
        });
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sense::lidar::LidarParams;
    use bevy::ecs::system::RunSystemOnce;

    /// The paper's scan of a straight wall 1 m ahead (perpendicular to the heading).
    fn wall_ahead_scan() -> LidarScan {
        let params = LidarParams::default();
        let (angle_min, inc) = params.angles();
        let ranges = (0..params.rays)
            .map(|k| {
                let c = (angle_min + k as f32 * inc).cos();
                if c > 1.0 / 5.6 { 1.0 / c } else { 5.6 }
            })
            .collect();
        LidarScan {
            ranges_m: ranges,
            angle_min_rad: angle_min,
            angle_increment_rad: inc,
            range_min_m: 0.05,
            range_max_m: 5.6,
        }
    }

    fn run() -> LocalGrid {
        let mut world = World::new();
        world.insert_resource(LocalGridParams::default());
        let robot = world.spawn((wall_ahead_scan(), LocalGrid::default())).id();
        world.run_system_once(local_grid).unwrap();
        world.get::<LocalGrid>(robot).unwrap().clone()
    }

    #[test]
    fn local_grid_shows_the_wall_ahead() {
        let grid = run();
        assert_eq!((grid.cells, grid.values.len()), (56, 56 * 56), "56 × 56 output");
        let at = |r: usize, c: usize| grid.values[r * 56 + c];
        // 1 m ahead of the centre row 28 at 56 / 5 cells per metre: row ≈ 16.8.
        for c in 20..36 {
            let (row, min) =
                (0..28).map(|r| (r, at(r, c))).fold((0, 2.0), |m, x| if x.1 < m.1 { x } else { m });
            assert!(min < 0.4, "column {c}: wall should be dark, min {min} at row {row}");
            assert!((15..=17).contains(&row), "column {c}: wall at row {row}, expected ≈ 16");
            assert!((18..26).all(|r| at(r, c) > 0.9), "column {c}: free between robot and wall");
            assert!((0..14).all(|r| at(r, c) == 0.5), "column {c}: beyond the wall is unknown");
        }
    }

    #[test]
    fn local_grid_behind_is_unknown_and_centre_free() {
        let grid = run();
        let at = |r: usize, c: usize| grid.values[r * 56 + c];
        for (r, c) in [(40, 27), (44, 28), (50, 27), (55, 28)] {
            assert_eq!(at(r, c), 0.5, "({r}, {c}) lies behind the robot, outside the 240° fov");
        }
        for (r, c) in [(27, 27), (27, 28), (28, 27), (28, 28)] {
            assert!((at(r, c) - 1.0).abs() < 1e-5, "centre ({r}, {c}) is the free footprint: {}", at(r, c));
        }
    }

    #[test]
    fn local_grid_left_is_left() {
        // A single hit 1 m to the robot's left must land left of the centre column.
        let scan = LidarScan {
            ranges_m: vec![1.0],
            angle_min_rad: std::f32::consts::FRAC_PI_2,
            angle_increment_rad: 0.0,
            range_min_m: 0.05,
            range_max_m: 5.6,
        };
        let params = LocalGridParams::default();
        let mut out = vec![0.0; 56 * 56];
        rasterize_scan(&scan, &params, &mut out);
        let row: Vec<f32> = (0..56).map(|c| out[27 * 56 + c].min(out[28 * 56 + c])).collect();
        let darkest = (0..56).min_by(|&a, &b| row[a].total_cmp(&row[b])).unwrap_or(0);
        assert!((16..=17).contains(&darkest), "hit to the left at column {darkest}, row {row:?}");
    }

    #[test]
    fn the_wide_grid_is_the_same_scan_over_a_wider_window() {
        let mut world = World::new();
        world.insert_resource(LocalGridParams { wide_extent_m: Some(10.0), ..default() });
        let robot = world.spawn((wall_ahead_scan(), LocalGrid::default())).id();
        world.run_system_once(local_grid).unwrap();
        let grid = world.get::<LocalGrid>(robot).unwrap().clone();
        assert_eq!(grid.values, run().values, "the paper's grid is unchanged");
        let wide = grid.wide.expect("asked for");
        let mut want = vec![0.0; 56 * 56];
        rasterize_scan(&wall_ahead_scan(), &LocalGridParams { extent_m: 10.0, ..default() }, &mut want);
        assert_eq!((wide.extent_m, &wide.values), (10.0, &want));
        // The wall 1 m ahead sits half as far from the centre row: row ≈ 28 − 5.6 ≈ 22.
        let darkest = (0..28).min_by(|&a, &b| want[a * 56 + 28].total_cmp(&want[b * 56 + 28])).unwrap();
        assert!((21..=23).contains(&darkest), "wall at row {darkest}");
        assert!(run().wide.is_none(), "no wide grid unless asked");
    }
}
