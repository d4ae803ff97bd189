//! The ray caster behind every range sensor: exact grid ray casting (Amanatides–Woo) on the fine
//! occupancy grid, accelerated by free squares that let a ray skip open space, plus other robots
//! as discs.
//!
//! A cell blocks a ray when it is not free: occupied and unknown cells stop rays (as in nav2), and
//! so does everything off the map. The range is the distance to the boundary of the first blocking
//! cell the ray enters, or the maximum range.

use crate::world::{Cell, OccupancyMap, Pose2, wrap_angle};
use bevy::prelude::Component;
use std::f32::consts::TAU;

/// Smallest free square (side, cells) over which the caster jumps instead of stepping cell by
/// cell. On the depot map, 2 vs 3 costs 4 % more instructions but 40 % fewer mispredicted
/// branches per ray (cachegrind on the `raycast/depot/fan_228` workload); wall time was within
/// noise, so the choice with the steadier pipeline wins.
const JUMP_MIN_SQUARE: u8 = 2;

/// The map prepared for ray casting; built once per map with [`RayGrid::from_map`] and stored on
/// the map entity. Derived data with an invariant (the free squares), hence private fields.
#[derive(Component, Clone, Debug)]
pub struct RayGrid {
    width: usize,
    height: usize,
    /// Row length of the padded grid: `width + 2` (a blocking border all round).
    stride: usize,
    resolution_m: f32,
    inv_resolution: f32,
    origin: Pose2,
    origin_sin: f32,
    origin_cos: f32,
    /// Per padded cell and quadrant q = (x step < 0) + 2·(y step < 0): the side (cells, capped at
    /// 255) of the largest all-free square that has this cell as its corner and extends into that
    /// quadrant. 0 = the cell blocks.
    squares: Vec<[u8; 4]>,
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

impl Default for Axis {
    fn default() -> Self {
        Self { step: 1, o_b: 0.0, inv: 0.0 }
    }
}

impl RayGrid {
    /// Prepares `map` for casting: marks blocking cells and computes the free squares
    /// (the largest-square dynamic programme, once per quadrant).
    pub fn from_map(map: &OccupancyMap) -> RayGrid {
        let (width, height) = (map.width, map.height);
        let (stride, rows) = (width + 2, height + 2);
        let free: Vec<bool> = (0..stride * rows)
            .map(|k| {
                let (pi, pj) = (k % stride, k / stride);
                let on_map = pi >= 1 && pj >= 1 && pi <= width && pj <= height;
                // A short `cells` vector reads as blocking rather than panicking.
                on_map && map.cells.get((pj - 1) * width + pi - 1) == Some(&Cell::Free)
            })
            .collect();
        let mut squares = vec![[0u8; 4]; stride * rows];
        for (q, (sx, sy)) in [(1isize, 1isize), (-1, 1), (1, -1), (-1, -1)].into_iter().enumerate() {
            // Visit cells so that the neighbours at +sx, +sy are done first; the border stays 0.
            let cols: Vec<usize> = if sx > 0 { (1..=width).rev().collect() } else { (1..=width).collect() };
            let lines: Vec<usize> =
                if sy > 0 { (1..=height).rev().collect() } else { (1..=height).collect() };
            for &pj in &lines {
                for &pi in &cols {
                    let k = pj * stride + pi;
                    if free[k] {
                        let kx = k.wrapping_add_signed(sx);
                        let ky = k.wrapping_add_signed(sy * stride as isize);
                        let kxy = ky.wrapping_add_signed(sx);
                        let m = squares[kx][q].min(squares[ky][q]).min(squares[kxy][q]);
                        squares[k][q] = m.saturating_add(1);
                    }
                }
            }
        }
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
            squares,
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
        !on_map || self.squares[self.padded_index(i as i32, j as i32)][0] == 0
    }

