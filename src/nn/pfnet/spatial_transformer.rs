//! PF-net's spatial transformer: for every particle, the local map it would see, cropped from the
//! filter's coarse global map (Karkus et al. 2018: 28 × 28 cells of 0.1 m = 2.8 m).
//!
//! Conventions (plain numbers in, so the engine needs no world types):
//! - Map: the fields of `NetworkMap`: fractional occupancy in [0, 1], `occupancy[j * width + i]`,
//!   row 0 at the bottom; the origin pose is the world pose of cell (0, 0)'s corner. Grid
//!   coordinates are a world point expressed in the origin's frame, divided by the resolution:
//!   cell (i, j) spans [i, i+1) × [j, j+1) and its centre is (i + 0.5, j + 0.5).
//! - Poses: world metres, x right, y up, yaw counter-clockwise from +x (as `Pose2`).
//! - Image: the layout of the observation grid (`LocalGrid`): row 0 farthest ahead, column 0 the
//!   particle's left (+y of its frame). The particle stands at the bottom centre facing up, so it
//!   sees what lies ahead (or, with `centred`, at the centre, as the robot in the grid): pixel
//!   (r, c)'s centre is, in the particle's frame, forward = (a − r − 0.5)·cell_m,
//!   left = (cells/2 − c − 0.5)·cell_m, with a = cells (cells/2 when centred; cells/2
//!   real-valued, so an odd side stays centred).
//! - Values: the network's encoding 1 − occupancy (1 = free, 0 = occupied).
//! - Sampling: bilinear between cell centres, so a pixel centre landing on a cell centre reads that
//!   cell exactly, and one halfway between a free and an occupied cell reads 0.5.
//! - Off the map: a neighbour outside the map counts as occupancy 1 (input 0), the rule
//!   `NetworkMap` applies to unknown cells. A real SLAM map's unknown means "never observed"
//!   (outside walls, behind glass), not "free", and beyond the map edge we know even less; one rule
//!   for both keeps the network from learning that the map's edge is open space. As a consequence
//!   the last half cell before the edge blends towards occupied. The Keras/TF reference differs:
//!   its STN sampler clamps indices to the border cell, so off the map it repeats the map's edge
//!   (free wherever the edge is open).
//!
//! Forward only: the map and the poses are inputs here, nothing is learned through this step.
//!
//! Speed (3,000 particles × 784 pixels per filter step): grid coordinates are affine in (r, c),
//! so each pose needs its trig once and two step vectors; a pixel is then a few multiply-adds,
//! a floor and four reads, with a fast path (no per-neighbour bounds tests) when all four
//! neighbours lie on the map, 16 pixels per AVX-512 gather where the CPU has it. No allocation.

use serde::{Deserialize, Serialize};

/// Occupancy of a neighbour off the map: what `NetworkMap` stores for unknown cells.
const OFF_MAP_OCCUPANCY: f32 = 1.0;

/// A read-only view of the filter's coarse occupancy map (the fields of `NetworkMap`).
#[derive(Clone, Copy, Debug)]
pub struct MapView<'a> {
    /// `occupancy[j * width + i]`, row 0 at the bottom, values in [0, 1].
    pub occupancy: &'a [f32],
    pub width: usize,
    pub height: usize,
    /// Side of one cell, metres.
    pub resolution_m: f32,
    /// World pose of cell (0, 0)'s outer corner.
    pub origin_x_m: f32,
    pub origin_y_m: f32,
    pub origin_yaw_rad: f32,
}

/// The local map each particle sees (paper: 28 × 28 cells of 0.1 m = 2.8 m).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct LocalMapSpec {
    /// Side of the square image, pixels.
    pub cells: usize,
    /// Side of one pixel, metres.
    pub cell_m: f32,
    /// Beyond the paper: the particle at the image's centre, as the robot sits in the LiDAR grid,
    /// instead of at its bottom centre (PF-net's layout, made for a camera that sees ahead). With
    /// the grid's window, a map feature and the scan feature beside it in the joint stage then
    /// show the same place; with the paper's 240° LiDAR it trains far worse (docs/pfnet.md, a
    /// local map laid out as the grid).
    #[serde(default)]
    pub centred: bool,
}

