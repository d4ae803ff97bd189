//! PF-net's architecture as data: the paper configuration and a compact one for CPU training.
//! The config travels inside every checkpoint, so a file always says which network it holds.

use super::observation::Observation;
use super::spatial_transformer::LocalMapSpec;
use serde::{Deserialize, Serialize};

/// Largest side of a particle's local map, cells (paper: 28): the feature cache crops at most
/// (64 / 2)² feature cells per particle.
pub const MAX_LOCAL_MAP_CELLS: usize = 64;

/// Smallest side of a particle's local map, cells: the joint stage's 3 × 3 locally-connected
/// layer, unpadded, needs its input (half the side) to be at least 4 cells for the 2 × 2 pool after it.
pub const MIN_LOCAL_MAP_CELLS: usize = 8;

/// One of a stage's parallel convolutions ('same' padding, stride 1), concatenated along channels.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct ConvBranch {
    pub filters: usize,
    pub kernel: usize,
    pub dilation: usize,
}

impl ConvBranch {
    const fn new(filters: usize, kernel: usize, dilation: usize) -> Self {
        Self { filters, kernel, dilation }
    }

    /// Channels of a stage's concatenated output.
    pub fn channels_of(branches: &[ConvBranch]) -> usize {
        branches.iter().fold(0, |sum, b| sum.saturating_add(b.filters))
    }

    /// The reference's layer name: `{prefix}_c{kernel}` plus `d{dilation}` when dilated.
    pub fn name(&self, prefix: &str) -> String {
        match self.dilation {
            1 => format!("{prefix}_c{}", self.kernel),
            d => format!("{prefix}_c{}d{d}", self.kernel),
        }
    }
}

/// The observation model of PF-net (Karkus et al. 2018) as used by APFN.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PfNetConfig {
    /// Local maps a particle sees, stacked as channels (1: free space; 2 with a wide view).
    pub map_channels: usize,
    /// What the observation image holds (the paper: the LiDAR occupancy grid).
    pub observation: Observation,
    /// Channels of the observation image: the observation's.
    pub obs_channels: usize,
    /// The local map each particle sees (paper: 28 × 28 cells of 0.1 m).
    pub local_map: LocalMapSpec,
    /// Side of the observation image, cells (paper: 56).
    pub obs_cells: usize,
    /// Map encoder, first stage: parallel convs → LayerNorm → ReLU → max-pool.
    pub map_stage1: Vec<ConvBranch>,
    /// Map encoder, second stage: parallel convs → LayerNorm → ReLU.
    pub map_stage2: Vec<ConvBranch>,
    /// Observation encoder, first stage: parallel convs → max-pool → LayerNorm → ReLU.
    pub obs_stage1: Vec<ConvBranch>,
    /// Observation encoder, second stage: convs → max-pool → LayerNorm → ReLU.
    pub obs_stage2: Vec<ConvBranch>,
    /// Filters of each of the joint stage's two locally-connected layers (3×3 and 5×5).
    pub joint_filters: usize,
    /// LayerNorm epsilon (Keras: 1e-3).
    pub layer_norm_eps: f32,
    /// Beyond the paper: a zoomed-out second view, one more channel on each side (absent: the
    /// paper's one view).
    pub wide_view: Option<WideView>,
    /// Beyond the paper: every map encoder reads the scan laid on its local map's pixels beside
    /// the map (absent: the paper's map encoder, which sees the map alone).
    pub scan_on_map: Option<ScanOnMap>,
    /// Beyond the paper: the map encoders' first convolutions read the map (and the laid scan)
    /// beyond the local map's edge, as far as they reach (`map_margin`), where the paper's see
    /// zero padding; a particle's input is that much wider on every side, its features still the
    /// local map's. The feature cache's banks see the map there too, so a first-stage bank holds
    /// what the exact path computes, up to the heading residual.
    pub map_context: bool,
}

