//! Layers derived from the fine occupancy grid: the filter's coarse network map, the traversable
//! map (free space eroded by the robot radius) and the Euclidean distance field.

use crate::world::map::edt::squared_edt;
use crate::world::map::error::MapError;
use crate::world::map::occupancy::{Cell, OccupancyMap};
use crate::world::pose::{Pose2, wrap_angle};
use bevy::prelude::Component;
use rand::Rng;
use std::f32::consts::PI;

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

/// Start poses are redrawn up to this many times to keep robots that collide apart.
pub const START_POSE_TRIES: usize = 100;

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

/// Distance from each fine cell's centre to the nearest cell a LiDAR ray can end at (see
/// [`DistanceField::build`]), metres.
#[derive(Component, Clone, Debug, PartialEq)]
pub struct DistanceField {
    pub width: usize,
    pub height: usize,
    pub resolution_m: f32,
    pub distances_m: Vec<f32>,
}

/// Unknown cells count as occupied (1) in the network map: the filter's map encoder sees
/// `1 − occupancy`, and reading unknown as free would tell it that open space lies where a real
/// map only says "never observed" (outside walls, behind glass), the same reason nav2's rays stop
/// at unknown cells.
const UNKNOWN_OCCUPANCY: f32 = 1.0;

impl NetworkMap {
    /// Block mean of `map` at `resolution_m` per cell (DESIGN: 0.1 m): occupied = 1, unknown = 1,
    /// free = 0. The cell ratio need not be an integer: each fine cell contributes in proportion
    /// to its overlap with the coarse cell. The last row/column of blocks may reach past the fine
    /// map; they average only the fine cells they cover. Origin (and yaw) = the fine map's.
    ///
    /// # Panics
    /// If `resolution_m` is not a positive finite number.
    pub fn from_fine(map: &OccupancyMap, resolution_m: f32) -> NetworkMap {
        assert!(resolution_m.is_finite() && resolution_m > 0.0, "network resolution must be positive");
        let mut ratio = f64::from(resolution_m) / f64::from(map.resolution_m);
        if (ratio - ratio.round()).abs() < 1e-4 * ratio {
            ratio = ratio.round(); // 0.1 / 0.05 and friends: no slivers from float noise
        }
        let (wx, width) = block_weights(map.width, ratio);
        let (wy, height) = block_weights(map.height, ratio);

        // Collapse x first (per fine row), then y.
        let mut rows = vec![0.0f64; map.height * width];
        for j in 0..map.height {
            for &(ci, fi, w) in &wx {
                let occ = match map.cells[j * map.width + fi] {
                    Cell::Free => 0.0,
                    Cell::Occupied => 1.0,
                    Cell::Unknown => f64::from(UNKNOWN_OCCUPANCY),
                };
                rows[j * width + ci] += w * occ;
            }
        }
        let mut sum = vec![0.0f64; width * height];
        for &(cj, fj, w) in &wy {
            for ci in 0..width {
                sum[cj * width + ci] += w * rows[fj * width + ci];
            }
        }
        let (area_x, area_y) = (axis_area(&wx, width), axis_area(&wy, height));
        let occupancy =
            (0..width * height).map(|k| (sum[k] / (area_x[k % width] * area_y[k / width])) as f32).collect();
        NetworkMap { resolution_m, origin: map.origin, width, height, occupancy }
    }
}

impl NetworkMap {
    /// Occupancy of the cell containing a world point; points off the map read as occupied (1),
    /// as unknown cells do.
    pub fn occupancy_at(&self, x: f32, y: f32) -> f32 {
        let local = self.origin.between(&Pose2::new(x, y, 0.0));
        self.occupancy_at_grid(local.x / self.resolution_m, local.y / self.resolution_m)
    }