impl Default for LocalMapSpec {
    fn default() -> Self {
        Self { cells: 28, cell_m: 0.1, centred: false }
    }
}

impl LocalMapSpec {
    /// Pixels between the particle and the image's top edge (its far edge ahead).
    pub fn pixels_ahead(&self) -> f32 {
        if self.centred { self.cells as f32 / 2.0 } else { self.cells as f32 }
    }

    /// Checks a pixel side for `field`: 0.01–1 m.
    pub fn check_cell_m(field: &str, cell_m: f32) -> Result<(), String> {
        match (0.01..=1.0).contains(&cell_m) {
            true => Ok(()),
            false => Err(format!("{field}: expected 0.01 to 1 m, found {cell_m}")),
        }
    }
}

/// Where a pose's pixels sample the map, in *centre coordinates* (grid coordinates − 0.5, so cell
/// (i, j)'s centre sits at the integers (i, j) and bilinear weights are plain fractions).
struct SamplePlan {
    /// Sample point of pixel (0, 0).
    first: [f32; 2],
    /// Change of the sample point from one row to the next (one pixel backwards).
    row_step: [f32; 2],
    /// Change of the sample point from one column to the next (one pixel to the right).
    col_step: [f32; 2],
}

impl SamplePlan {
    fn new(map: &MapView, x: f32, y: f32, yaw: f32, spec: &LocalMapSpec) -> SamplePlan {
        // Particle position in grid coordinates: undo the origin pose, then scale.
        let (origin_sin, origin_cos) = map.origin_yaw_rad.sin_cos();
        let (dx, dy) = (x - map.origin_x_m, y - map.origin_y_m);
        let grid_x = (origin_cos * dx + origin_sin * dy) / map.resolution_m;
        let grid_y = (-origin_sin * dx + origin_cos * dy) / map.resolution_m;
        // One pixel forward and one pixel left, in grid cells.
        let (sin, cos) = (yaw - map.origin_yaw_rad).sin_cos();
        let pixel_in_cells = spec.cell_m / map.resolution_m;
        let forward = [cos * pixel_in_cells, sin * pixel_in_cells];
        let left = [-sin * pixel_in_cells, cos * pixel_in_cells];
        // Pixel (0, 0): the far left corner pixel.
        let forward_0 = spec.pixels_ahead() - 0.5;
        let left_0 = spec.cells as f32 / 2.0 - 0.5;
        SamplePlan {
            first: [
                grid_x + forward_0 * forward[0] + left_0 * left[0] - 0.5,
                grid_y + forward_0 * forward[1] + left_0 * left[1] - 0.5,
            ],
            row_step: [-forward[0], -forward[1]],
            col_step: [-left[0], -left[1]],
        }
    }
}

/// For each pose k (world x, y, yaw), writes a cells×cells image into out[k] (row-major, [k][row][col]):
/// the particle stands at the bottom centre of the image facing up (row 0 = farthest ahead, column 0 = the
/// particle's left, +y of its frame), values in the network's encoding 1 − occupancy (1 = free, 0 = occupied),
/// sampled bilinearly between cell centres. Off-map reads as occupancy 1 (input 0), like unknown cells.
/// Non-finite poses read as off the map.
///
/// # Panics
/// If `xs`, `ys` and `yaws` differ in length, `out.len() != xs.len() · cells²`,
/// `map.occupancy.len() != width · height`, or the map resolution is not a positive finite number.
pub fn crop_local_maps(
    map: &MapView,
    xs: &[f32],
    ys: &[f32],
    yaws: &[f32],
    spec: &LocalMapSpec,
    out: &mut [f32],
) {
    crop_local_map_stack(map, xs, ys, yaws, std::slice::from_ref(spec), out);
}

