//! PF-net's map-feature cache (beyond the paper): the map encoder is translation-equivariant
//! (convolutions, per-pixel LayerNorm, ReLU; only the stride-2 pool snaps to a 2-pixel grid), so
//! instead of encoding every particle's 28 × 28 local map we encode the whole map once per
//! orientation and cut each particle's 14 × 14 features out of that bank.
//!
//! Orientation o has heading φ_o = 2π·o/N. Its *window* is an image of the map (plus a margin)
//! rendered by the spatial transformer as a particle facing φ_o would see it: rows run against
//! φ_o ("up" = φ_o), columns along its right. Window pixel (R, C)'s centre sits at window coordinates
//! (ρ, κ) = (R + ½, C + ½) with ρ(q) = (T − q)·up / δ, κ(q) = (q − T)·right / δ for the window's
//! top-left corner T and pixel side δ (the local map's 0.1 m). The encoder turns the window into
//! features at 2δ whose cell (I, J) summarises pixels 2I…2I+2 × 2J…2J+2 (3 × 3 pool, stride 2, TF
//! 'same': nothing before, one after), i.e. is centred at (ρ, κ) = (2I + 1.5, 2J + 1.5).
//!
//! A particle's exact feature (i, j) summarises its local pixels 2i…2i+2 × 2j…2j+2, centred at
//! forward = (n − 2i − 1.5)·δ, left = (n/2 − 2j − 1.5)·δ in its own frame (n = 28). The cached
//! feature is the bank of the orientation nearest the particle's heading, sampled bilinearly at
//! that point's (I, J): the crop is placed like the exact one and turned by the residual angle
//! (|θ − φ_o| ≤ π/N). When θ = φ_o and the point lands on the bank grid, a feature whose receptive
//! field stays inside the local map equals the exact one (test `aligned_pose_matches_exact_path`).
//! What remains approximate, measured on random poses in a 4 × 3 m room with random weights
//! (`agreement_report`, compact network, N = 32): the exact path's crop border dominates — its
//! convolutions see zero padding where the bank sees the map beyond, and the receptive field (29
//! pixels) reaches the border from every feature — giving a relative feature error of 0.50 and a
//! log-likelihood rank correlation of 0.68 against the exact path (0.42 / 0.81 paper network).
//! Against the same encoder without that border (a local map with 1.6 m of context, centre kept)
//! the cache is at 0.22 / 0.85 (paper 0.18 / 0.91): what is left is the heading residual (features
//! computed at φ_o, not θ) and the sub-cell offset (bilinear at 0.2 m instead of re-pooling; the
//! `pool_phases` option halves that spacing for 4× the memory).
//!
//! With a wide view of its own map encoder (`WideView::own_map_encoder`) each encoder has its
//! bank, rendered at its own pixel size, and a particle's features are both crops side by side.
//!
//! A network laying the scan on its local maps (`ScanOnMap` without encoders of its own) has map
//! features that change with every scan, so no bank holds them; but its first convolution is
//! linear in its two input channels, and the scan's channel is the same image for every particle.
//! Its banks hold that convolution's response to the map alone, every pixel ([`Depth::FirstStage`],
//! 28 × 28 per particle, cell (R, C) centred at (R + ½, C + ½)); the scan's share is computed once
//! per observation and added to each particle's crop, and the rest of the encoder runs per particle
//! (`PfNet::log_likelihoods_banked`). What is approximate is what it is above, at the first
//! convolution's reach (9 pixels) instead of the whole encoder's; with `PfNetConfig::map_context`
//! the exact path's first stage reads the map there too, and only the heading residual and the
//! bilinear sampling of the bank remain (`aligned_pose_matches_exact_path_through_first_stage_banks`).
//!
//! Windows are encoded in tiles with a halo wide enough that every kept feature sees exactly what
//! a one-shot encoding of the window would: memory stays bounded for large maps (the second
//! stage's im2col of a 640 × 640 window would take 0.6 GB in the paper network).
//!
//! Memory: N × C × (rotated map's bounding box + 2 × 3.2 m margin, at 0.2 m) floats — an 8 × 10 m
//! apartment at N = 32, C = 8: ≈ 8 MB; a 30 × 50 m warehouse ≈ 85 MB (×4 with `pool_phases`).

use super::config::MAX_LOCAL_MAP_CELLS;
use super::map_encoder::{MapActivations, MapEncoder};
use super::model::PfNet;
use super::spatial_transformer::{LocalMapSpec, MapView, crop_local_maps};
use super::stage::ChannelScratch;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::f64::consts::TAU;

/// Feature cells per tile side (plus the halo): the paper's second-stage im2col of one tile then
/// takes 1,600 taps × 80² pixels ≈ 41 MB per thread.
const TILE: usize = 64;
/// Cells of a crop whose taps are kept for every channel's plane (a network's features, the
/// paper's 14 × 14 at most (64 / 2)²); larger crops compute each cell's tap once as they go.
const PLANE_CELLS: usize = (MAX_LOCAL_MAP_CELLS / 2).pow(2);
/// Rows of a first-stage crop whose bank lines are requested before they are mixed.
const PREFETCH_ROWS: usize = 2;
/// Channels a crop mixes at once.
const CHANNEL_RUN: usize = 32;
/// Poses per parallel task of `crop_features`.
const CROP_CHUNK: usize = 64;

/// How many orientations the bank holds.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct FeatureCacheSpec {
    /// N: headings 2π·o/N; a particle's heading is at most π/N from one of them.
    pub orientations: usize,
    /// Also encode the window shifted by one pixel down, right and both, so the bank holds
    /// features every 0.1 m instead of 0.2 m (every phase of the stride-2 pool): 4× the memory
    /// and build time, a particle's features interpolated 0.1 m apart instead of 0.2 m.
    pub pool_phases: bool,
}

impl Default for FeatureCacheSpec {
    fn default() -> Self {
        Self { orientations: 32, pool_phases: false }
    }
}

/// What a bank holds of its map encoder.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Depth {
    /// The encoder's output: a feature every second pixel (after the stride-2 pool).
    Features,
    /// The first-stage convolution's response to the map channel alone, every pixel.
    FirstStage,
}

