//! The ray caster behind every range sensor: exact grid ray casting (Amanatides–Woo) on the fine
//! occupancy grid, accelerated by a Chebyshev clearance field, plus other robots as discs.
//!
//! A cell blocks a ray when it is not free: occupied and unknown cells stop rays (as in nav2), and
//! so does everything off the map. The range is the distance to the boundary of the first blocking
//! cell the ray enters, or the maximum range.

use crate::world::{Cell, OccupancyMap, Pose2};
use bevy::prelude::Component;

/// Smallest clearance (cells) at which the caster jumps instead of stepping cell by cell. A jump
/// costs about three DDA steps (a multiply-add, two truncations, two boundary times), so jumping
/// over fewer than two cells does not pay. Justified by `benches/raycast.rs` (group
/// `raycast/apartment` and `raycast/depot`, `fan_228` vs `reference_dda`).
const JUMP_MIN_CLEARANCE: u8 = 3;

/// Safety margin of a jump, cells: keeps the landing point strictly inside the free square despite
/// f32 rounding (coordinates up to ~2,000 cells carry ≤ 2.5e-4 cells of error).
const JUMP_MARGIN_CELLS: f32 = 0.01;

/// The map prepared for ray casting; built once per map with [`RayGrid::from_map`] and stored on
/// the map entity. Derived data with an invariant (the clearance field), hence private fields.
#[derive(Component, Clone, Debug)]
pub struct RayGrid {
    width: usize,
    height: usize,
    /// Row length of the padded field: `width + 2` (a blocking border all round).
    stride: usize,
    resolution_m: f32,
    inv_resolution: f32,
    origin: Pose2,
    origin_sin: f32,
    origin_cos: f32,
    /// Chebyshev distance (cells, capped at 255) from each padded cell to the nearest blocking
    /// cell; 0 = blocking. Every cell within distance `c − 1` of a cell with clearance `c` is free.
    clearance: Vec<u8>,
}

/// A ray in the grid frame: origin in cells (cell (i, j) spans [i, i+1) × [j, j+1)), unit
/// direction, and the maximum length in cells.
#[derive(Clone, Copy, Debug)]
struct GridRay {
    ox: f32,
    oy: f32,
    dx: f32,
    dy: f32,
    t_max: f32,
}

/// One axis of the DDA: the parameter at which the ray leaves column (or row) `i` is
/// `(i − o_b) · inv`. Computed from the index, never accumulated, so the fast caster and the
/// reference agree to the last bit on every cell they both visit.
#[derive(Clone, Copy, Debug)]
struct Axis {
    step: i32,
    o_b: f32,
    inv: f32,
}

impl Axis {
    fn new(o: f32, d: f32) -> Self {
        if d < 0.0 {
            Self { step: -1, o_b: o, inv: 1.0 / d }
        } else if d > 0.0 {
            Self { step: 1, o_b: o - 1.0, inv: 1.0 / d }
        } else {
            // Parallel to this axis: never crosses a boundary (i + 1 − o > 0, times +∞).
            Self { step: 1, o_b: o - 1.0, inv: f32::INFINITY }
        }
    }

    #[inline(always)]
    fn exit(&self, i: i32) -> f32 {
        (i as f32 - self.o_b) * self.inv
    }
}