    /// Occupancy at continuous grid coordinates (cells from the origin corner; cell (i, j) spans
    /// [i, i+1) × [j, j+1)); off the map reads as occupied.
    pub fn occupancy_at_grid(&self, gx: f32, gy: f32) -> f32 {
        let on_map = gx >= 0.0 && gy >= 0.0 && gx < self.width as f32 && gy < self.height as f32;
        // `as i32` first: f32 → usize is a slow multi-instruction conversion on x86-64.
        let cell = || gy as i32 as usize * self.width + gx as i32 as usize;
        if on_map { self.occupancy[cell()] } else { UNKNOWN_OCCUPANCY }
    }
}

/// Overlaps of fine cells with coarse cells along one axis: (coarse index, fine index, length in
/// fine cells), and the number of coarse cells.
fn block_weights(fine_n: usize, ratio: f64) -> (Vec<(usize, usize, f64)>, usize) {
    let coarse_n = (fine_n as f64 / ratio - 1e-9).ceil().max(0.0) as usize;
    let mut out = Vec::with_capacity(fine_n + coarse_n);
    for c in 0..coarse_n {
        let (lo, hi) = (c as f64 * ratio, ((c + 1) as f64 * ratio).min(fine_n as f64));
        for f in (lo.floor() as usize)..(hi.ceil() as usize).min(fine_n) {
            let w = hi.min((f + 1) as f64) - lo.max(f as f64);
            if w > 1e-9 {
                out.push((c, f, w));
            }
        }
    }
    (out, coarse_n)
}

/// Total covered length per coarse cell.
fn axis_area(weights: &[(usize, usize, f64)], coarse_n: usize) -> Vec<f64> {
    let mut area = vec![0.0; coarse_n];
    for &(c, _, w) in weights {
        area[c] += w;
    }
    area
}

impl TraversableMap {
    /// Free cells whose centre is farther than `robot_radius_m` from every non-free cell's centre
    /// (exact Euclidean distance; cells beyond the map edge count as non-free), restricted to the
    /// largest 8-connected component (ties: the one found first in row-major order).
    pub fn build(map: &OccupancyMap, robot_radius_m: f32) -> Result<TraversableMap, MapError> {
        let (w, h) = (map.width, map.height);
        let d2 = squared_edt(w, h, |k| map.cells[k] != Cell::Free);
        let clear = |k: usize| {
            let (i, j) = (k % w, k / w);
            let edge = (i + 1).min(j + 1).min(w - i).min(h - j) as f32;
            map.cells[k] == Cell::Free && d2[k].sqrt().min(edge) * map.resolution_m > robot_radius_m
        };
        let candidate: Vec<bool> = (0..w * h).map(clear).collect();
        let traversable = largest_component(w, h, &candidate);
        let cells: Vec<(u32, u32)> =
            (0..w * h).filter(|&k| traversable[k]).map(|k| ((k % w) as u32, (k / w) as u32)).collect();
        if cells.is_empty() {
            return Err(MapError::NoTraversableSpace { robot_radius_m });
        }
        Ok(TraversableMap { width: w, height: h, traversable, cells })
    }

    /// Traversable area, m², for the fine grid's `resolution_m`.
    pub fn area_m2(&self, resolution_m: f32) -> f32 {
        self.cells.len() as f32 * resolution_m * resolution_m
    }

    /// Whether cell (i, j) is traversable; cells off the grid are not.
    pub fn is_traversable(&self, i: usize, j: usize) -> bool {
        i < self.width && j < self.height && self.traversable[j * self.width + i]
    }

    /// A pose drawn uniformly: a traversable cell, a point within it, a yaw in (−π, π].
    ///
    /// # Panics
    /// If there is no traversable cell (`build` never returns such a map).
    pub fn sample_pose(&self, map: &OccupancyMap, rng: &mut impl Rng) -> Pose2 {
        let (i, j) = self.cells[rng.random_range(0..self.cells.len())];
        let (gx, gy) = (i as f32 + rng.random::<f32>(), j as f32 + rng.random::<f32>());
        let (x, y) = map.grid_to_world(gx, gy);
        Pose2::new(x, y, wrap_angle(rng.random_range(-PI..PI)))
    }