impl Depth {
    /// What `model`'s banks hold: the first stage when it lays the scan on its local maps.
    fn of(model: &PfNet) -> Self {
        match model.banks_hold_first_stage() {
            true => Self::FirstStage,
            false => Self::Features,
        }
    }

    /// Window pixels per cell of the encoded image, and a cell's centre in pixels from its
    /// top-left corner.
    fn step_and_centre(self) -> (usize, f64) {
        match self {
            Self::Features => (2, 1.5),
            Self::FirstStage => (1, 0.5),
        }
    }
}

/// One orientation's encoded window.
#[derive(Clone, Debug)]
struct Orientation {
    /// World unit vectors of the window's up (heading φ_o) and right.
    up: [f64; 2],
    right: [f64; 2],
    /// World position of the window's top-left corner T.
    corner: [f64; 2],
    /// Bank cells: window pixels / 2, or window pixels with every pool phase or at the first stage.
    rows: usize,
    cols: usize,
    /// [rows][cols][channels]: channels last, so a bilinear tap reads one contiguous run.
    features: Vec<f32>,
}

/// The map encoded at every orientation by each of the network's map encoders (the paper's, then
/// a wide view's own, at its wider pixels); see the module doc for the geometry.
#[derive(Clone, Debug)]
pub struct FeatureBank {
    encoders: Vec<EncoderBank>,
}

/// One map encoder's bank.
#[derive(Clone, Debug)]
struct EncoderBank {
    orientations: Vec<Orientation>,
    channels: usize,
    depth: Depth,
    /// A particle's local map: its side n, pixel side δ and the particle's place in it.
    local: LocalMapSpec,
    /// Window pixels between neighbouring bank cells: 2, or 1 with every pool phase or at the
    /// first stage.
    pixels_per_cell: f64,
}

/// A build thread's buffers.
#[derive(Default)]
struct Scratch {
    acts: MapActivations,
    /// A tile's first stage, and its buffers.
    first: Vec<f32>,
    channel: ChannelScratch,
    image: Vec<f32>,
    tile: Vec<f32>,
}

impl FeatureBank {
    /// Encodes `map` at every orientation with each of `model`'s map encoders (parallel over
    /// orientations with rayon; the result does not depend on the thread count).
    ///
    /// # Panics
    /// If `spec.orientations` is 0, a map encoder reads more than one local map (the spatial
    /// transformer renders one: a wide view needs `own_map_encoder`), or the map view is
    /// malformed (see `crop_local_maps`). `pool_phases` is moot for a first-stage bank (it holds
    /// every pixel).
    pub fn build(model: &PfNet, map: &MapView, spec: &FeatureCacheSpec) -> Self {
        Self::build_tiled(model, map, spec, TILE)
    }

    fn build_tiled(model: &PfNet, map: &MapView, spec: &FeatureCacheSpec, tile: usize) -> Self {
        assert!(spec.orientations > 0, "a feature bank needs at least one orientation");
        let config = &model.config;
        assert_eq!(
            config.map_encoder_channels(),
            config.channels_per_local_map(),
            "the spatial transformer renders one local map per encoder"
        );
        let depth = Depth::of(model);
        let encoders = (model.map_encoders().zip(config.local_maps()))
            .map(|(encoder, local)| EncoderBank::build((model, encoder, depth), local, map, spec, tile))
            .collect();
        Self { encoders }
    }

    /// Bytes held by the feature banks.
    pub fn memory_bytes(&self) -> usize {
        size_of::<Self>() + self.encoders.iter().map(EncoderBank::memory_bytes).sum::<usize>()
    }

    /// Values of one pose's features: every encoder's.
    fn feature_len(&self) -> usize {
        self.encoders.iter().map(EncoderBank::feature_len).sum()
    }

    /// Whether the banks hold the first stage's response to the map (a network laying the scan
    /// on its local maps, `crop_first_stage`) rather than map features (`crop_features`).
    pub fn holds_first_stage(&self) -> bool {
        self.encoders.first().is_some_and(|bank| bank.depth == Depth::FirstStage)
    }

    /// The orientation whose banks a particle heading `yaw` crops (every encoder holds the same).
    pub fn orientation_of(&self, yaw: f32) -> usize {
        self.encoders.first().map_or(0, |bank| bank.nearest_orientation(f64::from(yaw)))
    }

    /// Map encoder `encoder`'s first-stage response to the map at one pose (world x, y, yaw) →
    /// out [channels][n][n], the layout of the exact path's first convolution without the scan
    /// and the biases.
    ///
    /// # Panics
    /// If the banks hold map features, `encoder` is not one of the network's map encoders, or
    /// `out` is not one first stage long.
    pub fn crop_first_stage(&self, encoder: usize, (x, y, yaw): (f32, f32, f32), out: &mut [f32]) {
        assert!(self.holds_first_stage(), "crop_first_stage: the banks hold map features");
        let bank = &self.encoders[encoder];
        assert_eq!(out.len(), bank.feature_len(), "out holds one first stage");
        bank.crop_one(x, y, yaw, out);
    }

    /// For each pose (world x, y, yaw) writes its map features into out[k] ([k][channels][n/2][n/2],
    /// the layout of the exact path's encoder output). Poses beyond the margin read the window's
    /// edge (the features of all-occupied space); non-finite poses read a corner of it.
    ///
    /// # Panics
    /// If the banks hold first stages, `xs`, `ys` and `yaws` differ in length or `out.len()` is not
    /// poses × feature length.
    pub fn crop_features(&self, xs: &[f32], ys: &[f32], yaws: &[f32], out: &mut [f32]) {
        let len = self.feature_len();
        assert!(!self.holds_first_stage(), "crop_features: the banks hold first stages (crop_first_stage)");
        assert!(xs.len() == ys.len() && xs.len() == yaws.len(), "one x, y and yaw per pose");
        assert_eq!(out.len(), xs.len() * len, "out holds poses × map feature length");
        if len == 0 {
            return;
        }
        out.par_chunks_mut(CROP_CHUNK * len).enumerate().for_each(|(chunk, block)| {
            for (k, mut features) in block.chunks_exact_mut(len).enumerate() {
                let k = chunk * CROP_CHUNK + k;
                for bank in &self.encoders {
                    let (own, rest) = features.split_at_mut(bank.feature_len());
                    bank.crop_one(xs[k], ys[k], yaws[k], own);
                    features = rest;
                }
            }
        });
    }
}