    /// Range from the world point (x, y) along the world-frame heading `angle`, metres: the
    /// distance to the first blocking cell boundary, or `max_range_m` if there is none closer.
    /// A ray starting in a blocking cell or off the map reads 0.
    pub fn cast(&self, x: f32, y: f32, angle: f32, max_range_m: f32) -> f32 {
        let (ox, oy) = self.to_grid(x, y);
        let (dy, dx) = (angle - self.origin.yaw).sin_cos();
        if !self.starts_clear(ox, oy) || max_range_m.is_nan() || max_range_m <= 0.0 {
            return 0.0;
        }
        self.march(Ray::new(ox, oy, dx, dy, max_range_m * self.inv_resolution), max_range_m)
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
        if !self.starts_clear(ox, oy) || max_range_m.is_nan() || max_range_m <= 0.0 {
            out.fill(0.0);
            return;
        }
        let t_max = max_range_m * self.inv_resolution;
        // Ray directions by complex rotation in f64: one sin_cos per fan instead of one per ray,
        // error ~1e-15 rad after 228 rays (bench `raycast/*/fan_228`).
        let base = f64::from(origin.yaw - self.origin.yaw) + f64::from(angle_min);
        let (mut s, mut c) = base.sin_cos();
        let (ds, dc) = f64::from(angle_increment).sin_cos();
        for range in out.iter_mut() {
            *range = self.march(Ray::new(ox, oy, c as f32, s as f32, t_max), max_range_m);
            (s, c) = (s * dc + c * ds, c * dc - s * ds);
        }
        if !discs.is_empty() {
            self.apply_discs(origin, angle_min, angle_increment, discs, out);
        }
    }

    /// Shortens the fan's ranges to the nearest disc hits. Each disc is tested only against the
    /// rays inside its angular extent, not every ray against every disc (bench
    /// `raycast/*/batch_64x228_rayon_discs`, 63 discs per fan).
    fn apply_discs(
        &self,
        origin: Pose2,
        angle_min: f32,
        angle_increment: f32,
        discs: &[(f32, f32, f32)],
        out: &mut [f32],
    ) {
        let n = out.len();
        let mut hit = |k: usize, cx: f32, cy: f32, radius: f32| {
            let (dy, dx) = (origin.yaw + angle_min + k as f32 * angle_increment).sin_cos();
            if let Some(t) = ray_disc(origin.x, origin.y, dx, dy, cx, cy, radius) {
                out[k] = out[k].min(t);
            }
        };
        for &(cx, cy, radius) in discs {
            let (px, py) = (cx - origin.x, cy - origin.y);
            let d = px.hypot(py);
            if d.is_nan() || d <= radius {
                continue; // contains the origin: ignored (a robot does not see itself)
            }
            if angle_increment <= 0.0 {
                (0..n).for_each(|k| hit(k, cx, cy, radius)); // an odd fan: test every ray
                continue;
            }
            // Bearing of the disc from the first ray, and its angular half-width (+ a margin
            // for rounding; the exact test below decides).
            let bearing = wrap_angle(py.atan2(px) - origin.yaw - angle_min);
            let half = (radius / d).asin() + 1e-4;
            for turn in [-TAU, 0.0, TAU] {
                let lo = ((bearing + turn - half) / angle_increment).ceil().max(0.0);
                let hi = ((bearing + turn + half) / angle_increment).floor().min(n as f32 - 1.0);
                if lo <= hi {
                    (lo as usize..=hi as usize).for_each(|k| hit(k, cx, cy, radius));
                }
            }
        }
    }