    /// The first of up to `tries` [`sample_pose`](Self::sample_pose) draws that `accept`s, or one
    /// more draw when none does. Draws exactly once when the first is accepted, so an `accept`
    /// that always holds leaves the random stream as one `sample_pose` would.
    pub fn sample_pose_where(
        &self,
        map: &OccupancyMap,
        rng: &mut impl Rng,
        tries: usize,
        accept: impl Fn(&Pose2) -> bool,
    ) -> Pose2 {
        (0..tries)
            .map(|_| self.sample_pose(map, rng))
            .find(accept)
            .unwrap_or_else(|| self.sample_pose(map, rng))
    }
}

/// Marks the largest 8-connected component of `mask`.
fn largest_component(w: usize, h: usize, mask: &[bool]) -> Vec<bool> {
    let mut label = vec![0u32; w * h];
    let (mut best, mut best_size, mut next) = (0u32, 0usize, 0u32);
    let mut stack = Vec::new();
    for seed in 0..w * h {
        if !mask[seed] || label[seed] != 0 {
            continue;
        }
        next += 1;
        label[seed] = next;
        stack.push(seed);
        let mut size = 0;
        while let Some(k) = stack.pop() {
            size += 1;
            let (i, j) = (k % w, k / w);
            for nj in j.saturating_sub(1)..(j + 2).min(h) {
                for ni in i.saturating_sub(1)..(i + 2).min(w) {
                    let n = nj * w + ni;
                    if mask[n] && label[n] == 0 {
                        label[n] = next;
                        stack.push(n);
                    }
                }
            }
        }
        if size > best_size {
            (best, best_size) = (next, size);
        }
    }
    label.iter().map(|&l| l != 0 && l == best).collect()
}

impl DistanceField {
    /// Returned for points off the map and stored where the map has no occupied cell at all, m.
    /// Large but finite, so `exp(−d²/2σ²)` is 0 and products never turn into NaN; likelihood-field
    /// users clip with their own `max_occ_dist` (AMCL: 2 m).
    pub const FAR_M: f32 = 1.0e6;

    /// Exact Euclidean distance from each cell centre to the nearest centre of a cell where rays
    /// end, metres: every occupied cell, and every unknown cell next to (8-neighbourhood) a free
    /// one. Unknown cells stop rays (nav2's beam model and our LiDAR), so a beam that ends on the
    /// border of an unexplored area is a hit there; counting only occupied cells, as AMCL's
    /// likelihood field does, scores such beams as far from anything and pulls the filter towards
    /// poses that put them near some wall (on 0.1 m maps whose thin walls faded into unknown,
    /// 6 of 10 tracking runs ended above 10 cm, `docs/results/coarse_maps.md`). Unknown cells
    /// deep inside an unknown area are no ray's end, and stay at their distance from its border.
    pub fn build(map: &OccupancyMap) -> DistanceField {
        let (w, h) = (map.width, map.height);
        let borders_free = |k: usize| {
            let (i, j) = (k % w, k / w);
            let mut around = (j.saturating_sub(1)..(j + 2).min(h))
                .flat_map(|nj| (i.saturating_sub(1)..(i + 2).min(w)).map(move |ni| nj * w + ni));
            around.any(|n| map.cells[n] == Cell::Free)
        };
        let d2 = squared_edt(w, h, |k| match map.cells[k] {
            Cell::Occupied => true,
            Cell::Unknown => borders_free(k),
            Cell::Free => false,
        });
        let distances_m = d2
            .iter()
            .map(|&d| if d.is_finite() { d.sqrt() * map.resolution_m } else { Self::FAR_M })
            .collect();
        DistanceField { width: map.width, height: map.height, resolution_m: map.resolution_m, distances_m }
    }

