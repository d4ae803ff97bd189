//! A trained agent's networks given more belief channels (past steps' crops, further modes):
//! the new channels enter the first convolution with zero weight, so the widened networks act
//! exactly as the trained ones until training teaches them to read the new input.

use crate::nn::conv::widen_input_channels;
use crate::nn::sac::config::SacNetConfig;
use crate::nn::sac::networks::SacNetworks;

/// The first convolution of the belief encoder, the one tensor whose shape the channels change.
const BELIEF_INPUT_KERNEL: &str = "belief/conv0/kernel";

impl SacNetworks {
    /// These networks with `config.belief_channels` belief input channels, the first ones
    /// carrying the trained weights; `Err` says why when `config` differs in anything else or
    /// has fewer channels.
    pub fn widened(&self, config: &SacNetConfig) -> Result<Self, String> {
        let old = self.config.belief_channels;
        let same_otherwise = SacNetConfig { belief_channels: old, ..config.clone() } == self.config;
        if !same_otherwise || config.belief_channels < old {
            return Err(format!(
                "only the belief channels may grow (from {old}); the networks are {:?}, expected {config:?}",
                self.config
            ));
        }
        let mut wide = Self::zeros(config);
        for (id, spec) in self.params.specs() {
            let to = wide.params.find(&spec.name).expect("the same layout but for the channels");
            let (from, into) = (self.params.get(id), wide.params.get_mut(to));
            if spec.name == BELIEF_INPUT_KERNEL {
                widen_input_channels(from, into, spec.shape[0], spec.shape[2] * spec.shape[3], 0);
            } else {
                into.copy_from_slice(from);
            }
        }
        Ok(wide)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::nn::sac::networks::{Observations, PolicyWorkspace};

    fn tiny() -> SacNetConfig {
        SacNetConfig {
            conv_channels: vec![4, 4],
            encoder_fc: 8,
            mlp_width: 8,
            belief_cells: 9,
            belief_channels: 4,
            grid_cells: 9,
            depth_columns: 0,
        }
    }

    #[test]
    fn widened_networks_act_as_the_trained_ones_whatever_the_new_channels_hold() {
        let nets = SacNetworks::new(&tiny(), 7);
        let wide = nets.widened(&SacNetConfig { belief_channels: 8, ..tiny() }).expect("channels may grow");
        let area = 81;
        let belief: Vec<f32> = (0..4 * area).map(|i| (i % 13) as f32 / 13.0).collect();
        let past: Vec<f32> = (0..4 * area).map(|i| (i % 5) as f32 / 5.0).collect();
        let grid: Vec<f32> = (0..area).map(|i| (i % 3) as f32 / 3.0).collect();
        let state = [0.3, -0.2, 0.0, 0.5];
        let heads = |nets: &SacNetworks, belief: &[f32]| {
            let obs = Observations { n: 1, belief, grid: &grid, state: &state };
            nets.policy_heads(&obs, &mut PolicyWorkspace::default()).to_vec()
        };
        let stacked = [belief.clone(), past].concat();
        assert_eq!(heads(&wide, &stacked), heads(&nets, &belief), "the new channels weigh nothing yet");
        let err = wide.widened(&tiny()).unwrap_err();
        assert!(err.contains("only the belief channels may grow"), "{err}");
        let err = nets.widened(&SacNetConfig { mlp_width: 16, ..tiny() }).unwrap_err();
        assert!(err.contains("expected"), "{err}");
    }
}