impl RayGrid {
    /// Prepares `map` for casting: marks blocking cells and computes the clearance field.
    pub fn from_map(map: &OccupancyMap) -> RayGrid {
        let (width, height) = (map.width, map.height);
        let stride = width + 2;
        let rows = height + 2;
        // Two-pass chamfer with unit weights on all 8 neighbours = exact Chebyshev distance.
        let mut dist = vec![u16::MAX; stride * rows];
        for pj in 0..rows {
            for pi in 0..stride {
                let on_map = pi >= 1 && pj >= 1 && pi <= width && pj <= height;
                // A short `cells` vector reads as blocking rather than panicking.
                let free = on_map && map.cells.get((pj - 1) * width + pi - 1) == Some(&Cell::Free);
                if !free {
                    dist[pj * stride + pi] = 0;
                }
            }
        }
        for pj in 0..rows {
            for pi in 0..stride {
                let k = pj * stride + pi;
                let mut d = dist[k];
                if pi > 0 {
                    d = d.min(dist[k - 1].saturating_add(1));
                }
                if pj > 0 {
                    let up = k - stride;
                    d = d.min(dist[up].saturating_add(1));
                    if pi > 0 {
                        d = d.min(dist[up - 1].saturating_add(1));
                    }
                    if pi + 1 < stride {
                        d = d.min(dist[up + 1].saturating_add(1));
                    }
                }
                dist[k] = d;
            }
        }
        for pj in (0..rows).rev() {
            for pi in (0..stride).rev() {
                let k = pj * stride + pi;
                let mut d = dist[k];
                if pi + 1 < stride {
                    d = d.min(dist[k + 1].saturating_add(1));
                }
                if pj + 1 < rows {
                    let down = k + stride;
                    d = d.min(dist[down].saturating_add(1));
                    if pi > 0 {
                        d = d.min(dist[down - 1].saturating_add(1));
                    }
                    if pi + 1 < stride {
                        d = d.min(dist[down + 1].saturating_add(1));
                    }
                }
                dist[k] = d;
            }
        }
        let clearance = dist.into_iter().map(|d| d.min(255) as u8).collect();
        let (origin_sin, origin_cos) = map.origin.yaw.sin_cos();
        RayGrid {
            width,
            height,
            stride,
            resolution_m: map.resolution_m,
            inv_resolution: 1.0 / map.resolution_m,
            origin: map.origin,
            origin_sin,
            origin_cos,
            clearance,
        }
    }

    pub fn width(&self) -> usize {
        self.width
    }

    pub fn height(&self) -> usize {
        self.height
    }

    /// Cell side, metres.
    pub fn resolution_m(&self) -> f32 {
        self.resolution_m
    }

    /// Whether the cell (i, j) stops rays (off-map cells do).
    pub fn blocks(&self, i: i64, j: i64) -> bool {
        let on_map = i >= 0 && j >= 0 && (i as usize) < self.width && (j as usize) < self.height;
        !on_map || self.clearance[self.padded_index(i as i32, j as i32)] == 0
    }

    /// Range from the world point (x, y) along the world-frame heading `angle`, metres: the
    /// distance to the first blocking cell boundary, or `max_range_m` if there is none closer.
    /// A ray starting in a blocking cell or off the map reads 0.
    pub fn cast(&self, x: f32, y: f32, angle: f32, max_range_m: f32) -> f32 {
        let (ox, oy) = self.to_grid(x, y);
        let (dy, dx) = (angle - self.origin.yaw).sin_cos();
        self.cast_grid(ox, oy, dx, dy, max_range_m)
    }

    /// A fan of rays from `origin`: ray k points at `origin.yaw + angle_min + k · angle_increment`
    /// (angles in the origin's frame, CCW), one range per element of `out`. `discs` are extra
    /// round obstacles (world x, y, radius in metres; e.g. the other robots on this map) checked
    /// with an exact ray–circle test on top of the grid result; a disc containing the ray origin
    /// is ignored (a robot does not see itself). Pass `&[]` for none.
    pub fn cast_fan(
        &self,
        origin: Pose2,
        angle_min: f32,
        angle_increment: f32,
        max_range_m: f32,
        discs: &[(f32, f32, f32)],
        out: &mut [f32],
    ) {
        let (ox, oy) = self.to_grid(origin.x, origin.y);
        // Ray directions by complex rotation in f64: one sin_cos per fan instead of per ray,
        // error ~1e-15 rad after 228 rays (bench `raycast/*/fan_228`).
        let base = f64::from(origin.yaw - self.origin.yaw) + f64::from(angle_min);
        let (mut s, mut c) = base.sin_cos();
        let (ds, dc) = f64::from(angle_increment).sin_cos();
        let (ms, mc) = (self.origin_sin, self.origin_cos);
        for range in out.iter_mut() {
            let (dx, dy) = (c as f32, s as f32);
            let mut r = self.cast_grid(ox, oy, dx, dy, max_range_m);
            if !discs.is_empty() {
                // World-frame direction: rotate the grid-frame one by the map's yaw.
                let (wx, wy) = (mc * dx - ms * dy, ms * dx + mc * dy);
                for &(cx, cy, radius) in discs {
                    if let Some(t) = ray_disc(origin.x, origin.y, wx, wy, cx, cy, radius) {
                        r = r.min(t);
                    }
                }
            }
            *range = r;
            (s, c) = (s * dc + c * ds, c * dc - s * ds);
        }
    }