    /// Distance stored for the cell containing world point (x, y); [`Self::FAR_M`] off the map.
    pub fn distance_at(&self, map: &OccupancyMap, x: f32, y: f32) -> f32 {
        map.cell_at(x, y).map_or(Self::FAR_M, |(i, j)| self.distances_m[j * self.width + i])
    }

    /// Distance from a point to the nearest surface where rays end, metres, at continuous grid
    /// coordinates (cells from the origin corner; callers keep the point on the grid): the
    /// centre distances interpolated bilinearly, less half a cell (a ray ends on the face of the
    /// cell it meets, half a cell before that cell's centre), never below 0. Reading the
    /// containing cell's value instead scores an endpoint on a wall's face as 0 or one whole
    /// cell away depending on rounding, which biased tracking on 0.1 m maps by ≈ 4 cm.
    /// Distances beyond `max_m` are clamped to it first, so that [`Self::FAR_M`] never blends in.
    #[inline]
    pub fn surface_distance(&self, gx: f32, gy: f32, max_m: f32) -> f32 {
        // Cell centres sit at +0.5: the four around the point are (i, j) … (i + 1, j + 1).
        let (fx, fy) = ((gx - 0.5).max(0.0), (gy - 0.5).max(0.0));
        let (i, j) = (fx as i32 as usize, fy as i32 as usize);
        let (tx, ty) = (fx - i as f32, fy - j as f32);
        let (i1, j1) = ((i + 1).min(self.width - 1), (j + 1).min(self.height - 1));
        let d = |i: usize, j: usize| self.distances_m[j * self.width + i].min(max_m);
        let (bottom, top) = (d(i, j) + (d(i1, j) - d(i, j)) * tx, d(i, j1) + (d(i1, j1) - d(i, j1)) * tx);
        (bottom + (top - bottom) * ty - 0.5 * self.resolution_m).max(0.0)
    }

