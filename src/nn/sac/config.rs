//! The shapes of the SAC networks: the APFN authors' run and a compact variant for CPUs.

use serde::{Deserialize, Serialize};

/// Robot state appended to the image features: v, ω, the collision flag, the fraction of the
/// episode left (the depth strip, when the network reads one, follows it).
pub const STATE_LEN: usize = 4;
/// Normalised (linear, angular) velocity.
pub const ACTION_LEN: usize = 2;

/// Every image input has its own CNN of 3×3 stride-2 'valid' convolutions with ReLU, closed by a
/// dense layer with ReLU; the features of both encoders and the robot state feed the actor and
/// the twin critics, MLPs of two hidden layers.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SacNetConfig {
    /// Output channels of each encoder's convolutions, in order.
    pub conv_channels: Vec<usize>,
    /// Width of the dense layer closing each encoder.
    pub encoder_fc: usize,
    /// Width of the hidden layers of the actor and critic MLPs.
    pub mlp_width: usize,
    /// Side of the belief crop, cells, and its channels (4 per crop).
    pub belief_cells: usize,
    pub belief_channels: usize,
    /// Side of the LiDAR occupancy grid, cells.
    pub grid_cells: usize,
    /// Columns of the depth strip appended to the robot state, each as depth / `max_m` (the
    /// `depth` step's columns); 0: no depth input, as the paper's LiDAR agent.
    #[serde(default)]
    pub depth_columns: usize,
}

impl SacNetConfig {
    /// The authors' run: (32, 64, 64, 64) channels, FC 512, MLP 512 × 2.
    pub fn paper() -> Self {
        Self {
            conv_channels: vec![32, 64, 64, 64],
            encoder_fc: 512,
            mlp_width: 512,
            belief_cells: 50,
            belief_channels: 4,
            grid_cells: 56,
            depth_columns: 0,
        }
    }

    /// A quarter of the paper's encoder width and half its MLP (the JAX peer's compact variant):
    /// ≈ 6× fewer FLOPs per update on the same inputs.
    pub fn compact() -> Self {
        Self { conv_channels: vec![16, 32, 32, 32], encoder_fc: 128, mlp_width: 256, ..Self::paper() }
    }

    /// Length of the vector input: the robot state and the depth strip.
    pub fn state_len(&self) -> usize {
        STATE_LEN + self.depth_columns
    }

    /// Length of the actor's and critics' input before the action: both encoders and the state.
    pub fn feature_len(&self) -> usize {
        2 * self.encoder_fc + self.state_len()
    }

    /// Side of an encoder's last feature map for an input of side `side`; `None` when the
    /// stride-2 3×3 convolutions run out of pixels.
    fn encoded_side(&self, side: usize) -> Option<usize> {
        self.conv_channels.iter().try_fold(side, |s, _| (s >= 3).then(|| (s - 3) / 2 + 1))
    }

    /// The weights of every convolution and dense layer, counted without building the networks
    /// (each bias is smaller than its weights, so the networks hold less than twice this): a
    /// policy file whose configuration asks for more than the file holds is refused before
    /// anything is allocated. Saturates instead of overflowing on absurd sizes.
    pub fn weights(&self) -> u64 {
        let n = |v: usize| v as u64;
        let mul = |a: u64, b: u64| a.saturating_mul(b);
        let encoder = |c_in: usize, side: usize| {
            let (convs, last) = self.conv_channels.iter().fold((0u64, n(c_in)), |(sum, c_prev), &c| {
                (sum.saturating_add(mul(mul(c_prev, n(c)), 9)), n(c))
            });
            let flat = mul(last, n(self.encoded_side(side).unwrap_or(0)).saturating_pow(2));
            convs.saturating_add(mul(flat, n(self.encoder_fc)))
        };
        let (f, w) =
            (n(self.encoder_fc).saturating_mul(2).saturating_add(n(self.state_len())), n(self.mlp_width));
        // Two critics (features and action in, one value out) and the actor (mean and log σ out).
        let mlp = |inputs: u64, outputs: u64| mul(w, inputs.saturating_add(w).saturating_add(outputs));
        [
            encoder(self.belief_channels, self.belief_cells),
            encoder(1, self.grid_cells),
            mul(2, mlp(f.saturating_add(n(ACTION_LEN)), 1)),
            mlp(f, n(2 * ACTION_LEN)),
        ]
        .into_iter()
        .fold(0, u64::saturating_add)
    }