impl EncoderBank {
    fn build(
        (model, encoder, depth): (&PfNet, &MapEncoder, Depth),
        local: LocalMapSpec,
        map: &MapView,
        spec: &FeatureCacheSpec,
        tile: usize,
    ) -> Self {
        let phases = spec.pool_phases && depth == Depth::Features;
        let channels = match depth {
            Depth::Features => encoder.feature_len() / (local.cells / 2).pow(2),
            Depth::FirstStage => encoder.first_stage_channels(),
        };
        let orientations = (0..spec.orientations)
            .into_par_iter()
            .map_init(Scratch::default, |scratch, o| {
                let heading = TAU * o as f64 / spec.orientations as f64;
                let encoder = (model, encoder, depth, channels);
                encode_orientation(encoder, local, map, (heading, phases, tile), scratch)
            })
            .collect();
        let pixels_per_cell = if phases { 1.0 } else { depth.step_and_centre().0 as f64 };
        Self { orientations, channels, depth, local, pixels_per_cell }
    }

    fn memory_bytes(&self) -> usize {
        self.orientations.iter().map(|o| o.features.len() * size_of::<f32>()).sum::<usize>()
            + size_of::<Self>()
            + self.orientations.len() * size_of::<Orientation>()
    }

    /// Cells of one side of a particle's crop: its local map's, or half at the encoder's output.
    fn side(&self) -> usize {
        self.local.cells / self.depth.step_and_centre().0
    }

    fn feature_len(&self) -> usize {
        self.channels * self.side().pow(2)
    }

    /// The orientation whose window a particle heading `yaw` crops (a NaN heading crops the first).
    fn nearest_orientation(&self, yaw: f64) -> usize {
        let count = self.orientations.len();
        ((yaw * count as f64 / TAU).round() as i64).rem_euclid(count as i64) as usize
    }

    fn crop_one(&self, x: f32, y: f32, yaw: f32, out: &mut [f32]) {
        let (x, y, yaw) = (f64::from(x), f64::from(y), f64::from(yaw));
        let bank = &self.orientations[self.nearest_orientation(yaw)];
        let (sin, cos) = yaw.sin_cos();
        // The pixels between the particle and the map's far edge: n, or n/2 when centred.
        let (n, a, d) =
            (self.local.cells as f64, f64::from(self.local.pixels_ahead()), f64::from(self.local.cell_m));
        let (step, centre) = self.depth.step_and_centre();
        let step = step as f64;
        // Bank coordinates (I, J) of the point `forward`, `left` pixels from the particle.
        let to_bank = |forward: f64, left: f64| {
            let q = [x + (forward * cos - left * sin) * d, y + (forward * sin + left * cos) * d];
            let (tq, qt) = (
                [bank.corner[0] - q[0], bank.corner[1] - q[1]],
                [q[0] - bank.corner[0], q[1] - bank.corner[1]],
            );
            let rho = (tq[0] * bank.up[0] + tq[1] * bank.up[1]) / d;
            let kappa = (qt[0] * bank.right[0] + qt[1] * bank.right[1]) / d;
            [(rho - centre) / self.pixels_per_cell, (kappa - centre) / self.pixels_per_cell]
        };
        // Cell (i, j) is centred at forward = a − s·i − o, left = n/2 − s·j − o pixels (s pixels
        // per cell, o its centre: 2 and 1.5 for features): affine in (i, j).
        let (ahead, left) = (a - centre, n / 2.0 - centre);
        let first = to_bank(ahead, left);
        let next_i = to_bank(ahead - step, left);
        let next_j = to_bank(ahead, left - step);
        let di = [(next_i[0] - first[0]) as f32, (next_i[1] - first[1]) as f32];
        let dj = [(next_j[0] - first[0]) as f32, (next_j[1] - first[1]) as f32];
        let first = [first[0] as f32, first[1] as f32];

        let (side, c) = (self.side(), self.channels);
        let (max_u, max_v) = ((bank.rows - 1) as f32, (bank.cols - 1) as f32);
        // Cell (i, j)'s top-left bank tap and its bilinear fractions.
        let tap_of = |i: usize, j: usize| {
            let (i, j) = (i as f32, j as f32);
            // `max` first: NaN becomes 0, a corner of the window.
            let u = (first[0] + i * di[0] + j * dj[0]).max(0.0).min(max_u);
            let v = (first[1] + i * di[1] + j * dj[1]).max(0.0).min(max_v);
            let (i0, j0) = ((u as usize).min(bank.rows - 2), (v as usize).min(bank.cols - 2));
            ((i0 * bank.cols + j0) * c, u - i0 as f32, v - j0 as f32)
        };
        let (below, plane) = (bank.cols * c, side * side);
        if c < CHANNEL_RUN / 2 && plane <= PLANE_CELLS {
            // A few channels (a network's map features): the taps once, then plane by plane, each
            // written in order.
            let mut taps = [(0usize, 0.0f32, 0.0f32); PLANE_CELLS];
            for (cell, tap) in taps.iter_mut().take(plane).enumerate() {
                *tap = tap_of(cell / side, cell % side);
            }
            for (ch, plane) in out.chunks_exact_mut(plane).enumerate() {
                let features = &bank.features[ch..];
                for (value, &(top, fu, fv)) in plane.iter_mut().zip(&taps) {
                    let (t, b) = (&features[top..][..c + 1], &features[top + below..][..c + 1]);
                    let upper = t[0] + fv * (t[c] - t[0]);
                    let lower = b[0] + fv * (b[c] - b[0]);
                    *value = upper + fu * (lower - upper);
                }
            }
            return;
        }
        // Many (a first stage): row by row, each cell's channels' four taps are contiguous runs,
        // mixed a run at a time (vectorised) into `mixed` [cell][channel], then each channel's
        // part of the row is written to its plane in one go. The crop waits on memory more than
        // on arithmetic, so a row's taps are found `PREFETCH_ROWS` rows ahead and the lines of
        // their lower bank row requested then (the upper one is mostly the row before's lower).
        let mut taps = [[(0usize, 0.0f32, 0.0f32); MAX_LOCAL_MAP_CELLS]; PREFETCH_ROWS + 1];
        let find_row = |i: usize, taps: &mut [(usize, f32, f32)]| {
            for (j, tap) in taps.iter_mut().take(side).enumerate() {
                *tap = tap_of(i, j);
                prefetch(&bank.features[tap.0 + below..][..2 * c]);
            }
        };
        for (i, row_taps) in taps.iter_mut().enumerate().take(PREFETCH_ROWS.min(side)) {
            find_row(i, row_taps);
        }
        let mut mixed = [0.0f32; MAX_LOCAL_MAP_CELLS * CHANNEL_RUN];
        for i in 0..side {
            if i + PREFETCH_ROWS < side {
                find_row(i + PREFETCH_ROWS, &mut taps[(i + PREFETCH_ROWS) % (PREFETCH_ROWS + 1)]);
            }
            let row_taps = &taps[i % (PREFETCH_ROWS + 1)];
            for first in (0..c).step_by(CHANNEL_RUN) {
                let run = CHANNEL_RUN.min(c - first);
                for (mixed, &(top, fu, fv)) in mixed.chunks_exact_mut(CHANNEL_RUN).zip(row_taps).take(side) {
                    let tap = |at: usize| &bank.features[at + first..][..run];
                    let (t0, t1, b0, b1) = (tap(top), tap(top + c), tap(top + below), tap(top + below + c));
                    let corners = t0.iter().zip(t1).zip(b0).zip(b1);
                    for (m, (((&t0, &t1), &b0), &b1)) in mixed.iter_mut().zip(corners) {
                        let upper = t0 + fv * (t1 - t0);
                        let lower = b0 + fv * (b1 - b0);
                        *m = upper + fu * (lower - upper);
                    }
                }
                for ch in 0..run {
                    let row = &mut out[(first + ch) * plane + i * side..][..side];
                    for (value, cell) in row.iter_mut().zip(mixed.chunks_exact(CHANNEL_RUN)) {
                        *value = cell[ch];
                    }
                }
            }
        }
    }
}