/// The scan laid on a particle's local map (`scan_on_map.rs`): each map encoder reads, as a
/// second input channel, the LiDAR grid resampled to its local map's pixels. The grid is the
/// robot's and the local map the particle's, both in their own frame, so the two images agree
/// pixel for pixel where the particle stands on the truth, and a first convolution can compare
/// them where PF-net's encoders only meet after two stages and a pool. The price: a particle's
/// map features then depend on the scan, so no feature bank holds them; the feature cache holds
/// the first convolution's response to the map instead (`feature_cache.rs`) — or, with an
/// encoder of its own for the laid scan (`own_encoder`), the map features.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ScanOnMap {
    /// Side of the observation's LiDAR grid, metres: `local_grid`'s `extent_m` (paper: 5 m). A
    /// wide view's grid spans its own `grid_extent_m`.
    pub grid_extent_m: f32,
    /// The laid scan through an encoder of its own (one per view, a map encoder's layers), whose
    /// features join the observation's before the joint stage, aligned with the map features
    /// pixel for pixel, instead of as a second input channel of the map encoders. The scan is
    /// the same on every particle's pixels, so it is encoded once per step, and a particle's map
    /// features are the map's alone: the feature cache holds them. Measured: it trains as low as
    /// the scan on the map encoders' input but its likelihood peaks as far from the truth as the
    /// paper layout's (docs/pfnet.md). Absent: false.
    #[serde(default)]
    pub own_encoder: bool,
}

/// A second, wider view for open spaces: the particle's local map cropped again with wider
/// pixels (its last map channel) and the same scan rasterised over a wider window (the
/// observation's last channel, `local_grid`'s `wide_extent_m`). The paper's grid spans 5 m, so in
/// a hall whose walls and pillars lie farther away the network sees nothing to match; even MCL's
/// exact sensor model, given only the beams ending in that window, tracks 3–4 times worse there
/// (docs/pfnet.md, a wide view for the halls).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct WideView {
    /// Side of a pixel of the wide local map, metres (same pixel count as `local_map`).
    pub map_cell_m: f32,
    /// Side of the wide LiDAR window, metres (same cell count as the observation).
    pub grid_extent_m: f32,
    /// The wide local map through a map encoder of its own, whose features join the paper
    /// encoder's before the joint stage, instead of as a second input channel of the paper's.
    /// Each encoder then sees one map at one scale, translation-equivariant, so the feature cache
    /// holds both; mixed in one encoder the two scales shift differently and it holds neither.
    #[serde(default)]
    pub own_map_encoder: bool,
}

impl Default for PfNetConfig {
    fn default() -> Self {
        Self::paper()
    }
}

impl PfNetConfig {
    /// The paper's network: 1,017,497 parameters for one input channel each.
    pub fn paper() -> Self {
        Self {
            map_channels: 1,
            observation: Observation::Grid,
            obs_channels: 1,
            local_map: LocalMapSpec::default(),
            obs_cells: 56,
            map_stage1: vec![
                ConvBranch::new(24, 3, 1),
                ConvBranch::new(16, 5, 1),
                ConvBranch::new(8, 7, 1),
                ConvBranch::new(8, 7, 2),
                ConvBranch::new(8, 7, 3),
            ],
            map_stage2: vec![ConvBranch::new(4, 3, 1), ConvBranch::new(4, 5, 1)],
            obs_stage1: vec![
                ConvBranch::new(128, 3, 1),
                ConvBranch::new(128, 5, 1),
                ConvBranch::new(64, 5, 2),
                ConvBranch::new(64, 5, 4),
            ],
            obs_stage2: vec![ConvBranch::new(16, 3, 1)],
            joint_filters: 8,
            layer_norm_eps: 1e-3,
            wide_view: None,
            scan_on_map: None,
            map_context: false,
        }
    }