/// [`crop_local_maps`] at several pixel sizes: one image per spec and pose, `[k][spec][row][col]`
/// (a network's map channels: `PfNetConfig::local_maps`).
///
/// # Panics
/// As [`crop_local_maps`], with `out.len() != xs.len() · specs.len() · cells²`, or if the specs
/// differ in `cells`.
pub fn crop_local_map_stack(
    map: &MapView,
    xs: &[f32],
    ys: &[f32],
    yaws: &[f32],
    specs: &[LocalMapSpec],
    out: &mut [f32],
) {
    let cells = specs.first().map_or(0, |spec| spec.cells);
    assert!(specs.iter().all(|spec| spec.cells == cells), "every map channel has the same side");
    let pixels = cells * cells;
    assert!(xs.len() == ys.len() && xs.len() == yaws.len(), "one x, y and yaw per pose");
    assert_eq!(out.len(), xs.len() * specs.len() * pixels, "out holds poses × channels × cells² values");
    assert_eq!(map.occupancy.len(), map.width * map.height, "map occupancy is width × height");
    assert!(map.resolution_m.is_finite() && map.resolution_m > 0.0, "map resolution must be positive");
    if pixels == 0 {
        return;
    }
    let sample_row = row_sampler(map);
    for (k, image) in out.chunks_exact_mut(pixels).enumerate() {
        let (pose, spec) = (k / specs.len(), &specs[k % specs.len()]);
        let plan = SamplePlan::new(map, xs[pose], ys[pose], yaws[pose], spec);
        for (r, row) in image.chunks_exact_mut(cells).enumerate() {
            let start =
                [plan.first[0] + r as f32 * plan.row_step[0], plan.first[1] + r as f32 * plan.row_step[1]];
            sample_row(map, start, plan.col_step, row);
        }
    }
}

/// Writes pixel c of a row from centre coordinates start + c·step.
type RowSampler = fn(&MapView, [f32; 2], [f32; 2], &mut [f32]);

/// The row sampler for `map` on this CPU, chosen once per crop rather than once per row.
fn row_sampler(map: &MapView) -> RowSampler {
    #[cfg(target_arch = "x86_64")]
    if is_x86_feature_detected!("avx512f") && fits_gather_indices(map) {
        // SAFETY: chosen only where the CPU has AVX-512F.
        return |map, start, step, row| unsafe { sample_row_avx512(map, start, step, row) };
    }
    sample_row_scalar
}

fn sample_row_scalar(map: &MapView, start: [f32; 2], step: [f32; 2], row: &mut [f32]) {
    for (c, value) in row.iter_mut().enumerate() {
        let c = c as f32;
        *value = 1.0 - bilinear_occupancy(map, start[0] + c * step[0], start[1] + c * step[1]);
    }
}

/// Whether every cell index and the map's sides fit the gathers' 32-bit lanes.
fn fits_gather_indices(map: &MapView) -> bool {
    let limit = i32::MAX as usize;
    map.width < limit && map.height < limit && map.occupancy.len() < limit
}