    fn to_grid(&self, x: f32, y: f32) -> (f32, f32) {
        let (dx, dy) = (x - self.origin.x, y - self.origin.y);
        let (s, c) = (self.origin_sin, self.origin_cos);
        ((c * dx + s * dy) * self.inv_resolution, (-s * dx + c * dy) * self.inv_resolution)
    }

    #[inline(always)]
    fn padded_index(&self, i: i32, j: i32) -> usize {
        (j + 1) as usize * self.stride + (i + 1) as usize
    }

    fn cast_grid(&self, ox: f32, oy: f32, dx: f32, dy: f32, max_range_m: f32) -> f32 {
        if max_range_m.is_nan() || max_range_m <= 0.0 {
            return 0.0;
        }
        let ray = GridRay { ox, oy, dx, dy, t_max: max_range_m * self.inv_resolution };
        match self.march(&ray) {
            Some(t) => (t * self.resolution_m).min(max_range_m),
            None => max_range_m,
        }
    }

    /// The accelerated DDA: in cells with clearance ≥ [`JUMP_MIN_CLEARANCE`] it jumps along the
    /// ray by the clearance (the free square around the cell cannot hold a wall), elsewhere it
    /// steps cell by cell exactly like [`cast_reference`]. Returns the hit parameter in cells, or
    /// `None` when nothing blocks within `t_max`.
    fn march(&self, ray: &GridRay) -> Option<f32> {
        let GridRay { ox, oy, dx, dy, t_max } = *ray;
        // `contains` is false for NaN too.
        let on_map = (0.0..self.width as f32).contains(&ox) && (0.0..self.height as f32).contains(&oy);
        if !on_map || !dx.is_finite() || !dy.is_finite() {
            return Some(0.0);
        }
        let clear = &self.clearance;
        let (ax, ay) = (Axis::new(ox, dx), Axis::new(oy, dy));
        let (kx, ky) = (ax.step as isize, ay.step as isize * self.stride as isize);
        let inv_linf = 1.0 / dx.abs().max(dy.abs());
        // Non-negative on the map, so truncation is floor (no libm call on baseline x86-64).
        let (mut i, mut j) = (ox as i32, oy as i32);
        let mut k = self.padded_index(i, j);
        let (mut tx, mut ty) = (ax.exit(i), ay.exit(j));
        let mut t = 0.0f32;
        loop {
            let c = clear[k];
            if c == 0 {
                return Some(t);
            }
            if c >= JUMP_MIN_CLEARANCE {
                t += (f32::from(c) - 1.0 - JUMP_MARGIN_CELLS) * inv_linf;
                if t >= t_max {
                    return None;
                }
                (i, j) = ((ox + t * dx) as i32, (oy + t * dy) as i32);
                k = self.padded_index(i, j);
                (tx, ty) = (ax.exit(i), ay.exit(j));
                continue;
            }
            // `max`: a landing point exactly on a cell boundary (a ray along a grid line) can be
            // floored into the cell the ray is leaving, whose exit time lies behind; t never
            // goes back, so the loop always progresses.
            if tx < ty {
                t = t.max(tx);
                i += ax.step;
                k = k.wrapping_add_signed(kx);
                tx = ax.exit(i);
            } else {
                t = t.max(ty);
                j += ay.step;
                k = k.wrapping_add_signed(ky);
                ty = ay.exit(j);
            }
            if t >= t_max {
                return None;
            }
        }
    }
}