    /// The same structure, narrower, for training on a CPU: a quarter of the encoders'
    /// first-stage channels (the observation encoder's 384 channels at 56 × 56 dominate the paper
    /// network's training cost, the map encoder's first stage its per-particle cost) and half the
    /// features where the encoders meet (the locally-connected layers hold 93 % of the paper's
    /// weights), so a checkpoint stays under 2 MB.
    pub fn compact() -> Self {
        Self {
            map_stage2: vec![ConvBranch::new(2, 3, 1), ConvBranch::new(2, 5, 1)],
            obs_stage2: vec![ConvBranch::new(8, 3, 1)],
            map_stage1: vec![
                ConvBranch::new(8, 3, 1),
                ConvBranch::new(4, 5, 1),
                ConvBranch::new(4, 7, 1),
                ConvBranch::new(4, 7, 2),
                ConvBranch::new(4, 7, 3),
            ],
            obs_stage1: vec![
                ConvBranch::new(32, 3, 1),
                ConvBranch::new(32, 5, 1),
                ConvBranch::new(16, 5, 2),
                ConvBranch::new(16, 5, 4),
            ],
            ..Self::paper()
        }
    }

    /// This configuration observing `observation` instead.
    pub fn observing(self, observation: Observation) -> Self {
        let view = self.wide_view;
        Self { observation, ..self }.with_wide_view(view)
    }

    /// This configuration with `wide_view` (or without one): the channel counts follow.
    pub fn with_wide_view(self, wide_view: Option<WideView>) -> Self {
        let extra = usize::from(wide_view.is_some());
        Self { wide_view, map_channels: 1 + extra, obs_channels: self.observation.channels() + extra, ..self }
    }

    /// Whether the wide local map has a map encoder of its own (`WideView::own_map_encoder`).
    pub fn wide_map_encoder(&self) -> bool {
        self.wide_view.is_some_and(|view| view.own_map_encoder)
    }

    /// Input channels of each map encoder: every local map into the paper's, or one each; with
    /// `scan_on_map`, each followed by its scan.
    pub fn map_encoder_channels(&self) -> usize {
        let maps = if self.wide_map_encoder() { 1 } else { self.map_channels };
        maps * self.channels_per_local_map()
    }

    /// Channels a particle's input holds per local map: the map, then its scan with `scan_on_map`
    /// (unless the scan has encoders of its own).
    pub fn channels_per_local_map(&self) -> usize {
        1 + usize::from(self.scan_on_map.is_some_and(|scan| !scan.own_encoder))
    }

    /// Pixels of map a particle's input holds beyond its local map on every side: the first
    /// stage's reach, ((kernel − 1) · dilation) / 2 at most, with `map_context`; else none.
    pub fn map_margin(&self) -> usize {
        match self.map_context {
            true => self.map_stage1.iter().map(|b| (b.kernel - 1) * b.dilation / 2).max().unwrap_or(0),
            false => 0,
        }
    }

    /// Side of each image of a particle's input: the local map's and its margin on both sides.
    pub fn map_input_cells(&self) -> usize {
        self.local_map.cells + 2 * self.map_margin()
    }

    /// Whether the laid scan has encoders of its own (`ScanOnMap::own_encoder`).
    pub fn scan_encoders(&self) -> bool {
        self.scan_on_map.is_some_and(|scan| scan.own_encoder)
    }

    /// The local maps a particle sees, one per map channel: the paper's, then the wide view's.
    pub fn local_maps(&self) -> Vec<LocalMapSpec> {
        let wide = self.wide_view.map(|view| LocalMapSpec { cell_m: view.map_cell_m, ..self.local_map });
        std::iter::once(self.local_map).chain(wide).collect()
    }

    /// A named configuration (`paper` or `compact`).
    pub fn named(name: &str) -> Option<Self> {
        match name {
            "paper" => Some(Self::paper()),
            "compact" => Some(Self::compact()),
            _ => None,
        }
    }

