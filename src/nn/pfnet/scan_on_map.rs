//! A particle's input to the map encoders: its local maps, and with `PfNetConfig::scan_on_map`
//! the scan laid on each of them (beyond the paper, `ScanOnMap`); or, when the laid scan has
//! encoders of its own, their input, once per observation (`lay_scans`).
//!
//! The LiDAR grid has the robot at its centre facing up, the local map the particle at its bottom
//! centre (or centre) facing up, both with column 0 on the left: the same frame, so laying the
//! grid on a local map's pixels is one fixed resampling per step, the same for every particle.
//! Where a particle stands on the truth, the walls the scan saw then fall on the map's walls pixel
//! for pixel.

use super::model::PfNet;
use super::spatial_transformer::{LocalMapSpec, MapView, crop_local_map_stack, crop_local_maps};

/// What the grid holds where the robot did not look (`LocalGrid`: 0 occupied, 0.5 unknown, 1 free).
const UNKNOWN: f32 = 0.5;

/// Writes the LiDAR grid `grid` (`g × g` cells over `extent_m`, the layout of `LocalGrid`) onto
/// the pixels of a local map of `spec` and `margin` more pixels on every side (`out`, (cells +
/// 2·margin)² values): each pixel reads the grid bilinearly between cell centres at the pixel's
/// centre; beyond the grid it reads unknown.
///
/// # Panics
/// If `grid` is not square or `out` is not that many values.
pub fn lay_scan(grid: &[f32], extent_m: f32, (spec, margin): (&LocalMapSpec, usize), out: &mut [f32]) {
    let g = grid.len().isqrt();
    let side = spec.cells + 2 * margin;
    assert_eq!(g * g, grid.len(), "a square grid");
    assert_eq!(out.len(), side * side, "out holds one local map and its margin");
    let grid_cell_m = extent_m / g as f32;
    let read = |row: isize, col: isize| match (usize::try_from(row), usize::try_from(col)) {
        (Ok(r), Ok(c)) if r < g && c < g => grid[r * g + c],
        _ => UNKNOWN,
    };
    // A point `forward`, `left` metres from the robot, in grid centre coordinates (cell (r, c)'s
    // centre at the integers).
    let half = g as f32 / 2.0 - 0.5;
    let (ahead, leftmost) = (spec.pixels_ahead() + margin as f32, (spec.cells / 2 + margin) as f32);
    for (r, row) in out.chunks_exact_mut(side).enumerate() {
        let forward = (ahead - r as f32 - 0.5) * spec.cell_m;
        let v = half - forward / grid_cell_m;
        for (c, pixel) in row.iter_mut().enumerate() {
            let left = (leftmost - c as f32 - 0.5) * spec.cell_m;
            let u = half - left / grid_cell_m;
            let (r0, c0) = (v.floor(), u.floor());
            let (fv, fu) = (v - r0, u - c0);
            let (r0, c0) = (r0 as isize, c0 as isize);
            *pixel = (1.0 - fv) * ((1.0 - fu) * read(r0, c0) + fu * read(r0, c0 + 1))
                + fv * ((1.0 - fu) * read(r0 + 1, c0) + fu * read(r0 + 1, c0 + 1));
        }
    }
}

impl PfNet {
    /// Every pose's input to the map encoders, `[k][local_map_len]`: its local maps cropped from
    /// `map` (`PfNetConfig::local_maps`, with `map_context` each with its margin) and, with
    /// `scan_on_map`, after each the grid of `obs` (one observation image, the one these poses are
    /// weighed against) laid on its pixels.
    ///
    /// # Panics
    /// As `crop_local_map_stack`, or if `obs` is not one observation image.
    pub fn crop_inputs(
        &self,
        map: &MapView,
        (xs, ys, yaws): (&[f32], &[f32], &[f32]),
        obs: &[f32],
        out: &mut [f32],
    ) {
        let specs = self.config.local_maps();
        let (margin, per_map) = (self.config.map_margin(), self.config.channels_per_local_map());
        if margin == 0 && per_map == 1 {
            return crop_local_map_stack(map, xs, ys, yaws, &specs, out);
        }
        if per_map > 1 {
            assert_eq!(obs.len(), self.obs_len(), "one observation image");
        }
        assert_eq!(out.len(), xs.len() * self.local_map_len(), "out holds poses × local_map_len values");
        if xs.is_empty() {
            return;
        }
        let (stack, pixels) = (self.local_map_len(), self.config.map_input_cells().pow(2));
        for (view, spec) in specs.iter().enumerate() {
            let map_at = per_map * view * pixels;
            for (i, input) in out.chunks_exact_mut(stack).enumerate() {
                crop_with_margin(
                    map,
                    (xs[i], ys[i], yaws[i]),
                    (spec, margin),
                    &mut input[map_at..][..pixels],
                );
            }
            if per_map == 1 {
                continue;
            }
            let (grid, extent_m) = self.grid_of_view(obs, view);
            let scan_at = map_at + pixels;
            let (first, others) = out.split_at_mut(stack);
            let laid = &mut first[scan_at..][..pixels];
            lay_scan(grid, extent_m, (spec, margin), laid);
            for input in others.chunks_exact_mut(stack) {
                input[scan_at..][..pixels].copy_from_slice(laid);
            }
        }
    }