/// Distance along a unit ray from (x, y) to the disc (cx, cy, radius), if the ray starts outside
/// the disc and hits it.
fn ray_disc(x: f32, y: f32, dx: f32, dy: f32, cx: f32, cy: f32, radius: f32) -> Option<f32> {
    let (px, py) = (cx - x, cy - y);
    let inside = px * px + py * py - radius * radius;
    let b = px * dx + py * dy;
    if inside <= 0.0 || b <= 0.0 {
        return None;
    }
    let disc = b * b - inside;
    (disc >= 0.0).then(|| b - disc.sqrt())
}

/// Plain Amanatides–Woo DDA on the occupancy grid, one cell at a time: the test oracle for
/// [`RayGrid::cast`] and the baseline of `benches/raycast.rs`. Same arguments and result.
pub fn cast_reference(map: &OccupancyMap, x: f32, y: f32, angle: f32, max_range_m: f32) -> f32 {
    if max_range_m.is_nan() || max_range_m <= 0.0 {
        return 0.0;
    }
    // Same arithmetic as RayGrid::to_grid, so both casters see the same ray.
    let (s, c) = map.origin.yaw.sin_cos();
    let inv_res = 1.0 / map.resolution_m;
    let (rx, ry) = (x - map.origin.x, y - map.origin.y);
    let (ox, oy) = ((c * rx + s * ry) * inv_res, (-s * rx + c * ry) * inv_res);
    let (dy, dx) = (angle - map.origin.yaw).sin_cos();
    let t_max = max_range_m * inv_res;
    let blocks = |i: i64, j: i64| {
        let on_map = i >= 0 && j >= 0 && (i as usize) < map.width && (j as usize) < map.height;
        !on_map || map.get(i as usize, j as usize) != Cell::Free
    };
    if !(ox >= 0.0 && oy >= 0.0 && ox.is_finite() && oy.is_finite() && dx.is_finite()) {
        return 0.0;
    }
    let (mut i, mut j) = (ox as i64, oy as i64);
    if blocks(i, j) {
        return 0.0;
    }
    let (ax, ay) = (Axis::new(ox, dx), Axis::new(oy, dy));
    loop {
        let (tx, ty) = (ax.exit(i as i32), ay.exit(j as i32));
        let t = if tx < ty {
            i += i64::from(ax.step);
            tx
        } else {
            j += i64::from(ay.step);
            ty
        };
        if t >= t_max {
            return max_range_m;
        }
        if blocks(i, j) {
            return (t * map.resolution_m).min(max_range_m);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testing::tiny_room;
    use rand::{Rng, SeedableRng};
    use rand_pcg::Pcg64Mcg;
    use std::f32::consts::{FRAC_PI_2, FRAC_PI_4, PI};

    /// A 4 m × 4 m free square at 0.1 m with walls on all sides (inner free area 0.1..3.9 m).
    fn square_room() -> OccupancyMap {
        let mut map = OccupancyMap::filled(40, 40, 0.1, Cell::Free);
        for k in 0..40 {
            map.set(k, 0, Cell::Occupied);
            map.set(k, 39, Cell::Occupied);
            map.set(0, k, Cell::Occupied);
            map.set(39, k, Cell::Occupied);
        }
        map
    }

    #[test]
    fn raycast_walls_along_axes_and_diagonals() {
        let grid = RayGrid::from_map(&square_room());
        let (x, y) = (1.23f32, 2.04f32);
        let cases = [
            (0.0, 3.9 - x),
            (PI, x - 0.1),
            (FRAC_PI_2, 3.9 - y),
            (-FRAC_PI_2, y - 0.1),
            // Diagonal towards the top-right: hits whichever wall comes first.
            (FRAC_PI_4, ((3.9 - x).min(3.9 - y)) * 2f32.sqrt()),
            (-3.0 * FRAC_PI_4, ((x - 0.1).min(y - 0.1)) * 2f32.sqrt()),
        ];
        for (angle, expected) in cases {
            let r = grid.cast(x, y, angle, 10.0);
            assert!((r - expected).abs() < 1e-4, "angle {angle}: range {r}, expected {expected}");
            let reference = cast_reference(&square_room(), x, y, angle, 10.0);
            assert!((reference - expected).abs() < 1e-4, "reference at angle {angle}: {reference}");
        }
    }

    #[test]
    fn raycast_max_range_and_blocked_origin() {
        let grid = RayGrid::from_map(&square_room());
        assert_eq!(grid.cast(2.0, 2.0, 0.3, 1.0), 1.0, "nothing within 1 m reads max range");
        assert_eq!(grid.cast(0.05, 2.0, 0.0, 5.0), 0.0, "a ray starting inside a wall reads 0");
        assert_eq!(grid.cast(-1.0, 2.0, 0.0, 5.0), 0.0, "a ray starting off the map reads 0");
    }

    #[test]
    fn raycast_rays_along_grid_lines_terminate_and_agree() {
        // Origins on cell corners and fan directions a hair off the axes (cos(π/2) ≠ 0 in
        // floating point) once sent the marcher back and forth on the same boundary forever.
        let map = tiny_room();
        let grid = RayGrid::from_map(&map);
        let mut out = [0.0; 5];
        for (x, y) in [(0.4, 0.4), (0.5, 1.0), (1.0, 0.3)] {
            grid.cast_fan(Pose2::new(x, y, 0.0), -PI, FRAC_PI_2, 5.6, &[], &mut out);
            for (k, &r) in out.iter().enumerate() {
                let reference = cast_reference(&map, x, y, -PI + k as f32 * FRAC_PI_2, 5.6);
                assert!((r - reference).abs() < 1e-3, "({x}, {y}) ray {k}: {r} vs {reference}");
            }
        }
    }

    #[test]
    fn raycast_unknown_and_off_map_stop_rays() {
        // Row of free cells ending in unknown at x = 0.5 m; open (off-map) to the left.
        let map = OccupancyMap::from_ascii(0.1, "..........\n.....?....\n..........");
        let grid = RayGrid::from_map(&map);
        let r = grid.cast(0.05, 0.15, 0.0, 5.0);
        assert!((r - 0.45).abs() < 1e-5, "unknown cell at 0.5 m must stop the ray, got {r}");
        let r = grid.cast(0.35, 0.15, PI, 5.0);
        assert!((r - 0.35).abs() < 1e-5, "leaving the map must stop the ray, got {r}");
    }

    #[test]
    fn raycast_rotated_origin() {
        let mut map = square_room();
        map.origin = Pose2::new(5.0, -2.0, 0.7);
        let grid = RayGrid::from_map(&map);
        // A point 1.0 m from the grid's left wall face (grid x = 1.1 m), grid y = 2.0 m.
        let (x, y) = map.grid_to_world(11.0, 20.0);
        let toward_left_wall = 0.7 + PI;
        let r = grid.cast(x, y, toward_left_wall, 10.0);
        assert!((r - 1.0).abs() < 1e-4, "range in the rotated grid's frame: got {r}, expected 1.0");
        let along_grid_x = grid.cast(x, y, 0.7, 10.0);
        assert!((along_grid_x - 2.8).abs() < 1e-4, "got {along_grid_x}, expected 2.8");
    }

    fn assert_matches_reference(map: &OccupancyMap, rays: usize, seed: u64) {
        let grid = RayGrid::from_map(map);
        let mut rng = Pcg64Mcg::seed_from_u64(seed);
        let (w, h) = map.size_m();
        let mut hits = 0;
        for _ in 0..rays {
            let (gx, gy) = (rng.random_range(0.0..w), rng.random_range(0.0..h));
            let (x, y) = map.origin.transform_point(gx, gy);
            let angle = rng.random_range(-PI..PI);
            let max_range = rng.random_range(0.5..8.0);
            let fast = grid.cast(x, y, angle, max_range);
            let slow = cast_reference(map, x, y, angle, max_range);
            hits += usize::from(slow < max_range && slow > 0.0);
            assert!(
                (fast - slow).abs() < 1e-3,
                "ray from ({x}, {y}) at {angle} rad (max {max_range}): fast {fast}, reference {slow}"
            );
        }
        assert!(hits > rays / 10, "the test must exercise real hits, only {hits} of {rays}");
    }

    #[test]
    fn raycast_equals_reference_on_tiny_room() {
        assert_matches_reference(&tiny_room(), 5000, 1);
    }

    #[test]
    fn raycast_equals_reference_on_random_rotated_map() {
        let mut rng = Pcg64Mcg::seed_from_u64(9);
        let mut map = OccupancyMap::filled(300, 200, 0.05, Cell::Free);
        // Sparse clutter plus random rectangles: thin walls, open space and unknown blobs.
        for cell in map.cells.iter_mut() {
            let u: f32 = rng.random();
            *cell = if u < 0.01 {
                Cell::Occupied
            } else if u < 0.012 {
                Cell::Unknown
            } else {
                Cell::Free
            };
        }
        for _ in 0..40 {
            let (i0, j0) = (rng.random_range(0..290), rng.random_range(0..190));
            let (w, h) = (rng.random_range(1..40usize), rng.random_range(1..4usize));
            let (w, h) = if rng.random() { (w, h) } else { (h, w) };
            for j in j0..(j0 + h).min(200) {
                for i in i0..(i0 + w).min(300) {
                    map.set(i, j, Cell::Occupied);
                }
            }
        }
        map.origin = Pose2::new(-3.0, 4.0, -0.4);
        assert_matches_reference(&map, 20000, 2);
    }

    #[test]
    fn raycast_fan_matches_single_rays() {
        let map = tiny_room();
        let grid = RayGrid::from_map(&map);
        let pose = Pose2::new(0.55, 0.72, 2.5);
        let (amin, inc) = (-2.0, 4.0 / 227.0);
        let mut fan = vec![0.0; 228];
        grid.cast_fan(pose, amin, inc, 5.6, &[], &mut fan);
        for (k, &r) in fan.iter().enumerate() {
            let single = cast_reference(&map, pose.x, pose.y, pose.yaw + amin + k as f32 * inc, 5.6);
            assert!((r - single).abs() < 1e-3, "ray {k}: fan {r}, single {single}");
        }
    }

    #[test]
    fn raycast_discs_block_rays() {
        let grid = RayGrid::from_map(&square_room());
        let pose = Pose2::new(1.0, 2.0, 0.0);
        let discs = [(2.0, 2.0, 0.18), (1.0, 2.0, 0.18)]; // a robot ahead, and our own body
        let mut out = [0.0; 3];
        grid.cast_fan(pose, -FRAC_PI_2, FRAC_PI_2, 5.6, &discs, &mut out);
        assert!((out[1] - 0.82).abs() < 1e-4, "disc 1 m ahead, radius 0.18: got {}", out[1]);
        assert!((out[0] - 1.9).abs() < 1e-4, "own disc is ignored, wall to the right: got {}", out[0]);
        assert!((out[2] - 1.9).abs() < 1e-4, "wall to the left: got {}", out[2]);
        let mut without = [0.0; 3];
        grid.cast_fan(pose, -FRAC_PI_2, FRAC_PI_2, 5.6, &[], &mut without);
        assert!((without[1] - 2.9).abs() < 1e-4, "no discs: wall 2.9 m ahead, got {}", without[1]);
    }
}
