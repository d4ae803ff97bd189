//! The cached path of a network laying the scan on its local maps (`ScanOnMap` without encoders
//! of its own): the feature cache's banks hold each map encoder's first-stage response to the map
//! (`feature_cache.rs`), the scan's share is computed once per observation, and each particle's
//! crop of the bank plus that share runs through the rest of the encoder.

use super::feature_cache::FeatureBank;
use super::map_encoder::MapEncoder;
use super::model::{PfNet, Workspace};
use crate::nn::buffers::sized;
use std::sync::Arc;

impl PfNet {
    /// Whether the feature cache holds this network's first stage rather than its map features:
    /// it lays the scan on its local maps (see `feature_cache.rs`).
    pub fn banks_hold_first_stage(&self) -> bool {
        self.config.channels_per_local_map() > 1
    }

    /// Values of one observation's scan terms (`scan_terms`): every map encoder's first stage.
    pub fn scan_term_len(&self) -> usize {
        self.map_encoders().map(MapEncoder::first_stage_len).sum()
    }

    /// One observation [obs_len] → its scan terms [scan_term_len]: for each map encoder, its
    /// first convolution's response to the scan laid on its local map, biases included. The
    /// laid scan is the same image for every particle, so this is once per observation.
    ///
    /// # Panics
    /// If the network lays no scan on its local maps, or `obs` is not one observation.
    pub fn scan_terms(&self, obs: &[f32], terms: &mut [f32], ws: &mut Workspace) {
        assert!(self.banks_hold_first_stage(), "scan_terms: the network lays no scan on its local maps");
        assert_eq!(terms.len(), self.scan_term_len(), "terms hold one observation's scan terms");
        let (side, margin) = (self.config.local_map.cells, self.config.map_margin());
        let mut terms = terms;
        for (view, (encoder, spec)) in self.map_encoders().zip(self.config.local_maps()).enumerate() {
            let (grid, extent_m) = self.grid_of_view(obs, view);
            sized(&mut ws.laid_scan, self.config.map_input_cells().pow(2));
            super::scan_on_map::lay_scan(grid, extent_m, (&spec, margin), &mut ws.laid_scan);
            let (own, rest) = terms.split_at_mut(encoder.first_stage_len());
            let laid = (&ws.laid_scan[..], margin);
            encoder.first_stage_of_channel(&self.params, 1, laid, (side, side), true, own, &mut ws.channel);
            terms = rest;
        }
    }

    /// Map features of `poses.len()` particles from the feature cache's first-stage banks:
    /// particle i (world x, y, yaw) of robot `owner[i]` crops `banks[owner[i]]`, adds that
    /// robot's row of `scan_terms` ([robots][scan_term_len]) and runs the rest of each map
    /// encoder → features [n][map_feature_len].
    pub fn encode_banked(
        &self,
        (poses, owner): (&[[f32; 3]], &[u32]),
        (banks, scan_terms): (&[Arc<FeatureBank>], &[f32]),
        features: &mut [f32],
        ws: &mut Workspace,
    ) {
        let (n, acts, term_len) = (poses.len(), &mut ws.acts, self.scan_term_len());
        let mut first = 0;
        let both = self.encode_maps_with(
            n,
            (&mut acts.map, &mut acts.wide_map, &mut acts.map_features),
            |e, encoder, acts| {
                let at = first;
                first += encoder.first_stage_len();
                encoder.forward_from_first_stage(&self.params, n, acts, |i, conv1| {
                    let robot = owner[i] as usize;
                    let [x, y, yaw] = poses[i];
                    banks[robot].crop_first_stage(e, (x, y, yaw), conv1);
                    let scan = &scan_terms[robot * term_len + at..][..conv1.len()];
                    for (value, s) in conv1.iter_mut().zip(scan) {
                        *value += s;
                    }
                });
            },
        );
        features.copy_from_slice(both);
    }
}