    /// `Err("field: expected …")` when the shapes cannot build a network.
    pub fn check(&self) -> Result<(), String> {
        let fits = |side: usize| self.encoded_side(side).is_some_and(|s| s >= 1);
        let positive =
            |v: usize, field: &str| if v > 0 { Ok(()) } else { Err(format!("{field}: expected ≥ 1")) };
        positive(self.conv_channels.len(), "conv_channels")?;
        if self.conv_channels.contains(&0) {
            return Err("conv_channels: expected every layer to have ≥ 1 channel".into());
        }
        positive(self.encoder_fc, "encoder_fc")?;
        positive(self.mlp_width, "mlp_width")?;
        positive(self.belief_channels, "belief_channels")?;
        if self.depth_columns > 0 {
            crate::limits::DEPTH_COLUMNS.check("depth_columns", self.depth_columns)?;
        }
        for (side, field) in [(self.belief_cells, "belief_cells"), (self.grid_cells, "grid_cells")] {
            if !fits(side) {
                return Err(format!(
                    "{field}: expected a side large enough for {} stride-2 3×3 convolutions, got {side}",
                    self.conv_channels.len()
                ));
            }
        }
        Ok(())
    }
}

#[cfg(test)]
impl SacNetConfig {
    /// Networks small enough for a unit test to run them many times.
    pub fn tiny() -> Self {
        Self {
            conv_channels: vec![2],
            encoder_fc: 4,
            mlp_width: 8,
            belief_cells: 5,
            belief_channels: 4,
            grid_cells: 5,
            depth_columns: 0,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::nn::sac::SacNetworks;

    #[test]
    fn weights_count_every_weight_and_bound_the_networks() {
        let tiny = SacNetConfig {
            conv_channels: vec![2],
            belief_cells: 3,
            grid_cells: 5,
            ..SacNetConfig::compact()
        };
        for config in [SacNetConfig::paper(), SacNetConfig::compact(), tiny] {
            let (weights, total) = (config.weights(), SacNetworks::zeros(&config).params.len() as u64);
            assert!(weights < total && total < 2 * weights, "{weights} weights of {total}: {config:?}");
        }
        let absurd = SacNetConfig { mlp_width: usize::MAX, ..SacNetConfig::compact() };
        assert_eq!(absurd.weights(), u64::MAX, "saturates");
    }

    #[test]
    fn configs_check_and_bad_shapes_name_the_field() {
        assert_eq!(SacNetConfig::paper().check(), Ok(()));
        assert_eq!(SacNetConfig::compact().check(), Ok(()));
        let tiny = SacNetConfig { grid_cells: 8, ..SacNetConfig::paper() };
        assert!(tiny.check().unwrap_err().starts_with("grid_cells:"), "{:?}", tiny.check());
        let empty = SacNetConfig { conv_channels: vec![], ..SacNetConfig::paper() };
        assert!(empty.check().unwrap_err().starts_with("conv_channels:"));
    }

    #[test]
    fn a_config_written_before_depth_input_reads_as_lidar_only() {
        let mut json = serde_json::to_value(SacNetConfig::compact()).expect("serialise");
        json.as_object_mut().expect("an object").remove("depth_columns");
        let read: SacNetConfig = serde_json::from_value(json).expect("the field is optional");
        assert_eq!(read, SacNetConfig::compact());
        let depth = SacNetConfig { depth_columns: 56, ..SacNetConfig::compact() };
        assert_eq!(
            depth.feature_len(),
            SacNetConfig::compact().feature_len() + 56,
            "depth follows the state"
        );
    }
}