    /// Marches `ray` to its end; metres, misses read exactly `max_range_m`.
    fn march(&self, mut ray: Ray, max_range_m: f32) -> f32 {
        loop {
            if let Some(t) = ray.advance(&self.squares, self.stride) {
                return if t >= ray.t_max { max_range_m } else { (t * self.resolution_m).min(max_range_m) };
            }
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

    /// Whether a ray from grid point (ox, oy) starts on the map in a free cell.
    fn starts_clear(&self, ox: f32, oy: f32) -> bool {
        // `contains` is false for NaN too.
        (0.0..self.width as f32).contains(&ox)
            && (0.0..self.height as f32).contains(&oy)
            && self.squares[self.padded_index(ox as i32, oy as i32)][0] > 0
    }
}

/// One ray being marched: the accelerated DDA. Where the free square at the current cell, in the
/// ray's quadrant, has side ≥ [`JUMP_MIN_SQUARE`], the ray jumps to the cell through which it
/// leaves that square (nothing inside can block it); elsewhere it steps cell by cell exactly like
/// [`cast_reference`]. Coordinates in cells; the origin must lie in a free cell of the map.
#[derive(Clone, Copy, Debug, Default)]
struct Ray {
    ox: f32,
    oy: f32,
    dx: f32,
    dy: f32,
    t_max: f32,
    ax: Axis,
    ay: Axis,
    /// Which of the four free squares this ray uses.
    quadrant: usize,
    i: i32,
    j: i32,
    tx: f32,
    ty: f32,
    /// Entry parameter of the current cell (or a point inside it after a jump), cells.
    t: f32,
}

impl Ray {
    fn new(ox: f32, oy: f32, dx: f32, dy: f32, t_max: f32) -> Self {
        let (ax, ay) = (Axis::new(ox, dx), Axis::new(oy, dy));
        let quadrant = usize::from(ax.step < 0) + 2 * usize::from(ay.step < 0);
        // Non-negative on the map, so truncation is floor (no libm call on baseline x86-64).
        let (i, j) = (ox as i32, oy as i32);
        let (tx, ty) = (ax.exit(i), ay.exit(j));
        Self { ox, oy, dx, dy, t_max, ax, ay, quadrant, i, j, tx, ty, t: 0.0 }
    }

    /// One jump or one cell step. `Some(t)` (cells) once the ray is done: the entry parameter of
    /// the blocking cell, or `t_max` when nothing blocks within range.
    #[inline(always)]
    fn advance(&mut self, squares: &[[u8; 4]], stride: usize) -> Option<f32> {
        let side = squares[(self.j + 1) as usize * stride + (self.i + 1) as usize][self.quadrant];
        if side == 0 {
            return Some(self.t);
        }
        if side >= JUMP_MIN_SQUARE {
            // Far column and row of the square; the ray leaves it through whichever it exits
            // first, from the cell on that edge it is in at that moment (the same cell the plain
            // DDA would be in), so the march resumes exactly.
            let reach = i32::from(side) - 1;
            let (fi, fj) = (self.i + reach * self.ax.step, self.j + reach * self.ay.step);
            let (ex, ey) = (self.ax.exit(fi), self.ay.exit(fj));
            let via_x = ex < ey;
            let te = if via_x { ex } else { ey };
            let li = ((self.ox + te * self.dx) as i32).clamp(self.i.min(fi), self.i.max(fi));
            let lj = ((self.oy + te * self.dy) as i32).clamp(self.j.min(fj), self.j.max(fj));
            (self.i, self.j) = if via_x { (fi, lj) } else { (li, fj) };
            self.t = later(self.t, te);
            (self.tx, self.ty) = (self.ax.exit(self.i), self.ay.exit(self.j));
        } else {
            // One cell step, written as selects: the axis is unpredictable, and a mispredicted
            // branch here cost more than recomputing both boundary times (bench
            // `raycast/*/fan_228`). `max`: t never goes back (it cannot in exact arithmetic).
            let step_x = self.tx < self.ty;
            self.t = later(self.t, if step_x { self.tx } else { self.ty });
            self.i += if step_x { self.ax.step } else { 0 };
            self.j += if step_x { 0 } else { self.ay.step };
            (self.tx, self.ty) = (self.ax.exit(self.i), self.ay.exit(self.j));
        }
        (self.t >= self.t_max).then_some(self.t_max)
    }
}

/// `max` without NaN handling (plain `maxss`; f32::max costs four more instructions per step in
/// the march, bench `raycast/*/fan_228`). The march never produces NaN from a free origin.
#[inline(always)]
fn later(a: f32, b: f32) -> f32 {
    if b > a { b } else { a }
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
    fn raycast_disc_culling_equals_brute_force() {
        let map = tiny_room();
        let grid = RayGrid::from_map(&map);
        let mut rng = Pcg64Mcg::seed_from_u64(3);
        for _ in 0..50 {
            let pose =
                Pose2::new(rng.random_range(0.2..1.0), rng.random_range(0.2..0.7), rng.random_range(-PI..PI));
            let discs: Vec<(f32, f32, f32)> = (0..6)
                .map(|_| {
                    (rng.random_range(0.0..2.0), rng.random_range(0.0..1.5), rng.random_range(0.05..0.3))
                })
                .collect();
            let (amin, inc) = (-2.0944, 4.1888 / 227.0);
            let mut fan = vec![0.0; 228];
            grid.cast_fan(pose, amin, inc, 5.6, &discs, &mut fan);
            let mut plain = vec![0.0; 228];
            grid.cast_fan(pose, amin, inc, 5.6, &[], &mut plain);
            for (k, (&r, &g)) in fan.iter().zip(&plain).enumerate() {
                let (dy, dx) = (pose.yaw + amin + k as f32 * inc).sin_cos();
                let brute = discs
                    .iter()
                    .filter_map(|&(cx, cy, cr)| ray_disc(pose.x, pose.y, dx, dy, cx, cy, cr))
                    .fold(g, f32::min);
                assert!((r - brute).abs() < 1e-5, "ray {k} from {pose:?}: culled {r}, brute force {brute}");
            }
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