    /// [`Self::surface_distance`] at a world point; `max_m` off the map.
    pub fn surface_distance_at(&self, map: &OccupancyMap, x: f32, y: f32, max_m: f32) -> f32 {
        let (gx, gy) = map.world_to_grid(x, y);
        let on_map = gx >= 0.0 && gy >= 0.0 && gx < self.width as f32 && gy < self.height as f32;
        if on_map { self.surface_distance(gx, gy, max_m) } else { max_m }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::world::rng::stream;

    #[test]
    fn network_map_reads_occupancy_at_world_points_under_a_rotated_origin() {
        let mut map = OccupancyMap::from_ascii(0.1, "..#\n...");
        map.origin = Pose2::new(1.0, 2.0, PI / 2.0);
        let net = NetworkMap::from_fine(&map, 0.1);
        // Cell (2, 1) (top right of the drawing) lies 0.25 m along the origin's x (world +y) and
        // 0.15 m along its y (world −x).
        assert_eq!(net.occupancy_at(1.0 - 0.15, 2.0 + 0.25), 1.0, "the occupied cell");
        assert_eq!(net.occupancy_at(1.0 - 0.05, 2.0 + 0.05), 0.0, "a free cell");
        assert_eq!(net.occupancy_at(1.0 + 0.05, 2.0 + 0.05), 1.0, "off the map reads occupied");
    }

    #[test]
    fn distance_field_matches_known_distances() {
        let map = OccupancyMap::from_ascii(
            0.1,
            "
            .....
            .....
            ....?
            .#...
            .....
            ",
        );
        let field = DistanceField::build(&map);
        let at = |i: usize, j: usize| field.distances_m[j * 5 + i];
        assert_eq!(at(1, 1), 0.0, "occupied cell is at distance 0");
        assert_eq!(at(4, 2), 0.0, "an unknown cell beside free space ends rays");
        assert!((at(4, 4) - 0.2).abs() < 1e-6, "two cells above that unknown cell: got {}", at(4, 4));
        assert!((at(0, 4) - 0.1 * 10f32.sqrt()).abs() < 1e-6, "(1, 3) cells from the wall: got {}", at(0, 4));
        let (x, y) = map.cell_center(2, 1);
        assert!((field.distance_at(&map, x, y) - 0.1).abs() < 1e-6);
        assert_eq!(field.distance_at(&map, -1.0, 0.2), DistanceField::FAR_M, "off-map is far");
        let empty = DistanceField::build(&OccupancyMap::filled(3, 2, 0.1, Cell::Free));
        assert!(empty.distances_m.iter().all(|&d| d == DistanceField::FAR_M), "no obstacle: all far");
    }

    #[test]
    fn distance_field_ignores_unknown_cells_no_ray_reaches() {
        let map = OccupancyMap::from_ascii(
            0.1,
            "
            ?????
            ?????
            .....
            ",
        );
        let field = DistanceField::build(&map);
        let at = |i: usize, j: usize| field.distances_m[j * 5 + i];
        assert_eq!(at(2, 1), 0.0, "the unknown border row ends rays");
        assert!((at(2, 2) - 0.1).abs() < 1e-6, "the row behind it is one cell from the border: {}", at(2, 2));
    }

    #[test]
    fn surface_distance_is_zero_on_a_face_and_grows_across_free_space() {
        let map = OccupancyMap::from_ascii(0.1, "#......\n#......");
        let field = DistanceField::build(&map);
        for (gx, expected) in [(0.5, 0.0), (1.0, 0.0), (1.5, 0.05), (2.25, 0.125), (4.0, 0.3)] {
            let d = field.surface_distance(gx, 1.0, 2.0);
            assert!((d - expected).abs() < 1e-6, "at gx {gx}: {d} vs {expected}");
        }
        let clamped = field.surface_distance(6.9, 0.1, 0.4);
        assert!((clamped - 0.35).abs() < 1e-6, "clamped before interpolating, less half a cell: {clamped}");
        assert_eq!(field.surface_distance_at(&map, -0.1, 0.1, 2.0), 2.0, "off the map: the maximum");
    }

    #[test]
    fn distance_field_equals_brute_force_on_random_map() {
        let mut rng = stream(&[42]);
        let (w, h) = (23, 17);
        let mut map = OccupancyMap::filled(w, h, 0.05, Cell::Free);
        for c in &mut map.cells {
            *c = match rng.random::<f32>() {
                u if u < 0.04 => Cell::Occupied,
                u if u < 0.3 => Cell::Unknown,
                _ => Cell::Free,
            };
        }
        for j in 8..13 {
            for i in 5..12 {
                map.set(i, j, Cell::Unknown); // an unknown area with an inside no ray reaches
            }
        }
        let field = DistanceField::build(&map);
        let ends_rays = |s: usize| {
            let (i, j) = (s % w, s / w);
            let free_beside = (0..w * h)
                .any(|n| map.cells[n] == Cell::Free && (n % w).abs_diff(i) <= 1 && (n / w).abs_diff(j) <= 1);
            map.cells[s] == Cell::Occupied || (map.cells[s] == Cell::Unknown && free_beside)
        };
        assert!(field.distances_m[10 * w + 8] > 0.0, "the unknown area's inside is no obstacle");
        for k in 0..w * h {
            let (i, j) = ((k % w) as f32, (k / w) as f32);
            let brute = (0..w * h)
                .filter(|&s| ends_rays(s))
                .map(|s| ((s % w) as f32 - i).hypot((s / w) as f32 - j))
                .fold(f32::INFINITY, f32::min)
                * 0.05;
            assert!(
                (field.distances_m[k] - brute).abs() < 1e-5,
                "cell {k}: {} vs {brute}",
                field.distances_m[k]
            );
        }
    }

    fn two_rooms() -> OccupancyMap {
        // Two 8×6 rooms joined by a corridor 3 cells (0.15 m) wide, at 0.05 m per cell.
        OccupancyMap::from_ascii(
            0.05,
            "
            ##########################
            #........#######.........#
            #........#######.........#
            #........................#
            #........................#
            #........................#
            #........#######.........#
            #........#######.........#
            #........#######.........#
            ##########################
            ",
        )
    }

    #[test]
    fn erosion_cuts_a_corridor_narrower_than_the_robot() {
        let map = two_rooms();
        let small = TraversableMap::build(&map, 0.05).expect("small robot fits");
        assert!(small.is_traversable(12, 5), "a 0.05 m robot drives down the corridor middle");
        assert!(small.is_traversable(3, 4) && small.is_traversable(20, 4), "both rooms stay connected");
        let wide = TraversableMap::build(&map, 0.12).expect("rooms still fit a 0.12 m robot");
        assert!(!wide.is_traversable(12, 5), "corridor of 0.15 m is closed for a 0.12 m radius");
        assert!(wide.is_traversable(20, 4), "the larger (right) room is kept");
        assert!(!wide.is_traversable(4, 4), "the smaller, now disconnected room is dropped");
        assert!(wide.cells.iter().all(|&(i, j)| wide.is_traversable(i as usize, j as usize)));
        assert!((wide.area_m2(0.05) - wide.cells.len() as f32 * 0.0025).abs() < 1e-6);
    }

    #[test]
    fn no_traversable_space_is_an_error() {
        let err = TraversableMap::build(&two_rooms(), 0.5).expect_err("nothing fits a 0.5 m robot");
        assert!(err.to_string().contains("traversable space"), "message names it: {err}");
    }

    #[test]
    fn sampled_poses_are_traversable() {
        let map = two_rooms();
        let trav = TraversableMap::build(&map, 0.05).expect("fits");
        let mut rng = stream(&[7, 1]);
        for _ in 0..500 {
            let p = trav.sample_pose(&map, &mut rng);
            let (i, j) = map.cell_at(p.x, p.y).expect("on the map");
            assert!(trav.is_traversable(i, j), "sample {p:?} lies in cell ({i}, {j})");
            assert!(p.yaw > -PI && p.yaw <= PI, "yaw wrapped: {}", p.yaw);
        }
    }

    #[test]
    fn network_map_is_the_block_mean() {
        let map = OccupancyMap::from_ascii(
            0.05,
            "
            #.?
            ..#
            ...
            ",
        );
        let net = NetworkMap::from_fine(&map, 0.1);
        assert_eq!((net.width, net.height), (2, 2), "3 fine cells → 2 blocks, the last partial");
        let at = |i: usize, j: usize| net.occupancy[j * 2 + i];
        assert_eq!(at(0, 0), 0.0, "bottom-left block is all free");
        assert_eq!(at(1, 0), 0.5, "bottom-right partial block: one occupied of two cells");
        assert_eq!(at(0, 1), 0.5, "top-left partial block: one occupied of two cells");
        assert_eq!(at(1, 1), 1.0, "top-right corner: the single unknown cell counts as 1");
        assert_eq!(net.origin, map.origin);

        let mut fine = OccupancyMap::filled(10, 4, 0.03, Cell::Free);
        fine.set(0, 0, Cell::Occupied);
        let net = NetworkMap::from_fine(&fine, 0.1);
        assert_eq!((net.width, net.height), (3, 2), "0.3 m × 0.12 m → 3 × 2 cells of 0.1 m");
        let expected = 1.0 / (0.1f32 / 0.03).powi(2); // one fine cell of a 3⅓ × 3⅓ block
        assert!((net.occupancy[0] - expected).abs() < 1e-4, "got {}, want {expected}", net.occupancy[0]);
        assert!(net.occupancy[1..].iter().all(|&o| o == 0.0), "other blocks are free: {:?}", net.occupancy);
    }
}