    /// The scan encoders' input (`ScanOnMap::own_encoder`): the grid of each of `n` observations
    /// laid on every local map's pixels, `[n][views][cells²]`.
    ///
    /// # Panics
    /// Without `scan_on_map`, or if `obs` is not `n` observation images.
    pub(super) fn lay_scans(&self, obs: &[f32], n: usize, out: &mut Vec<f32>) {
        assert!(self.config.scan_on_map.is_some(), "a network laying the scan");
        assert_eq!(obs.len(), n * self.obs_len(), "n observation images");
        let specs = self.config.local_maps();
        let pixels = self.config.local_map.cells.pow(2);
        out.resize(n * specs.len() * pixels, 0.0);
        let laid = out.chunks_exact_mut(pixels);
        let views =
            obs.chunks_exact(self.obs_len()).flat_map(|one| (0..specs.len()).map(move |view| (one, view)));
        for (out, (one, view)) in laid.zip(views) {
            let (grid, extent_m) = self.grid_of_view(one, view);
            lay_scan(grid, extent_m, (&specs[view], 0), out);
        }
    }

    /// The grid of one observation image that `view`'s local map is laid with, and its extent:
    /// the paper's grid is the observation's first channel, a wide view's its last.
    pub(super) fn grid_of_view<'a>(&self, obs: &'a [f32], view: usize) -> (&'a [f32], f32) {
        let grid_len = self.config.obs_cells.pow(2);
        match (view, self.config.scan_on_map, self.config.wide_view) {
            (0, Some(scan), _) => (&obs[..grid_len], scan.grid_extent_m),
            (_, Some(_), Some(wide)) => (&obs[obs.len() - grid_len..], wide.grid_extent_m),
            _ => unreachable!("a scan is laid on the paper's local map and a wide view's"),
        }
    }
}