/// Asks the cache for the first and last lines of `run` (a hint: no value depends on it); the
/// neighbouring cells' requests cover the lines between.
#[inline(always)]
fn prefetch(run: &[f32]) {
    #[cfg(target_arch = "x86_64")]
    {
        use std::arch::x86_64::{_MM_HINT_T0, _mm_prefetch};
        // SAFETY: SSE is in every x86-64 CPU, and a prefetch reads nothing (the pointers are
        // in bounds anyway).
        unsafe {
            _mm_prefetch::<_MM_HINT_T0>(run.as_ptr().cast());
            _mm_prefetch::<_MM_HINT_T0>(run.as_ptr_range().end.wrapping_sub(1).cast());
        }
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = run; // std has no portable prefetch: the hardware's own prefetcher is left to it
}

/// Renders the window of heading `heading` (map + margin) at `local`'s pixels and encodes it tile
/// by tile with `encoder`, to the bank's depth.
fn encode_orientation(
    (model, encoder, depth, channels): (&PfNet, &MapEncoder, Depth, usize),
    local: LocalMapSpec,
    map: &MapView,
    (heading, phases, tile): (f64, bool, usize),
    s: &mut Scratch,
) -> Orientation {
    let d = f64::from(local.cell_m);
    // A feature of a particle on the map reaches √(2.8² + 1.4²) ≈ 3.1 m away; two more feature
    // cells keep the second stage's 5 × 5 convolution off the window's edge.
    let margin = (local.cells + 4) as f64;
    let (sin, cos) = heading.sin_cos();
    let (up, right) = ([cos, sin], [sin, -cos]);

    // The map's corners along up and right, in pixels.
    let (osin, ocos) = f64::from(map.origin_yaw_rad).sin_cos();
    let (w, h) =
        (map.width as f64 * f64::from(map.resolution_m), map.height as f64 * f64::from(map.resolution_m));
    let (mut up_range, mut right_range) = ([f64::MAX, f64::MIN], [f64::MAX, f64::MIN]);
    for (gx, gy) in [(0.0, 0.0), (w, 0.0), (0.0, h), (w, h)] {
        let q = [
            f64::from(map.origin_x_m) + ocos * gx - osin * gy,
            f64::from(map.origin_y_m) + osin * gx + ocos * gy,
        ];
        let (a, b) = ((q[0] * up[0] + q[1] * up[1]) / d, (q[0] * right[0] + q[1] * right[1]) / d);
        up_range = [up_range[0].min(a), up_range[1].max(a)];
        right_range = [right_range[0].min(b), right_range[1].max(b)];
    }
    // Even sides, so pool windows start on even pixels as in a local map.
    let even = |extent: f64| 2 * ((extent + 2.0 * margin) / 2.0).ceil() as usize;
    let (px_rows, px_cols) = (even(up_range[1] - up_range[0]), even(right_range[1] - right_range[0]));
    // ρ = margin at the map's farthest point ahead, κ = margin at its leftmost.
    let (t_up, t_right) = ((up_range[1] + margin) * d, (right_range[0] - margin) * d);
    let corner = [t_up * up[0] + t_right * right[0], t_up * up[1] + t_right * right[1]];

    // The spatial transformer's square crop whose top-left corner is T; the window is its top-left part.
    let side = px_rows.max(px_cols) + 2; // one more pixel for the shifted pool phases
    let sf = side as f64 * d;
    let pose = [corner[0] - sf * up[0] + sf / 2.0 * right[0], corner[1] - sf * up[1] + sf / 2.0 * right[1]];
    s.image.resize(side * side, 0.0);
    let spec = LocalMapSpec { cells: side, cell_m: local.cell_m, centred: false };
    crop_local_maps(map, &[pose[0] as f32], &[pose[1] as f32], &[heading as f32], &spec, &mut s.image);

    // q window pixels per encoded cell.
    let q = depth.step_and_centre().0;
    let (rows, cols) = (px_rows / q, px_cols / q);
    let (stride, shifts): (usize, &[(usize, usize)]) =
        if phases { (2, &[(0, 0), (0, 1), (1, 0), (1, 1)]) } else { (1, &[(0, 0)]) };
    let (bank_rows, bank_cols) = (rows * stride, cols * stride);
    let mut features = vec![0.0; bank_rows * bank_cols * channels];
    let halo = halo(model, depth);
    // Shift (a, b): the pool's windows start at pixel (2I + a, 2J + b), bank cell (stride·I + a, stride·J + b).
    for &(a, b) in shifts {
        for r0 in (0..rows).step_by(tile) {
            for c0 in (0..cols).step_by(tile) {
                let (r1, c1) = ((r0 + tile).min(rows), (c0 + tile).min(cols));
                // Encoded rows/cols [a, b) of the window, from its pixels [q·a, q·b).
                let (ra, rb) = (r0.saturating_sub(halo), (r1 + halo).min(rows));
                let (ca, cb) = (c0.saturating_sub(halo), (c1 + halo).min(cols));
                let (th, tw) = (q * (rb - ra), q * (cb - ca));
                s.tile.clear();
                for pr in q * ra..q * rb {
                    s.tile.extend_from_slice(&s.image[(pr + a) * side + q * ca + b..][..tw]);
                }
                let encoded = encode_tile((model, encoder, depth), (th, tw), s);
                let (fh, fw) = (th / q, tw / q);
                for r in r0..r1 {
                    for c in c0..c1 {
                        let at = ((stride * r + a) * bank_cols + stride * c + b) * channels;
                        let cell = &mut features[at..][..channels];
                        for (ch, value) in cell.iter_mut().enumerate() {
                            *value = encoded[(ch * fh + r - ra) * fw + c - ca];
                        }
                    }
                }
            }
        }
    }
    Orientation { up, right, corner, rows: bank_rows, cols: bank_cols, features }
}

/// One tile (`s.tile`, th × tw pixels) encoded to `depth`: [channels][th/q][tw/q].
fn encode_tile<'s>(
    (model, encoder, depth): (&PfNet, &MapEncoder, Depth),
    (th, tw): (usize, usize),
    s: &'s mut Scratch,
) -> &'s [f32] {
    match depth {
        Depth::Features => {
            encoder.forward_sized(&model.params, &s.tile, 1, (th, tw), &mut s.acts);
            &s.acts.features
        }
        Depth::FirstStage => {
            s.first.resize(encoder.first_stage_channels() * th * tw, 0.0);
            encoder.first_stage_of_channel(
                &model.params,
                0,
                (&s.tile, 0),
                (th, tw),
                false,
                &mut s.first,
                &mut s.channel,
            );
            &s.first
        }
    }
}

