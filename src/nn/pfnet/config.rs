//! PF-net's architecture as data: the paper configuration and a compact one for CPU training.
//! The config travels inside every checkpoint, so a file always says which network it holds.

use super::observation::Observation;
use super::spatial_transformer::LocalMapSpec;
use serde::{Deserialize, Serialize};

/// Largest side of a particle's local map, cells (paper: 28): the feature cache crops at most
/// (64 / 2)² feature cells per particle.
pub const MAX_LOCAL_MAP_CELLS: usize = 64;

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
        branches.iter().map(|b| b.filters).sum()
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
    /// Channels of a particle's local map (1: free space).
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
        Self { observation, obs_channels: observation.channels(), ..self }
    }

    /// A named configuration (`paper` or `compact`).
    pub fn named(name: &str) -> Option<Self> {
        match name {
            "paper" => Some(Self::paper()),
            "compact" => Some(Self::compact()),
            _ => None,
        }
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
        if self.map_channels == 0 {
            return Err("map_channels: expected at least 1".into());
        }
        if self.obs_channels != self.observation.channels() {
            return Err(format!(
                "obs_channels: expected {} for observation `{}`, found {}",
                self.observation.channels(),
                self.observation.name(),
                self.obs_channels
            ));
        }
        if self.local_map.cells * 2 != self.obs_cells
            || !self.local_map.cells.is_multiple_of(4)
            || self.local_map.cells > MAX_LOCAL_MAP_CELLS
        {
            return Err(format!(
                "local_map.cells, obs_cells: expected a multiple of 4 up to {MAX_LOCAL_MAP_CELLS} and twice \
                 it (the encoders meet at a quarter of the observation), found {} and {}",
                self.local_map.cells, self.obs_cells
            ));
        }
        LocalMapSpec::check_cell_m("local_map.cell_m", self.local_map.cell_m)?;
        if self.joint_filters == 0 || self.layer_norm_eps <= 0.0 {
            return Err("joint_filters, layer_norm_eps: expected ≥ 1 and > 0".into());
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn observation_channels_are_checked_by_name() {
        let two = PfNetConfig::compact().observing(Observation::GridAndDepth);
        assert_eq!((two.obs_channels, two.check()), (2, Ok(())));
        let err = PfNetConfig { obs_channels: 1, ..two }.check().unwrap_err();
        assert_eq!(err, "obs_channels: expected 2 for observation `grid_and_depth`, found 1");
    }

    #[test]
    fn local_map_sides_are_checked_by_name() {
        assert!(PfNetConfig::paper().check().is_ok() && PfNetConfig::compact().check().is_ok());
        for (cells, obs_cells) in [(30, 60), (28, 50), (MAX_LOCAL_MAP_CELLS + 4, 2 * MAX_LOCAL_MAP_CELLS + 8)]
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