/// The local map of `spec` seen from `pose` and `margin` more pixels on every side: the crop of a
/// map `2·margin` pixels wider, placed so the particle sits as in `spec`'s.
pub(super) fn crop_with_margin(
    map: &MapView,
    (x, y, yaw): (f32, f32, f32),
    (spec, margin): (&LocalMapSpec, usize),
    out: &mut [f32],
) {
    let wider = LocalMapSpec { cells: spec.cells + 2 * margin, ..*spec };
    // The wider crop's own placement puts the particle `back` pixels too far ahead of its edge.
    let back = (wider.pixels_ahead() - spec.pixels_ahead() - margin as f32) * spec.cell_m;
    let (x, y) = (x - back * yaw.cos(), y - back * yaw.sin());
    crop_local_maps(map, &[x], &[y], &[yaw], &wider, out);
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::nn::gradcheck::test_values;
    use crate::nn::pfnet::{MapInput, Observation, PfNetConfig, ScanOnMap, WideView, Workspace};
    use crate::particles::map_view;
    use crate::sense::{LidarParams, LidarScan, LocalGridParams, RayGrid, cast_scan, rasterize_scan};
    use crate::testing::tiny_room;
    use crate::world::Pose2;
    use crate::world::map::NetworkMap;

    /// The 56 × 56 grid (5 m) of the noise-free scan from `pose` in the tiny room.
    fn grid_at(pose: Pose2) -> Vec<f32> {
        let mut scan = LidarScan::default();
        cast_scan(&RayGrid::from_map(&tiny_room()), pose, &[], &LidarParams::default(), &mut scan);
        let mut grid = vec![0.0; 56 * 56];
        rasterize_scan(&scan, &LocalGridParams::default(), &mut grid);
        grid
    }

    /// How well the scan seen from `scan_from`, laid on the local map cropped at `particle`, fits
    /// that map: of the pixels where it shows a hit (darker than unknown: a hit fills a fraction of
    /// a grid cell, so the grid's darkest cells are 0.2–0.3), the share within one pixel of a map
    /// wall; of those it shows free, the share free on the map.
    fn fit(scan_from: Pose2, particle: Pose2, spec: &LocalMapSpec) -> (f32, f32) {
        let cells = spec.cells as isize;
        let mut laid = vec![0.0; spec.cells.pow(2)];
        lay_scan(&grid_at(scan_from), 5.0, (spec, 0), &mut laid);
        let network = NetworkMap::from_fine(&tiny_room(), 0.1);
        let mut local = vec![0.0; laid.len()];
        crop_local_maps(&map_view(&network), &[particle.x], &[particle.y], &[particle.yaw], spec, &mut local);
        let wall_near = |k: isize| {
            let (r, c) = (k / cells, k % cells);
            (-1..=1).any(|dr| {
                (-1..=1).any(|dc| {
                    let (r, c) = (r + dr, c + dc);
                    (0..cells).contains(&r)
                        && (0..cells).contains(&c)
                        && local[(r * cells + c) as usize] < 0.5
                })
            })
        };
        let share = |pixels: Vec<isize>, fits: &dyn Fn(isize) -> bool| {
            assert!(
                pixels.len() >= 10,
                "the scan should show the room in the window, found {}",
                pixels.len()
            );
            pixels.iter().filter(|&&k| fits(k)).count() as f32 / pixels.len() as f32
        };
        let (hits, free): (Vec<isize>, Vec<isize>) = (
            (0..cells * cells).filter(|&k| laid[k as usize] < 0.45).collect(),
            (0..cells * cells).filter(|&k| laid[k as usize] > 0.9).collect(),
        );
        (share(hits, &wall_near), share(free, &|k| local[k as usize] > 0.5))
    }

    #[test]
    fn the_scan_falls_on_the_walls_of_the_true_pose() {
        // Turned, so that a flipped axis or a mirrored side would move the pillar off its walls.
        let truth = Pose2::new(0.55, 0.45, 0.6);
        for centred in [false, true] {
            let spec = LocalMapSpec { centred, ..LocalMapSpec::default() };
            let (hits, free) = fit(truth, truth, &spec);
            assert!(
                hits > 0.95 && free > 0.95,
                "centred {centred}: {hits} of the hits on walls, {free} of the free space free"
            );
            for off in [Pose2::new(0.85, 0.45, 0.6), Pose2::new(0.55, 0.45, 1.1)] {
                let shifted = fit(truth, off, &spec);
                assert!(shifted.1 < free - 0.1, "centred {centred}: {shifted:?} at {off:?} against {free}");
            }
        }
    }

    /// Log-likelihoods of three poses in the tiny room on the scan `obs`, from the network's own crop.
    fn log_likelihoods(model: &PfNet, obs: &[f32]) -> Vec<f32> {
        let network = NetworkMap::from_fine(&tiny_room(), 0.1);
        let (xs, ys, yaws) = ([0.5, 1.2, 1.6], [0.5, 0.8, 1.1], [0.0, 1.5, -2.5]);
        let mut maps = vec![0.0; 3 * model.local_map_len()];
        model.crop_inputs(&map_view(&network), (&xs, &ys, &yaws), obs, &mut maps);
        model.forward_steps(obs, (&maps, MapInput::LocalMaps), 1, 3, &mut Workspace::default()).to_vec()
    }

    #[test]
    fn a_network_gaining_the_scan_starts_as_the_one_without() {
        let scan = ScanOnMap { grid_extent_m: 5.0, own_encoder: false };
        let view = WideView { map_cell_m: 0.2, grid_extent_m: 10.0, own_map_encoder: true };
        for config in [PfNetConfig::compact(), PfNetConfig::compact().with_wide_view(Some(view))] {
            let without = PfNet::new(config, 3).unwrap();
            let mut with = without.with_scan_on_map(scan).unwrap();
            assert_eq!(with.local_map_len(), 2 * without.local_map_len(), "a scan after each local map");
            let obs = test_values(without.obs_len(), 5).iter().map(|v| v.abs()).collect::<Vec<_>>();
            let (want, got) = (log_likelihoods(&without, &obs), log_likelihoods(&with, &obs));
            for (w, g) in want.iter().zip(&got) {
                assert!((w - g).abs() < 1e-5, "{want:?} against {got:?}");
            }
            // Every map encoder reads its scan once its weights there grow.
            for prefix in ["m_c3/", "mw_c3/"].into_iter().take(without.config.map_channels) {
                let id = with.params.find(&format!("{prefix}kernel")).unwrap();
                let taps = 9;
                with.params.get_mut(id)[taps] = 0.5; // output 0, input channel 1 (the scan), first tap
                let nudged = log_likelihoods(&with, &obs);
                assert!(nudged.iter().zip(&got).any(|(a, b)| (a - b).abs() > 1e-4), "{prefix}: {nudged:?}");
                with.params.get_mut(id)[taps] = 0.0;
            }
            assert!(
                with.with_scan_on_map(ScanOnMap { grid_extent_m: 4.0, own_encoder: false }).is_err(),
                "another grid"
            );
        }
    }

    /// With encoders of its own the laid scan stays out of a particle's input, so the feature
    /// cache can hold the map features: each view's scan encoder reads that view's grid laid on
    /// its pixels, once per observation.
    #[test]
    fn a_scan_with_encoders_of_its_own_leaves_the_particles_input_to_the_map() {
        let scan = ScanOnMap { grid_extent_m: 5.0, own_encoder: true };
        let view = WideView { map_cell_m: 0.2, grid_extent_m: 10.0, own_map_encoder: true };
        for config in [PfNetConfig::compact(), PfNetConfig::compact().with_wide_view(Some(view))] {
            let without = PfNet::new(config.clone(), 3).unwrap();
            let mut with = PfNet::new(PfNetConfig { scan_on_map: Some(scan), ..config }, 3).unwrap();
            let obs = test_values(2 * with.obs_len(), 5).iter().map(|v| v.abs()).collect::<Vec<_>>();
            let network = NetworkMap::from_fine(&tiny_room(), 0.1);
            let (xs, ys, yaws) = ([0.5, 1.2], [0.5, 0.8], [0.0, 1.5]);
            let crop = |model: &PfNet| {
                let mut maps = vec![0.0; 2 * model.local_map_len()];
                model.crop_inputs(&map_view(&network), (&xs, &ys, &yaws), &obs[..model.obs_len()], &mut maps);
                maps
            };
            assert_eq!(crop(&with), crop(&without), "the local maps alone");

            let mut laid = Vec::new();
            with.lay_scans(&obs, 2, &mut laid);
            let (specs, grid_len) = (with.config.local_maps(), with.config.obs_cells.pow(2));
            let pixels = with.config.local_map.cells.pow(2);
            for (i, one) in obs.chunks_exact(with.obs_len()).enumerate() {
                // The paper's grid is the first channel, a wide view's the last.
                let grids = [(&one[..grid_len], 5.0), (&one[one.len() - grid_len..], 10.0)];
                for (v, (spec, (grid, extent_m))) in specs.iter().zip(grids).enumerate() {
                    let mut want = vec![0.0; pixels];
                    lay_scan(grid, extent_m, (spec, 0), &mut want);
                    assert_eq!(
                        laid[(i * specs.len() + v) * pixels..][..pixels],
                        want,
                        "observation {i}, view {v}"
                    );
                }
            }

            let got = log_likelihoods(&with, &obs[..with.obs_len()]);
            for prefix in ["s_c3/", "sw_c3/"].into_iter().take(specs.len()) {
                let id = with.params.find(&format!("{prefix}kernel")).unwrap();
                with.params.get_mut(id)[0] += 0.5;
                let nudged = log_likelihoods(&with, &obs[..with.obs_len()]);
                assert!(nudged.iter().zip(&got).any(|(a, b)| (a - b).abs() > 1e-4), "{prefix}: {nudged:?}");
                with.params.get_mut(id)[0] -= 0.5;
            }
            let err = without.with_scan_on_map(scan).unwrap_err();
            assert!(err.contains("train from scratch"), "{err}");
        }
        let one_view =
            PfNet::new(PfNetConfig { scan_on_map: Some(scan), ..PfNetConfig::compact() }, 3).unwrap();
        let err = one_view.with_wide_view(view).unwrap_err();
        assert!(err.contains("encoders of its own"), "{err}");
    }

    /// With `map_context` each image of a particle's input is its local map (or laid scan) and
    /// the first stage's reach of map beyond it on every side: the centre is the image without.
    #[test]
    fn a_margin_of_context_surrounds_each_local_map_and_its_scan() {
        let scan = Some(ScanOnMap { grid_extent_m: 5.0, own_encoder: false });
        let view = WideView { map_cell_m: 0.2, grid_extent_m: 10.0, own_map_encoder: true };
        let centred = LocalMapSpec { centred: true, ..LocalMapSpec::default() };
        let configs = [
            PfNetConfig { scan_on_map: scan, ..PfNetConfig::compact() }.with_wide_view(Some(view)),
            PfNetConfig { local_map: centred, ..PfNetConfig::compact() },
        ];
        let network = NetworkMap::from_fine(&tiny_room(), 0.1);
        let (xs, ys, yaws) = ([0.5, 1.2], [0.5, 0.8], [0.0, 1.5]);
        for (k, config) in configs.into_iter().enumerate() {
            let plain = PfNet::new(config.clone(), 3).unwrap();
            let wider = PfNet::new(PfNetConfig { map_context: true, ..config }, 3).unwrap();
            let obs = test_values(plain.obs_len(), 5).iter().map(|v| v.abs()).collect::<Vec<_>>();
            let crop = |model: &PfNet| {
                let mut maps = vec![0.0; 2 * model.local_map_len()];
                model.crop_inputs(&map_view(&network), (&xs, &ys, &yaws), &obs, &mut maps);
                maps
            };
            let (inner, outer, margin) = (28, wider.config.map_input_cells(), wider.config.map_margin());
            assert_eq!((margin, outer), (9, 46), "the compact first stage reaches 9 pixels");
            let (want, got) = (crop(&plain), crop(&wider));
            let mut beyond = 0.0f32;
            let per_map = wider.config.channels_per_local_map();
            let images = want.chunks_exact(inner * inner).zip(got.chunks_exact(outer * outer));
            for (image, (want, got)) in images.enumerate() {
                let is_map = image % per_map == 0;
                for (r, row) in got.chunks_exact(outer).enumerate() {
                    for (c, &value) in row.iter().enumerate() {
                        match (r.checked_sub(margin), c.checked_sub(margin)) {
                            (Some(i), Some(j)) if i < inner && j < inner => {
                                let expected = want[i * inner + j];
                                assert!(
                                    (value - expected).abs() < 1e-5,
                                    "pixel ({r}, {c}): {value} vs {expected}"
                                );
                            }
                            _ if is_map => beyond = beyond.max(value),
                            _ => {}
                        }
                    }
                }
            }
            // Behind a particle at its local map's bottom edge lies the room's free space (1);
            // the centred local map already spans the tiny room, its margin lies off the map (0).
            if k == 0 {
                assert!(beyond > 0.0, "the margin holds the map, not zero padding");
            }
        }
    }

    #[test]
    fn only_grid_networks_with_an_encoder_per_view_lay_the_scan() {
        let scan = Some(ScanOnMap { grid_extent_m: 5.0, own_encoder: false });
        let depth = PfNetConfig { scan_on_map: scan, ..PfNetConfig::compact().observing(Observation::Depth) };
        assert_eq!(
            depth.check().unwrap_err(),
            "scan_on_map: expected a network observing the LiDAR grid whose views have map encoders of \
             their own, found observation `depth`"
        );
        let view = WideView { map_cell_m: 0.2, grid_extent_m: 10.0, own_map_encoder: false };
        let shared = PfNetConfig { scan_on_map: scan, ..PfNetConfig::compact().with_wide_view(Some(view)) };
        assert!(shared.check().unwrap_err().ends_with("and a wide view through the paper's encoder"));
        let flat = PfNetConfig {
            scan_on_map: Some(ScanOnMap { grid_extent_m: 0.0, own_encoder: false }),
            ..PfNetConfig::compact()
        };
        assert_eq!(flat.check().unwrap_err(), "scan_on_map.grid_extent_m: expected > 0 m, found 0");
    }
}