/// [`sample_row`] 16 pixels at a time (measured: the crop was a quarter of the exact path's time,
/// scalar): four masked gathers, a neighbour off the map reading [`OFF_MAP_OCCUPANCY`] instead,
/// then the scalar path's operations in its order (no FMA), so the values are the same bits.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
fn sample_row_avx512(map: &MapView, start: [f32; 2], step: [f32; 2], row: &mut [f32]) {
    use std::arch::x86_64::*;
    let lane =
        _mm512_setr_ps(0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0, 9.0, 10.0, 11.0, 12.0, 13.0, 14.0, 15.0);
    let (start_u, start_v) = (_mm512_set1_ps(start[0]), _mm512_set1_ps(start[1]));
    let (step_u, step_v) = (_mm512_set1_ps(step[0]), _mm512_set1_ps(step[1]));
    // The scalar clamp; `max` returns its second operand for NaN, as `f32::max` returns -2.
    let low = _mm512_set1_ps(-2.0);
    let (high_u, high_v) = (_mm512_set1_ps(map.width as f32 + 1.0), _mm512_set1_ps(map.height as f32 + 1.0));
    let (width, height) = (_mm512_set1_epi32(map.width as i32), _mm512_set1_epi32(map.height as i32));
    let (zero, one_i, one) = (_mm512_setzero_si512(), _mm512_set1_epi32(1), _mm512_set1_ps(1.0));
    let off_map = _mm512_set1_ps(OFF_MAP_OCCUPANCY);
    let on_map =
        |k: __m512i, side: __m512i| _mm512_cmpge_epi32_mask(k, zero) & _mm512_cmplt_epi32_mask(k, side);
    let cells = map.occupancy.as_ptr();
    for (chunk, values) in row.chunks_mut(16).enumerate() {
        let active = ((1u32 << values.len()) - 1) as __mmask16;
        let c = _mm512_add_ps(lane, _mm512_set1_ps((chunk * 16) as f32));
        let u = _mm512_min_ps(_mm512_max_ps(_mm512_add_ps(start_u, _mm512_mul_ps(c, step_u)), low), high_u);
        let v = _mm512_min_ps(_mm512_max_ps(_mm512_add_ps(start_v, _mm512_mul_ps(c, step_v)), low), high_v);
        let (floor_u, floor_v) = (
            _mm512_roundscale_ps::<{ _MM_FROUND_TO_NEG_INF | _MM_FROUND_NO_EXC }>(u),
            _mm512_roundscale_ps::<{ _MM_FROUND_TO_NEG_INF | _MM_FROUND_NO_EXC }>(v),
        );
        let (i, j) = (_mm512_cvttps_epi32(floor_u), _mm512_cvttps_epi32(floor_v));
        let (i1, j1) = (_mm512_add_epi32(i, one_i), _mm512_add_epi32(j, one_i));
        let (left, right) = (active & on_map(i, width), active & on_map(i1, width));
        let (below, above) = (on_map(j, height), on_map(j1, height));
        let bottom = _mm512_add_epi32(_mm512_mullo_epi32(j, width), i);
        let top = _mm512_add_epi32(bottom, width);
        let gather = |mask: __mmask16, index: __m512i| {
            // SAFETY: a lane is read only where its neighbour lies on the map, so its index is
            // below `occupancy.len()`, which fits an i32 (`fits_gather_indices`).
            unsafe { _mm512_mask_i32gather_ps::<4>(off_map, mask, index, cells) }
        };
        let (bottom_left, bottom_right) =
            (gather(left & below, bottom), gather(right & below, _mm512_add_epi32(bottom, one_i)));
        let (top_left, top_right) =
            (gather(left & above, top), gather(right & above, _mm512_add_epi32(top, one_i)));
        let (fu, fv) = (_mm512_sub_ps(u, floor_u), _mm512_sub_ps(v, floor_v));
        let bottom = _mm512_add_ps(bottom_left, _mm512_mul_ps(fu, _mm512_sub_ps(bottom_right, bottom_left)));
        let top = _mm512_add_ps(top_left, _mm512_mul_ps(fu, _mm512_sub_ps(top_right, top_left)));
        let occupancy = _mm512_add_ps(bottom, _mm512_mul_ps(fv, _mm512_sub_ps(top, bottom)));
        // SAFETY: the store is masked to the chunk's `values.len()` lanes.
        unsafe { _mm512_mask_storeu_ps(values.as_mut_ptr(), active, _mm512_sub_ps(one, occupancy)) };
    }
}

/// Occupancy at centre coordinates (u, v), interpolated between the four surrounding cell
/// centres; neighbours off the map count as [`OFF_MAP_OCCUPANCY`].
#[inline(always)]
fn bilinear_occupancy(map: &MapView, u: f32, v: f32) -> f32 {
    let (width, height) = (map.width, map.height);
    // Beyond one cell outside, every neighbour is off the map anyway: clamping there changes no
    // value but keeps the indices far from i32 overflow (and `max` turns NaN into off-map).
    let u = u.max(-2.0).min(width as f32 + 1.0);
    let v = v.max(-2.0).min(height as f32 + 1.0);
    let (i, j) = (floor_to_i32(u), floor_to_i32(v));
    let (fu, fv) = (u - i as f32, v - j as f32);
    let inside = i >= 0 && j >= 0 && (i as usize) + 1 < width && (j as usize) + 1 < height;
    let [bottom_left, bottom_right, top_left, top_right] = if inside {
        let bottom = j as usize * width + i as usize;
        let top = bottom + width;
        let (bottom_pair, top_pair) = (&map.occupancy[bottom..bottom + 2], &map.occupancy[top..top + 2]);
        [bottom_pair[0], bottom_pair[1], top_pair[0], top_pair[1]]
    } else {
        let cell = |i: i32, j: i32| {
            let on_map = i >= 0 && j >= 0 && (i as usize) < width && (j as usize) < height;
            if on_map { map.occupancy[j as usize * width + i as usize] } else { OFF_MAP_OCCUPANCY }
        };
        [cell(i, j), cell(i + 1, j), cell(i, j + 1), cell(i + 1, j + 1)]
    };
    let bottom = bottom_left + fu * (bottom_right - bottom_left);
    let top = top_left + fu * (top_right - top_left);
    bottom + fv * (top - bottom)
}