    /// One observation image `[obs_channels][obs_cells²]` split into the grid's channel, the
    /// depth image's and the wide grid's, each present when observed.
    #[allow(clippy::type_complexity)]
    pub fn split_observation<'a>(
        &self,
        image: &'a mut [f32],
    ) -> (Option<&'a mut [f32]>, Option<&'a mut [f32]>, Option<&'a mut [f32]>) {
        let (sensor, wide) = image.split_at_mut(self.observation.channels() * self.obs_cells.pow(2));
        let (grid, depth) = self.observation.split(sensor);
        (grid, depth, self.wide_view.map(|_| wide))
    }

    /// The weights of the network's convolution and locally-connected kernels, counted without
    /// building it. Every other tensor (biases, LayerNorm, the dense head) is smaller than a kernel
    /// before it, so the network holds at most a few times this many values: a checkpoint whose
    /// configuration asks for more than its file holds is refused before anything is allocated.
    /// Saturates instead of overflowing on absurd sizes.
    pub fn kernel_weights(&self) -> u64 {
        let n = |v: usize| v as u64;
        let stage = |c_in: usize, branches: &[ConvBranch]| {
            branches.iter().fold(0u64, |sum, b| {
                sum.saturating_add(
                    n(b.filters).saturating_mul(n(c_in)).saturating_mul(n(b.kernel).saturating_pow(2)),
                )
            })
        };
        let encoder = |c_in: usize, first: &[ConvBranch], second: &[ConvBranch]| {
            stage(c_in, first).saturating_add(stage(ConvBranch::channels_of(first), second))
        };
        let map_encoders = 1 + u64::from(self.wide_map_encoder());
        let map = encoder(self.map_encoder_channels(), &self.map_stage1, &self.map_stage2);
        let obs = encoder(self.obs_channels, &self.obs_stage1, &self.obs_stage2);
        // Both locally-connected layers (3 × 3 unpadded, 5 × 5 padded by 1) give side − 2 outputs.
        let joint_in = map_encoders
            .saturating_mul(n(ConvBranch::channels_of(&self.map_stage2)))
            .saturating_add(n(ConvBranch::channels_of(&self.obs_stage2)));
        let positions = n((self.local_map.cells / 2).saturating_sub(2)).saturating_pow(2);
        let joint =
            positions.saturating_mul(n(self.joint_filters)).saturating_mul(joint_in.saturating_mul(9 + 25));
        map_encoders.saturating_mul(map).saturating_add(obs).saturating_add(joint)
    }

    /// `Err("field: expected …")` when the configuration cannot build a network.
    pub fn check(&self) -> Result<(), String> {
        let stages = [
            ("map_stage1", &self.map_stage1),
            ("map_stage2", &self.map_stage2),
            ("obs_stage1", &self.obs_stage1),
            ("obs_stage2", &self.obs_stage2),
        ];
        for (field, branches) in stages {
            if branches.is_empty() {
                return Err(format!("{field}: expected at least one convolution"));
            }
            if branches.iter().any(|b| b.filters == 0 || b.kernel == 0 || b.dilation == 0) {
                return Err(format!("{field}: expected filters, kernel and dilation ≥ 1"));
            }
        }
        let extra = usize::from(self.wide_view.is_some());
        if self.map_channels != 1 + extra {
            return Err(format!(
                "map_channels: expected {} ({} wide view), found {}",
                1 + extra,
                if extra == 1 { "with a" } else { "without" },
                self.map_channels
            ));
        }
        if self.obs_channels != self.observation.channels() + extra {
            return Err(format!(
                "obs_channels: expected {} for observation `{}`{}, found {}",
                self.observation.channels() + extra,
                self.observation.name(),
                if extra == 1 { " and a wide view" } else { "" },
                self.obs_channels
            ));
        }
        if let Some(view) = self.wide_view {
            LocalMapSpec::check_cell_m("wide_view.map_cell_m", view.map_cell_m)?;
            if !(view.grid_extent_m.is_finite() && view.grid_extent_m > 0.0) {
                return Err(format!("wide_view.grid_extent_m: expected > 0 m, found {}", view.grid_extent_m));
            }
        }
        if self.local_map.cells * 2 != self.obs_cells
            || !self.local_map.cells.is_multiple_of(4)
            || !(MIN_LOCAL_MAP_CELLS..=MAX_LOCAL_MAP_CELLS).contains(&self.local_map.cells)
        {
            return Err(format!(
                "local_map.cells, obs_cells: expected a multiple of 4 from {MIN_LOCAL_MAP_CELLS} to \
                 {MAX_LOCAL_MAP_CELLS} and twice it (the encoders meet at a quarter of the observation), \
                 found {} and {}",
                self.local_map.cells, self.obs_cells
            ));
        }
        LocalMapSpec::check_cell_m("local_map.cell_m", self.local_map.cell_m)?;
        if let Some(scan) = self.scan_on_map {
            if !(scan.grid_extent_m.is_finite() && scan.grid_extent_m > 0.0) {
                return Err(format!(
                    "scan_on_map.grid_extent_m: expected > 0 m, found {}",
                    scan.grid_extent_m
                ));
            }
            if !self.observation.uses_grid() || self.wide_view.is_some_and(|view| !view.own_map_encoder) {
                return Err(format!(
                    "scan_on_map: expected a network observing the LiDAR grid whose views have map \
                     encoders of their own, found observation `{}`{}",
                    self.observation.name(),
                    if self.wide_view.is_some() {
                        " and a wide view through the paper's encoder"
                    } else {
                        ""
                    }
                ));
            }
        }
        if self.map_context && (self.scan_encoders() || self.map_stage1.iter().any(|b| b.kernel % 2 == 0)) {
            return Err("map_context: expected odd first-stage kernels (the margin is a whole reach on \
                        each side) and no encoders of the scan's own"
                .into());
        }
        if self.joint_filters == 0 || !(self.layer_norm_eps > 0.0 && self.layer_norm_eps.is_finite()) {
            return Err(format!(
                "joint_filters, layer_norm_eps: expected ≥ 1 and a finite number > 0, found {} and {}",
                self.joint_filters, self.layer_norm_eps
            ));
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::nn::pfnet::PfNet;

    #[test]
    fn observation_channels_are_checked_by_name() {
        let two = PfNetConfig::compact().observing(Observation::GridAndDepth);
        assert_eq!((two.obs_channels, two.check()), (2, Ok(())));
        let err = PfNetConfig { obs_channels: 1, ..two }.check().unwrap_err();
        assert_eq!(err, "obs_channels: expected 2 for observation `grid_and_depth`, found 1");
    }

    #[test]
    fn a_wide_view_adds_a_channel_on_each_side() {
        let view = WideView { map_cell_m: 0.2, grid_extent_m: 10.0, own_map_encoder: false };
        let wide = PfNetConfig::compact().observing(Observation::GridAndDepth).with_wide_view(Some(view));
        assert_eq!((wide.map_channels, wide.obs_channels, wide.check()), (2, 3, Ok(())));
        assert_eq!(wide.local_maps().iter().map(|m| m.cell_m).collect::<Vec<_>>(), [0.1, 0.2]);
        assert_eq!(wide.clone().observing(Observation::Depth).obs_channels, 2, "the view survives");
        assert_eq!(
            wide.clone().with_wide_view(None),
            PfNetConfig::compact().observing(Observation::GridAndDepth)
        );
        let err = PfNetConfig { map_channels: 1, ..wide.clone() }.check().unwrap_err();
        assert_eq!(err, "map_channels: expected 2 (with a wide view), found 1");
        let err = PfNetConfig { obs_channels: 2, ..wide.clone() }.check().unwrap_err();
        assert_eq!(err, "obs_channels: expected 3 for observation `grid_and_depth` and a wide view, found 2");
        assert_eq!(
            (wide.map_encoder_channels(), wide.wide_map_encoder()),
            (2, false),
            "one encoder reads both"
        );
        let own = WideView { own_map_encoder: true, ..view };
        let towers = PfNetConfig::compact().with_wide_view(Some(own));
        assert_eq!(
            (towers.map_channels, towers.map_encoder_channels(), towers.wide_map_encoder()),
            (2, 1, true)
        );
        let written: WideView = ron::from_str("(map_cell_m: 0.2, grid_extent_m: 10.0)").unwrap();
        assert_eq!(written, view, "views written before `own_map_encoder` share one encoder");
        let flat = WideView { grid_extent_m: 0.0, ..view };
        let err = wide.with_wide_view(Some(flat)).check().unwrap_err();
        assert_eq!(err, "wide_view.grid_extent_m: expected > 0 m, found 0");
    }

    #[test]
    fn kernel_weights_bound_the_network_from_below_within_a_small_factor() {
        let view = WideView { map_cell_m: 0.2, grid_extent_m: 10.0, own_map_encoder: false };
        let configs = [
            PfNetConfig::paper(),
            PfNetConfig::compact(),
            PfNetConfig::compact().observing(Observation::GridAndDepth).with_wide_view(Some(view)),
            PfNetConfig::compact().with_wide_view(Some(WideView { own_map_encoder: true, ..view })),
        ];
        for config in configs {
            let (kernels, total) =
                (config.kernel_weights(), PfNet::new(config.clone(), 0).unwrap().params.len() as u64);
            assert!(
                kernels <= total && total <= 4 * kernels,
                "{kernels} kernel weights of {total}: {config:?}"
            );
        }
        let absurd = PfNetConfig { joint_filters: usize::MAX, ..PfNetConfig::compact() };
        assert_eq!(absurd.kernel_weights(), u64::MAX, "saturates");
    }

    #[test]
    fn a_nan_layer_norm_epsilon_is_refused_by_name() {
        let nan = PfNetConfig { layer_norm_eps: f32::NAN, ..PfNetConfig::compact() };
        assert_eq!(
            nan.check().unwrap_err(),
            "joint_filters, layer_norm_eps: expected ≥ 1 and a finite number > 0, found 8 and NaN"
        );
    }

    #[test]
    fn map_context_reaches_as_far_as_the_first_stage_and_needs_odd_kernels() {
        let context = PfNetConfig { map_context: true, ..PfNetConfig::paper() };
        assert_eq!((context.map_margin(), context.map_input_cells()), (9, 46), "7 × 7 dilated 3");
        assert_eq!(PfNetConfig::paper().map_input_cells(), 28, "no margin without it");
        let mut even = context.clone();
        even.map_stage1[0].kernel = 4;
        assert!(even.check().unwrap_err().starts_with("map_context: expected odd first-stage kernels"));
        let own = Some(ScanOnMap { grid_extent_m: 5.0, own_encoder: true });
        assert!(PfNetConfig { scan_on_map: own, ..context }.check().unwrap_err().starts_with("map_context:"));
    }

    #[test]
    fn local_map_sides_are_checked_by_name() {
        assert!(PfNetConfig::paper().check().is_ok() && PfNetConfig::compact().check().is_ok());
        for (cells, obs_cells) in
            [(30, 60), (28, 50), (4, 8), (MAX_LOCAL_MAP_CELLS + 4, 2 * MAX_LOCAL_MAP_CELLS + 8)]
        {
            let mut config = PfNetConfig::compact();
            (config.local_map.cells, config.obs_cells) = (cells, obs_cells);
            let err = config.check().unwrap_err();
            assert!(err.starts_with("local_map.cells, obs_cells: expected"), "unhelpful error: {err}");
            assert!(err.contains(&format!("found {cells} and {obs_cells}")), "{err}");
        }
        for cell_m in [0.0, f32::NAN, 2.0] {
            let mut config = PfNetConfig::compact();
            config.local_map.cell_m = cell_m;
            assert_eq!(
                config.check().unwrap_err(),
                format!("local_map.cell_m: expected 0.01 to 1 m, found {cell_m}")
            );
        }
    }
}