/// Encoded cells a tile must extend beyond the cells it keeps so they match a one-shot encoding:
/// at the first stage its reach r1 in pixels; for features, the second stage reaches r2 pooled
/// cells, a pool window 2 pixels further, the first stage r1 pixels.
fn halo(model: &PfNet, depth: Depth) -> usize {
    let reach = |branches: &[super::config::ConvBranch]| {
        branches.iter().map(|b| ((b.kernel - 1) * b.dilation).div_ceil(2)).max().unwrap_or(0)
    };
    let (r1, r2) = (reach(&model.config.map_stage1), reach(&model.config.map_stage2));
    match depth {
        Depth::Features => r2 + (r1 + 1).div_ceil(2) + 1,
        Depth::FirstStage => r1,
    }
}

#[cfg(test)]
mod tests {
    use super::super::config::{PfNetConfig, ScanOnMap, WideView};
    use super::super::model::Workspace;
    use super::super::scan_on_map::crop_with_margin;
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_pcg::Pcg64;
    use std::ops::RangeInclusive;
    use std::sync::Arc;

    pub(super) struct TestMap {
        occupancy: Vec<f32>,
        width: usize,
        height: usize,
        pub(super) origin: (f32, f32, f32),
    }

    impl TestMap {
        pub(super) fn view(&self) -> MapView<'_> {
            MapView {
                occupancy: &self.occupancy,
                width: self.width,
                height: self.height,
                resolution_m: 0.1,
                origin_x_m: self.origin.0,
                origin_y_m: self.origin.1,
                origin_yaw_rad: self.origin.2,
            }
        }
    }

    /// A 4 × 3 m room: outer walls, two inner walls with a door, a few boxes, blurred edges.
    pub(super) fn room(seed: u64) -> TestMap {
        let (width, height) = (40, 30);
        let mut rng = Pcg64::seed_from_u64(seed);
        let mut occ = vec![0.0f32; width * height];
        let mut set = |i: usize, j: usize, v: f32| occ[j * width + i] = v;
        for i in 0..width {
            set(i, 0, 1.0);
            set(i, height - 1, 1.0);
        }
        for j in 0..height {
            set(0, j, 1.0);
            set(width - 1, j, 1.0);
            if !(12..20).contains(&j) {
                set(17, j, 1.0);
            }
        }
        for i in 17..32 {
            set(i, 21, 0.8);
        }
        for _ in 0..6 {
            let (i, j) = (rng.random_range(2..36), rng.random_range(2..26));
            for (di, dj) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
                set(i + di, j + dj, rng.random_range(0.5..1.0));
            }
        }
        TestMap { occupancy: occ, width, height, origin: (-0.7, 0.4, 0.35) }
    }

    /// The observation a network laying the scan on its local maps is given: a fixed pattern.
    fn observation(model: &PfNet) -> Vec<f32> {
        (0..model.obs_len()).map(|i| ((i * 7 + i / 13) % 3) as f32 / 2.0).collect()
    }

    /// Exact path: crop each pose's local map (and lay `observation`'s scan on it), encode it.
    pub(super) fn exact(model: &PfNet, map: &MapView, xs: &[f32], ys: &[f32], yaws: &[f32]) -> Vec<f32> {
        let mut maps = vec![0.0; xs.len() * model.local_map_len()];
        model.crop_inputs(map, (xs, ys, yaws), &observation(model), &mut maps);
        let mut features = vec![0.0; xs.len() * model.map_feature_len()];
        model.encode_local_maps(&maps, xs.len(), &mut features, &mut Default::default());
        features
    }

    pub(super) fn cached(
        bank: &FeatureBank,
        model: &PfNet,
        xs: &[f32],
        ys: &[f32],
        yaws: &[f32],
    ) -> Vec<f32> {
        let mut features = vec![f32::NAN; xs.len() * model.map_feature_len()];
        if !bank.holds_first_stage() {
            bank.crop_features(xs, ys, yaws, &mut features);
            return features;
        }
        let (mut ws, mut terms) = (Workspace::default(), vec![0.0; model.scan_term_len()]);
        model.scan_terms(&observation(model), &mut terms, &mut ws);
        let poses: Vec<[f32; 3]> = (0..xs.len()).map(|k| [xs[k], ys[k], yaws[k]]).collect();
        let (owner, banks) = (vec![0; xs.len()], [Arc::new(bank.clone())]);
        model.encode_banked((&poses, &owner), (&banks, &terms), &mut features, &mut ws);
        features
    }

    #[test]
    fn aligned_pose_matches_exact_path() {
        // A 56-pixel local map has 14 × 14 interior features whose receptive field (29 pixels)
        // never meets the crop's zero padding; at 28 pixels none does. With a wide view of its
        // own encoder, each bank is checked at a pose on its own grid.
        let wide = WideView { map_cell_m: 0.2, grid_extent_m: 10.0, own_map_encoder: true };
        for wide_view in [None, Some(wide)] {
            let config = PfNetConfig {
                local_map: LocalMapSpec { cells: 56, ..LocalMapSpec::default() },
                obs_cells: 112,
                ..PfNetConfig::compact()
            };
            let model = PfNet::new(config.with_wide_view(wide_view), 3).unwrap();
            let map = room(1);
            for pool_phases in [false, true] {
                let spec = FeatureCacheSpec { orientations: 8, pool_phases };
                let built = FeatureBank::build(&model, &map.view(), &spec);
                let mut first = 0;
                for (bank, local) in built.encoders.iter().zip(model.config.local_maps()) {
                    let what = format!("{spec:?}, {} m pixels", local.cell_m);
                    let features = (first, bank.feature_len(), 7..=20);
                    assert_aligned_pose_matches(&model, &map, (&built, bank, features), local, &what);
                    first += bank.feature_len();
                }
            }
        }
    }

    /// `log_likelihoods_banked` crops a two-robot global belief in its own order (`CropOrder`)
    /// and must return each particle exactly what the particles taken as they come, chunk by
    /// chunk as the rayon tasks take them, give.
    #[test]
    fn banked_likelihoods_in_crop_order_equal_those_in_particle_order() {
        use super::super::batch::{CropOrder, MAP_ENCODER_CHUNK, PARTICLE_CHUNK, Workspaces};
        let scan_on_map = Some(ScanOnMap { grid_extent_m: 5.0, own_encoder: false });
        let model = PfNet::new(PfNetConfig { scan_on_map, ..PfNetConfig::compact() }, 3).unwrap();
        let spec = FeatureCacheSpec { orientations: 8, pool_phases: false };
        let banks = [1, 2].map(|seed| Arc::new(FeatureBank::build(&model, &room(seed).view(), &spec)));
        let mut rng = Pcg64::seed_from_u64(9);
        let n = 2 * PARTICLE_CHUNK + 44; // the last task short
        let poses: Vec<[f32; 3]> = (0..n)
            .map(|_| [rng.random_range(-0.5..3.0), rng.random_range(0.5..3.5), rng.random_range(-3.2..3.2)])
            .collect();
        let owner: Vec<u32> = (0..n).map(|_| rng.random_range(0..2)).collect();
        let mut order = CropOrder::default();
        order.sort(&poses, &owner, &banks);
        assert!(order.moves_any(), "the order must differ from the particles' own");

        let mut ws = Workspace::default();
        let obs: Vec<f32> = [observation(&model), observation(&model).into_iter().rev().collect()].concat();
        let mut obs_terms = vec![0.0; 2 * model.obs_term_len()];
        model.observation_terms(&obs, 2, &mut obs_terms, &mut ws);
        let mut scan_terms = vec![0.0; 2 * model.scan_term_len()];
        for (one, terms) in obs.chunks(model.obs_len()).zip(scan_terms.chunks_mut(model.scan_term_len())) {
            model.scan_terms(one, terms, &mut ws);
        }
        let mut got = vec![f32::NAN; n];
        let terms = (&obs_terms[..], &scan_terms[..]);
        model.log_likelihoods_banked(
            terms,
            &owner,
            (&poses, &banks),
            &mut got,
            &Workspaces::for_current_pool(),
        );

        let (flen, mut want) = (model.map_feature_len(), vec![f32::NAN; n]);
        for ((poses, owner), out) in poses
            .chunks(PARTICLE_CHUNK)
            .zip(owner.chunks(PARTICLE_CHUNK))
            .zip(want.chunks_mut(PARTICLE_CHUNK))
        {
            let mut features = vec![0.0; poses.len() * flen];
            let subs = poses.chunks(MAP_ENCODER_CHUNK).zip(owner.chunks(MAP_ENCODER_CHUNK));
            for (sub, part) in subs.zip(features.chunks_mut(MAP_ENCODER_CHUNK * flen)) {
                model.encode_banked(sub, (&banks, &scan_terms), part, &mut ws);
            }
            model.joint_log_likelihoods(&features, &obs_terms, owner, out, &mut ws);
        }
        assert!(want.iter().all(|l| l.is_finite()));
        assert_eq!(got, want, "to the bit");
    }

    #[test]
    fn aligned_pose_matches_exact_path_through_first_stage_banks() {
        // A network laying the scan on its local maps: each particle's first stage cropped from
        // the bank plus the scan's share, then the rest of the encoder. The first stage reaches 9
        // pixels, so the same interior features as above never meet the crop's border; with
        // `map_context` the exact path's first stage reads the map there as the bank does, and
        // every feature matches.
        let wide = WideView { map_cell_m: 0.2, grid_extent_m: 10.0, own_map_encoder: true };
        for (wide_view, map_context) in [(None, false), (Some(wide), false), (Some(wide), true)] {
            let config = PfNetConfig {
                local_map: LocalMapSpec { cells: 56, ..LocalMapSpec::default() },
                obs_cells: 112,
                scan_on_map: Some(ScanOnMap { grid_extent_m: 5.0, own_encoder: false }),
                map_context,
                ..PfNetConfig::compact()
            };
            let model = PfNet::new(config.with_wide_view(wide_view), 4).unwrap();
            let map = room(1);
            let built = FeatureBank::build(
                &model,
                &map.view(),
                &FeatureCacheSpec { orientations: 8, pool_phases: false },
            );
            assert!(built.holds_first_stage());
            let mut first = 0;
            for (e, local) in model.config.local_maps().into_iter().enumerate() {
                let bank = &built.encoders[e];
                let what = format!("first stage, {} m pixels, context {map_context}", local.cell_m);
                let len = model.map_encoders().nth(e).unwrap().feature_len();
                let cells = if map_context { 0..=27 } else { 7..=20 };
                let features = (first, len, cells);
                assert_aligned_pose_matches(&model, &map, (&built, bank, features), local, &what);
                first += len;
            }
        }
    }

    /// At poses facing a bank's orientations whose local maps sit on its grid, the features of
    /// `bank`'s encoder (`len` values from `first` of a pose's features) in rows and columns
    /// `cells` equal the exact path's.
    fn assert_aligned_pose_matches(
        model: &PfNet,
        map: &TestMap,
        (built, bank, (first, len, cells)): (
            &FeatureBank,
            &EncoderBank,
            (usize, usize, RangeInclusive<usize>),
        ),
        local: LocalMapSpec,
        what: &str,
    ) {
        let (n, half, d) = (56.0, 28, f64::from(local.cell_m));
        // With every pool phase an odd pixel offset is on the bank's grid too.
        let (stride, shift) = if bank.pixels_per_cell == 1.0 { (2, 1.0) } else { (1, 0.0) };
        for o in [0, 3, 6] {
            let b = &bank.orientations[o];
            // A pose whose local map's top-left pixel is window pixel (R0, C0): ρ(p) = R0 + n,
            // κ(p) = C0 + n/2. Pick it near the map's middle.
            let even = |cells: usize| (2 * (cells / stride / 2)) as f64 - 28.0 + shift;
            let (r0, c0) = (even(b.rows), even(b.cols));
            let (rho, kappa) = ((r0 + n) * d, (c0 + n / 2.0) * d);
            let x = b.corner[0] - rho * b.up[0] + kappa * b.right[0];
            let y = b.corner[1] - rho * b.up[1] + kappa * b.right[1];
            let yaw = (TAU * o as f64 / 8.0) as f32;
            let want = exact(model, &map.view(), &[x as f32], &[y as f32], &[yaw]);
            let got = cached(built, model, &[x as f32], &[y as f32], &[yaw]);
            let (want, got) = (&want[first..][..len], &got[first..][..len]);
            let mut worst = 0.0f32;
            for ch in 0..len / (half * half) {
                for i in cells.clone() {
                    for j in cells.clone() {
                        let k = (ch * half + i) * half + j;
                        worst = worst.max((got[k] - want[k]).abs());
                    }
                }
            }
            let scale = want.iter().fold(0.0f32, |m, v| m.max(v.abs()));
            assert!(scale > 0.1, "{what}: features are not trivially zero");
            assert!(
                worst < 2e-4 * scale.max(1.0),
                "{what}, orientation {o}: worst interior difference {worst}"
            );
        }
    }

    fn ranks(v: &[f32]) -> Vec<f64> {
        let mut order: Vec<usize> = (0..v.len()).collect();
        order.sort_by(|&a, &b| v[a].total_cmp(&v[b]));
        let mut r = vec![0.0; v.len()];
        for (rank, &k) in order.iter().enumerate() {
            r[k] = rank as f64;
        }
        r
    }

    fn spearman(a: &[f32], b: &[f32]) -> f64 {
        let (ra, rb) = (ranks(a), ranks(b));
        let m = (a.len() as f64 - 1.0) / 2.0;
        let cov: f64 = ra.iter().zip(&rb).map(|(x, y)| (x - m) * (y - m)).sum();
        let var: f64 = ra.iter().map(|x| (x - m).powi(2)).sum();
        cov / var
    }

    /// The encoder without the crop's border: a local map padded by `m` pixels of real context on
    /// every side, encoded, its central features kept. What a bank crop approximates.
    fn with_context(model: &PfNet, map: &MapView, xs: &[f32], ys: &[f32], yaws: &[f32]) -> Vec<f32> {
        let (n, m) = (model.config.local_map.cells, 16);
        let (side, half, len) = (n + 2 * m, n / 2, model.map_feature_len());
        let (mut image, mut acts) = (vec![0.0; side * side], MapActivations::default());
        let mut out = vec![0.0; xs.len() * len];
        for (k, features) in out.chunks_exact_mut(len).enumerate() {
            let local = (&model.config.local_map, m);
            crop_with_margin(map, (xs[k], ys[k], yaws[k]), local, &mut image);
            let encoder = model.map_encoders().next().expect("the paper's map encoder");
            encoder.forward_sized(&model.params, &image, 1, (side, side), &mut acts);
            let full = side / 2;
            for (ch, plane) in features.chunks_exact_mut(half * half).enumerate() {
                for (i, row) in plane.chunks_exact_mut(half).enumerate() {
                    let at = (ch * full + m / 2 + i) * full + m / 2;
                    row.copy_from_slice(&acts.features[at..at + half]);
                }
            }
        }
        out
    }

    fn relative(got: &[f32], want: &[f32]) -> f64 {
        let norm = |v: &mut dyn Iterator<Item = f32>| v.map(|x| f64::from(x).powi(2)).sum::<f64>().sqrt();
        norm(&mut got.iter().zip(want).map(|(a, b)| a - b)) / norm(&mut want.iter().copied())
    }

    /// Cached against exact and against the border-free encoder, on random poses in a room; the
    /// log-likelihoods come from the joint stage with one random observation.
    fn agreement(config: PfNetConfig, specs: &[FeatureCacheSpec]) -> Vec<[f64; 4]> {
        let model = PfNet::new(config, 0).unwrap();
        let map = room(2);
        let view = map.view();
        let mut rng = Pcg64::seed_from_u64(5);
        let k = 96;
        let (mut xs, mut ys, mut yaws) = (vec![], vec![], vec![]);
        let (sin, cos) = map.origin.2.sin_cos();
        for _ in 0..k {
            let (gx, gy) = (rng.random_range(0.2..3.8f32), rng.random_range(0.2..2.8f32));
            xs.push(map.origin.0 + cos * gx - sin * gy);
            ys.push(map.origin.1 + sin * gx + cos * gy);
            yaws.push(rng.random_range(-4.0..4.0f32));
        }
        let obs: Vec<f32> = (0..model.obs_len()).map(|_| f32::from(rng.random_bool(0.2))).collect();
        let mut ws = Default::default();
        let mut obs_terms = vec![0.0; model.obs_term_len()];
        model.observation_terms(&obs, 1, &mut obs_terms, &mut ws);
        let owner = vec![0u32; k];
        let mut loglik = |features: &[f32]| {
            let mut out = vec![0.0; k];
            model.joint_log_likelihoods(features, &obs_terms, &owner, &mut out, &mut ws);
            out
        };
        let exact_features = exact(&model, &view, &xs, &ys, &yaws);
        let context_features = with_context(&model, &view, &xs, &ys, &yaws);
        let (exact_ll, context_ll) = (loglik(&exact_features), loglik(&context_features));
        println!(
            "{} network, {k} poses: border-free vs exact: relative feature error {:.3}, rank correlation {:.3}",
            if model.config == PfNetConfig::paper() { "paper" } else { "compact" },
            relative(&context_features, &exact_features),
            spearman(&context_ll, &exact_ll)
        );
        specs
            .iter()
            .map(|spec| {
                let bank = FeatureBank::build(&model, &view, spec);
                let got = cached(&bank, &model, &xs, &ys, &yaws);
                let ll = loglik(&got);
                let row = [
                    relative(&got, &exact_features),
                    spearman(&ll, &exact_ll),
                    relative(&got, &context_features),
                    spearman(&ll, &context_ll),
                ];
                println!(
                    "  N = {}, pool phases {}: cached vs exact {:.3} / {:.3}, cached vs border-free {:.3} / {:.3} \
                     (relative feature error / log-likelihood rank correlation), bank {:.2} MB",
                    spec.orientations,
                    spec.pool_phases,
                    row[0],
                    row[1],
                    row[2],
                    row[3],
                    bank.memory_bytes() as f64 / 1e6
                );
                row
            })
            .collect()
    }

    #[test]
    fn random_poses_are_close_to_exact() {
        // The particle at the local map's bottom centre (the paper) and at its centre.
        for centred in [false, true] {
            let local_map = LocalMapSpec { centred, ..LocalMapSpec::default() };
            let config = PfNetConfig { local_map, ..PfNetConfig::compact() };
            let [to_exact, rank_exact, to_context, rank_context] =
                agreement(config, &[FeatureCacheSpec::default()])[0];
            // The exact path's crop border (zero padding, seen by every feature: the receptive
            // field is 29 pixels) dominates the difference; without it the cache is much closer.
            let what = format!("centred: {centred}");
            assert!(to_exact < 0.6 && rank_exact > 0.5, "{what}: cached vs exact: {to_exact}, {rank_exact}");
            assert!(
                to_context < 0.3 && rank_context > 0.75,
                "{what}: cached vs border-free: {to_context}, {rank_context}"
            );
        }
    }

    #[test]
    #[ignore = "measurement: several orientation counts and the paper network (a few seconds)"]
    fn agreement_report() {
        let specs = |phases| {
            [8, 16, 32, 64].map(|orientations| FeatureCacheSpec { orientations, pool_phases: phases })
        };
        agreement(PfNetConfig::compact(), &[specs(false), specs(true)].concat());
        agreement(PfNetConfig::paper(), &[specs(false), specs(true)].concat());
    }

    #[test]
    fn building_is_deterministic_and_tiling_is_invisible() {
        // Both banks of a wide view with a map encoder of its own.
        let view = WideView { map_cell_m: 0.2, grid_extent_m: 10.0, own_map_encoder: true };
        let model = PfNet::new(PfNetConfig::compact().with_wide_view(Some(view)), 7).unwrap();
        let map = room(3);
        let spec = FeatureCacheSpec { orientations: 4, pool_phases: true };
        let a = FeatureBank::build(&model, &map.view(), &spec);
        let b = FeatureBank::build(&model, &map.view(), &spec);
        let tiny = FeatureBank::build_tiled(&model, &map.view(), &spec, 5);
        let orientations = |bank: &FeatureBank| -> Vec<Orientation> {
            bank.encoders.iter().flat_map(|e| e.orientations.clone()).collect()
        };
        assert_eq!(orientations(&a).len(), 2 * 4, "each encoder's bank");
        for ((a, b), t) in orientations(&a).iter().zip(&orientations(&b)).zip(&orientations(&tiny)) {
            assert_eq!(a.features, b.features, "two builds differ");
            let worst = a.features.iter().zip(&t.features).fold(0.0f32, |m, (x, y)| m.max((x - y).abs()));
            assert!(worst < 1e-4, "tiles of 5 cells differ from tiles of {TILE} by {worst}");
        }
        // Far off the map and NaN poses still give finite features.
        let out = cached(&a, &model, &[-50.0, f32::NAN], &[3.0, 0.0], &[0.3, 1.0]);
        assert!(out.iter().all(|v| v.is_finite()));
    }
}