/// `x.floor() as i32` for |x| well inside i32's range, without a libm call on targets lacking a
/// rounding instruction (`as i32` truncates towards zero).
#[inline(always)]
fn floor_to_i32(x: f32) -> i32 {
    let truncated = x as i32;
    if truncated as f32 > x { truncated - 1 } else { truncated }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_pcg::Pcg64;
    use std::f32::consts::{FRAC_PI_2, PI};

    /// An owned map for tests; `view` lends it as the API's `MapView`.
    struct TestMap {
        occupancy: Vec<f32>,
        width: usize,
        height: usize,
        resolution_m: f32,
        origin: (f32, f32, f32),
    }

    impl TestMap {
        fn free(width: usize, height: usize) -> TestMap {
            TestMap {
                occupancy: vec![0.0; width * height],
                width,
                height,
                resolution_m: 0.1,
                origin: (0.0, 0.0, 0.0),
            }
        }

        fn set(&mut self, i: usize, j: usize, occupancy: f32) {
            self.occupancy[j * self.width + i] = occupancy;
        }

        fn at(&self, i: usize, j: usize) -> f32 {
            self.occupancy[j * self.width + i]
        }

        fn view(&self) -> MapView<'_> {
            MapView {
                occupancy: &self.occupancy,
                width: self.width,
                height: self.height,
                resolution_m: self.resolution_m,
                origin_x_m: self.origin.0,
                origin_y_m: self.origin.1,
                origin_yaw_rad: self.origin.2,
            }
        }
    }

    const CELLS: usize = 28;

    /// The default 28 × 28 crop at one pose.
    fn crop(map: &TestMap, x: f32, y: f32, yaw: f32) -> Vec<f32> {
        let mut out = vec![f32::NAN; CELLS * CELLS];
        crop_local_maps(&map.view(), &[x], &[y], &[yaw], &LocalMapSpec::default(), &mut out);
        out
    }

    /// Pixel (r, c) of a 28 × 28 image.
    fn px(image: &[f32], r: usize, c: usize) -> f32 {
        image[r * CELLS + c]
    }

    fn assert_close(got: f32, want: f32, what: &str) {
        assert!((got - want).abs() < 1e-5, "{what}: got {got}, want {want}");
    }

    /// 40 × 40 free cells of 0.1 m with a wall along column i = 30, a spot at (20, 30) and a
    /// quarter-occupied cell at (25, 20).
    fn wall_map() -> TestMap {
        let mut map = TestMap::free(40, 40);
        for j in 0..40 {
            map.set(30, j, 1.0);
        }
        map.set(20, 30, 1.0);
        map.set(25, 20, 0.25);
        map
    }

    #[test]
    fn known_crop_facing_plus_x() {
        let map = wall_map();
        // From (1.0, 2.0) facing +x, pixel (r, c) samples cell centre (37 − r, 33 − c) exactly.
        let image = crop(&map, 1.0, 2.0, 0.0);
        for r in 0..CELLS {
            for c in 0..CELLS {
                assert_close(px(&image, r, c), 1.0 - map.at(37 - r, 33 - c), &format!("pixel ({r}, {c})"));
            }
        }
        assert!((0..CELLS).all(|c| px(&image, 7, c) < 1e-5), "the wall 0.7 m ahead lies across row 7");
        assert_close(px(&image, 17, 3), 0.0, "the spot is ahead and to the left: column 3");
        assert_close(px(&image, 12, 13), 0.75, "fractional occupancy 0.25 reads 0.75");
        assert_close(px(&image, 27, 14), 1.0, "free just ahead of the particle");
    }

    #[test]
    fn a_quarter_turn_turns_the_image() {
        let map = wall_map();
        // From (2.0, 1.0) facing +y the wall (x = 3.05) is on the right: pixel (r, c) samples cell
        // centre (6 + c, 37 − r), so the wall is column 24 in every row.
        let image = crop(&map, 2.0, 1.0, FRAC_PI_2);
        for r in 0..CELLS {
            for c in 0..CELLS {
                assert_close(px(&image, r, c), 1.0 - map.at(6 + c, 37 - r), &format!("pixel ({r}, {c})"));
            }
        }
        assert!((0..CELLS).all(|r| px(&image, r, 24) < 1e-5), "wall along column 24");
        assert_close(px(&image, 7, 14), 0.0, "the spot");

        // Same scene rotated a quarter turn counter-clockwise: a random map A and its rotated copy
        // B (cell (i, j) of A is cell (H − 1 − j, i) of B) give the same crop at the rotated pose,
        // away from cell alignment so interpolation is exercised too.
        let mut rng = Pcg64::seed_from_u64(7);
        let (w, h) = (23, 31);
        let mut a = TestMap::free(w, h);
        a.occupancy.iter_mut().for_each(|o| *o = rng.random::<f32>());
        let mut b = TestMap::free(h, w);
        for j in 0..h {
            for i in 0..w {
                b.set(h - 1 - j, i, a.at(i, j));
            }
        }
        let (x, y, yaw) = (1.234, 1.567, 0.3);
        let in_a = crop(&a, x, y, yaw);
        let in_b = crop(&b, h as f32 * 0.1 - y, x, yaw + FRAC_PI_2);
        for k in 0..CELLS * CELLS {
            assert!((in_a[k] - in_b[k]).abs() < 1e-4, "pixel {k}: {} vs {}", in_a[k], in_b[k]);
        }
    }

    #[test]
    fn beyond_the_map_edge_reads_occupied() {
        let mut map = TestMap::free(40, 40);
        map.set(2, 10, 1.0);
        // From (0.5, 2.0) facing −x, pixel (r, c) samples cell centre (r − 23, 6 + c): rows 0..=22
        // lie beyond the left edge.
        let image = crop(&map, 0.5, 2.0, PI);
        for r in 0..CELLS {
            for c in 0..CELLS {
                let want = if r <= 22 { 0.0 } else { 1.0 - map.at(r - 23, 6 + c) };
                assert_close(px(&image, r, c), want, &format!("pixel ({r}, {c})"));
            }
        }
        assert_close(px(&image, 25, 4), 0.0, "the occupied cell inside the map");
        assert!(crop(&map, -5.0, -5.0, 0.7).iter().all(|&v| v == 0.0), "far off the map: all occupied");
        assert!(crop(&map, f32::NAN, 1.0, 0.0).iter().all(|&v| v == 0.0), "a NaN pose reads off-map");
    }

    #[test]
    fn halfway_between_free_and_occupied_reads_half() {
        let mut map = TestMap::free(40, 40);
        for j in 0..40 {
            for i in 11..40 {
                map.set(i, j, 1.0);
            }
        }
        // From (0.45, 2.0) facing +x, row r samples centre coordinate 31.5 − r along x.
        let image = crop(&map, 0.45, 2.0, 0.0);
        assert_close(px(&image, 21, 5), 0.5, "halfway between free cell 10 and occupied cell 11");
        assert_close(px(&image, 20, 5), 0.0, "between occupied cells 11 and 12");
        assert_close(px(&image, 22, 5), 1.0, "between free cells 9 and 10");
        // Facing −x, row 23 samples halfway between cell 0 (free) and the off-map cell −1.
        let image = crop(&map, 0.45, 2.0, PI);
        assert_close(px(&image, 23, 5), 0.5, "halfway between the edge cell and off-map");

        // Both axes: one occupied cell seen from a corner between four cell centres.
        let mut spot = TestMap::free(40, 40);
        spot.set(20, 20, 1.0);
        let image = crop(&spot, 0.45, 1.95, 0.0); // centre coordinates (31.5 − r, 32.5 − c)
        for r in 0..CELLS {
            for c in 0..CELLS {
                let want = if (11..=12).contains(&r) && (12..=13).contains(&c) { 0.75 } else { 1.0 };
                assert_close(px(&image, r, c), want, &format!("pixel ({r}, {c})"));
            }
        }
    }

    #[test]
    fn a_centred_particle_sees_half_the_window_behind_it() {
        // Centred at a pose, the image is the bottom-centred one of the pose half a window back.
        let map = wall_map();
        let centred = LocalMapSpec { centred: true, ..LocalMapSpec::default() };
        let (x, y, yaw) = (1.7f32, 2.1f32, 0.4f32);
        let mut got = vec![f32::NAN; CELLS * CELLS];
        crop_local_maps(&map.view(), &[x], &[y], &[yaw], &centred, &mut got);
        let back = CELLS as f32 / 2.0 * centred.cell_m;
        let want = crop(&map, x - back * yaw.cos(), y - back * yaw.sin(), yaw);
        for k in 0..CELLS * CELLS {
            assert!((got[k] - want[k]).abs() < 1e-4, "pixel {k}: got {}, want {}", got[k], want[k]);
        }
        assert_ne!(got, crop(&map, x, y, yaw), "the bottom-centred image is another window");
    }

    #[test]
    fn map_origin_offset_and_yaw_are_honoured() {
        let plain = wall_map();
        let mut moved = wall_map();
        // Grid +x points along world +y and grid +y along world −x; the pose moves with the map,
        // so the particle sees the scene of `known_crop_facing_plus_x`.
        moved.origin = (1.0, -2.0, FRAC_PI_2);
        let want = crop(&plain, 1.0, 2.0, 0.0);
        let got = crop(&moved, -1.0, -1.0, FRAC_PI_2);
        for k in 0..CELLS * CELLS {
            assert_close(got[k], want[k], &format!("pixel {k}"));
        }
        assert!((0..CELLS).all(|c| px(&got, 7, c) < 1e-5), "the wall stays on row 7");
    }

    /// Direct per-pixel evaluation of the documented geometry in f64, trig at every pixel.
    fn reference_crop(map: &TestMap, pose: (f32, f32, f32), spec: &LocalMapSpec) -> Vec<f32> {
        let (x, y, yaw) = (pose.0 as f64, pose.1 as f64, pose.2 as f64);
        let (ox, oy, oyaw) = (map.origin.0 as f64, map.origin.1 as f64, map.origin.2 as f64);
        let (cells, cell_m, res) = (spec.cells as f64, spec.cell_m as f64, map.resolution_m as f64);
        let cell = |i: i64, j: i64| {
            let on = i >= 0 && j >= 0 && i < map.width as i64 && j < map.height as i64;
            if on { map.at(i as usize, j as usize) as f64 } else { 1.0 }
        };
        let mut out = Vec::new();
        for r in 0..spec.cells {
            for c in 0..spec.cells {
                let forward = (f64::from(spec.pixels_ahead()) - r as f64 - 0.5) * cell_m;
                let left = (cells / 2.0 - c as f64 - 0.5) * cell_m;
                let wx = x + yaw.cos() * forward - yaw.sin() * left;
                let wy = y + yaw.sin() * forward + yaw.cos() * left;
                let (dx, dy) = (wx - ox, wy - oy);
                let gx = (oyaw.cos() * dx + oyaw.sin() * dy) / res;
                let gy = (-oyaw.sin() * dx + oyaw.cos() * dy) / res;
                let (u, v) = (gx - 0.5, gy - 0.5);
                let (i, j) = (u.floor() as i64, v.floor() as i64);
                let (fu, fv) = (u - i as f64, v - j as f64);
                let occupancy = (1.0 - fu) * (1.0 - fv) * cell(i, j)
                    + fu * (1.0 - fv) * cell(i + 1, j)
                    + (1.0 - fu) * fv * cell(i, j + 1)
                    + fu * fv * cell(i + 1, j + 1);
                out.push((1.0 - occupancy) as f32);
            }
        }
        out
    }

    #[test]
    fn matches_a_per_pixel_reference_for_a_batch_of_poses() {
        let mut rng = Pcg64::seed_from_u64(42);
        let mut map = TestMap::free(17, 13);
        map.occupancy.iter_mut().for_each(|o| *o = rng.random::<f32>());
        map.resolution_m = 0.1;
        map.origin = (0.3, -0.7, 2.5);
        // Odd side, pixels coarser than cells, poses inside, across the edge and far off; the
        // particle at the bottom centre and at the centre.
        for centred in [false, true] {
            let spec = LocalMapSpec { cells: 5, cell_m: 0.17, centred };
            check_against_reference(&map, &spec, &mut rng);
        }
    }

    fn check_against_reference(map: &TestMap, spec: &LocalMapSpec, rng: &mut Pcg64) {
        let poses: Vec<(f32, f32, f32)> = (0..12)
            .map(|_| (rng.random_range(-2.5..1.5), rng.random_range(-1.0..2.5), rng.random_range(-PI..PI)))
            .collect();
        let xs: Vec<f32> = poses.iter().map(|p| p.0).collect();
        let ys: Vec<f32> = poses.iter().map(|p| p.1).collect();
        let yaws: Vec<f32> = poses.iter().map(|p| p.2).collect();
        let pixels = spec.cells * spec.cells;
        let mut out = vec![f32::NAN; poses.len() * pixels];
        crop_local_maps(&map.view(), &xs, &ys, &yaws, spec, &mut out);
        for (k, &pose) in poses.iter().enumerate() {
            let want = reference_crop(map, pose, spec);
            for (p, (&got, &want)) in out[k * pixels..(k + 1) * pixels].iter().zip(&want).enumerate() {
                assert!((got - want).abs() < 2e-4, "{spec:?} pose {k} pixel {p}: got {got}, want {want}");
            }
        }
    }

    #[test]
    fn rows_read_the_same_bits_on_every_path() {
        // On an AVX-512 machine `row_sampler`'s choice gathers 16 pixels at once; it must give the scalar
        // path's bits for rows inside the map, across its edge, far off it and at NaN.
        let mut rng = Pcg64::seed_from_u64(11);
        let mut map = TestMap::free(40, 30);
        map.occupancy.iter_mut().for_each(|o| *o = rng.random::<f32>());
        for trial in 0..400 {
            let len = rng.random_range(1..45);
            let start = match trial % 40 {
                0 => [f32::NAN, 3.0],
                _ => [rng.random_range(-5.0..45.0), rng.random_range(-5.0..35.0)],
            };
            let step = [rng.random_range(-1.5..1.5), rng.random_range(-1.5..1.5)];
            let (mut fast, mut scalar) = (vec![0.0; len], vec![0.0; len]);
            row_sampler(&map.view())(&map.view(), start, step, &mut fast);
            sample_row_scalar(&map.view(), start, step, &mut scalar);
            for (c, (f, s)) in fast.iter().zip(&scalar).enumerate() {
                assert_eq!(f.to_bits(), s.to_bits(), "trial {trial} pixel {c}: {f} against {s}");
            }
        }
    }

    #[test]
    fn a_stack_holds_each_poses_crops_in_spec_order() {
        let mut rng = Pcg64::seed_from_u64(7);
        let mut map = TestMap::free(30, 20);
        map.occupancy.iter_mut().for_each(|o| *o = rng.random::<f32>());
        let specs = [
            LocalMapSpec { cells: 4, ..LocalMapSpec::default() },
            LocalMapSpec { cells: 4, cell_m: 0.25, centred: false },
        ];
        let (xs, ys, yaws) = ([0.6, 1.9], [0.4, 1.2], [0.3, -2.0]);
        let mut stack = vec![f32::NAN; 2 * 2 * 16];
        crop_local_map_stack(&map.view(), &xs, &ys, &yaws, &specs, &mut stack);
        for pose in 0..2 {
            for (c, spec) in specs.iter().enumerate() {
                let mut one = vec![f32::NAN; 16];
                let at = pose..=pose;
                crop_local_maps(&map.view(), &xs[at.clone()], &ys[at.clone()], &yaws[at], spec, &mut one);
                let image = pose * specs.len() + c;
                assert_eq!(stack[image * 16..(image + 1) * 16], one[..], "pose {pose}, channel {c}");
            }
        }
        assert_ne!(stack[..16], stack[16..32], "the wider pixels see another window");
    }
}
