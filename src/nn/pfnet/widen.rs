//! Starting a wider PF-net from a trained one: a one-sensor network as the start of a grid + depth
//! one, a one-view network as the start of one with a wide view, and one whose map encoders see
//! the map alone as the start of one laying the scan on it. Every weight carries over;
//! the first convolutions read the old channels with the old weights and the new channel with
//! zeros. The widened network's likelihoods are then the old one's, whatever the new channel
//! holds, so training starts from the trained model and can only add what the new channel tells,
//! where a wider model trained from scratch starts over.

use super::config::{PfNetConfig, ScanOnMap, WideView};
use super::model::PfNet;
use super::observation::Observation;
use crate::nn::conv::widen_input_channels;

impl PfNet {
    /// This network observing `observation`: itself if it already does, else a `grid` or `depth`
    /// network widened to `grid_and_depth` (its sensor's channel keeps its weights, the other
    /// channel's are zero).
    ///
    /// # Errors
    /// Any other pair of observations, naming both; a network with a wide view (its last channel
    /// would move).
    pub fn widened_to(&self, observation: Observation) -> Result<PfNet, String> {
        let from = self.config.observation;
        if from == observation {
            return Ok(self.clone());
        }
        let kept_channel = match (from, observation, self.config.wide_view) {
            (Observation::Grid, Observation::GridAndDepth, None) => 0,
            (Observation::Depth, Observation::GridAndDepth, None) => 1,
            _ => {
                return Err(format!(
                    "a `{}` network{} cannot start a `{}` one; expected a `grid` or `depth` network \
                     without a wide view to widen to `grid_and_depth`",
                    from.name(),
                    if self.config.wide_view.is_some() { " with a wide view" } else { "" },
                    observation.name()
                ));
            }
        };
        self.carried_into(self.config.clone().observing(observation), kept_channel)
    }

    /// This network with the wide view `view`: itself if it has it, else a one-view network whose
    /// first map and observation convolutions gain a last input channel of zero weight.
    ///
    /// # Errors
    /// A network with another wide view, naming both.
    pub fn with_wide_view(&self, view: WideView) -> Result<PfNet, String> {
        match self.config.wide_view {
            Some(have) if have == view => Ok(self.clone()),
            Some(have) => {
                Err(format!("a network with the wide view {have:?} cannot start one with {view:?}"))
            }
            None if self.config.scan_encoders() => Err(format!(
                "a network whose laid scan has encoders of its own cannot start one with the wide view \
                 {view:?}; expected one laying the scan on its map encoders' input, or training from scratch"
            )),
            None => self.carried_into(self.config.clone().with_wide_view(Some(view)), 0),
        }
    }

    /// This network with the scan laid on its local maps (`ScanOnMap`): itself if it has it, else
    /// one whose map encoders' first convolutions gain the scan's channel after each map's, at
    /// zero weight.
    ///
    /// # Errors
    /// A network with another `scan_on_map`, naming both; one that cannot read the scan there
    /// (`PfNetConfig::check`).
    pub fn with_scan_on_map(&self, scan: ScanOnMap) -> Result<PfNet, String> {
        match self.config.scan_on_map {
            Some(have) if have == scan => Ok(self.clone()),
            Some(have) => Err(format!("a network with {have:?} cannot start one with {scan:?}")),
            None if scan.own_encoder => Err(format!(
                "{scan:?}: the scan's own encoders train from scratch; expected no `init`, or \
                 `own_encoder: false` to lay the scan on the map encoders' input"
            )),
            None => self.carried_into(PfNetConfig { scan_on_map: Some(scan), ..self.config.clone() }, 0),
        }
    }

    /// This network with its map encoders' first stage reading the map beyond the local maps'
    /// edge or not (`PfNetConfig::map_context`): itself if it already does, else the same weights
    /// (none depends on it) in encoders built for that input.
    ///
    /// # Errors
    /// A network that cannot have it (`PfNetConfig::check`).
    pub fn with_map_context(&self, map_context: bool) -> Result<PfNet, String> {
        if self.config.map_context == map_context {
            return Ok(self.clone());
        }
        let mut net = PfNet::new(PfNetConfig { map_context, ..self.config.clone() }, 0)?;
        net.params.values.clone_from(&self.params.values);
        Ok(net)
    }

    /// A fresh network of `config` holding this one's weights; where a first convolution has more
    /// input channels, the old ones sit from channel `kept_channel` on and the others are zero. A
    /// wide map encoder of its own starts as a copy of the paper one, its features reaching the
    /// joint stage through zero weights.
    fn carried_into(&self, config: PfNetConfig, kept_channel: usize) -> Result<PfNet, String> {
        let mut wide = PfNet::new(config, 0)?;
        let quarter = (self.config.local_map.cells / 2).pow(2);
        let joint_channels = |net: &PfNet| (net.map_feature_len() + net.obs_feature_len()) / quarter;
        let (c_old, c_new) = (joint_channels(self), joint_channels(&wide));
        let names: Vec<String> = wide.params.specs().map(|(_, s)| s.name.clone()).collect();
        for name in names {
            let id = wide.params.find(&name).expect("listed above");
            let source = match (self.params.find(&name), name.strip_prefix("mw")) {
                (None, Some(rest)) => format!("m{rest}"),
                _ => name.clone(),
            };
            let old_id = self.params.find(&source).ok_or_else(|| format!("`{source}` missing"))?;
            let (old_shape, shape) = (&self.params.spec(old_id).shape, wide.params.spec(id).shape.clone());
            let old = self.params.get(old_id);
            let new = wide.params.get_mut(id);
            if *old_shape == shape {
                new.copy_from_slice(old);
            } else if let ([c_out, c_old, kh, kw], [c_out2, c_new, kh2, kw2]) = (&old_shape[..], &shape[..])
                && (c_out, kh, kw) == (c_out2, kh2, kw2)
                && kept_channel + c_old <= *c_new
            {
                widen_input_channels(old, new, *c_out, kh * kw, kept_channel);
            } else if let ([.., old_patch], [.., patch]) = (&old_shape[..], &shape[..])
                && name.starts_with("j_lc")
                && old_shape.len() == shape.len()
                && old_patch * c_new == patch * c_old
            {
                widen_joint_map_channels(old, new, (c_old, c_new), self.map_feature_len() / quarter);
            } else {
                return Err(format!("`{name}`: shape {old_shape:?} does not widen to {shape:?}"));
            }
        }
        Ok(wide)
    }
}

/// A locally-connected kernel whose patches (`(kh, kw, c)`, `c_old` channels, map features
/// first) gain map channels: old channel c < `map` stays c, the rest move up by c_new − c_old,
/// and the channels in between are zero.
fn widen_joint_map_channels(old: &[f32], new: &mut [f32], (c_old, c_new): (usize, usize), map: usize) {
    new.fill(0.0);
    for (old, new) in old.chunks_exact(c_old).zip(new.chunks_exact_mut(c_new)) {
        new[..map].copy_from_slice(&old[..map]);
        new[map + c_new - c_old..].copy_from_slice(&old[map..]);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::nn::gradcheck::test_values;
    use crate::nn::params::ParamId;
    use crate::nn::pfnet::{MapInput, Workspace};

    /// Sets the first tap of output 0 on input channel 1 of the first convolution named `prefix…`
    /// to 0.5 and returns that kernel's id.
    fn nudge_second_channel(model: &mut PfNet, prefix: &str) -> ParamId {
        let id = (model.params.specs())
            .find(|(_, s)| s.name.starts_with(prefix) && s.name.ends_with("/kernel"))
            .map(|(id, _)| id)
            .unwrap();
        let taps = model.params.spec(id).shape[2] * model.params.spec(id).shape[3];
        model.params.get_mut(id)[taps] = 0.5;
        id
    }

    /// The widened network scores every particle as the one-sensor network did, whatever the
    /// second channel holds; after one change to a depth weight it no longer does.
    #[test]
    fn widened_grid_network_ignores_depth_until_trained() {
        let grid = PfNet::new(PfNetConfig::named("compact").unwrap(), 3).unwrap();
        let mut wide = grid.widened_to(Observation::GridAndDepth).unwrap();
        assert_eq!(wide.config.observation, Observation::GridAndDepth);
        let k = 4;
        let maps = test_values(k * grid.local_map_len(), 5);
        let grid_obs = test_values(grid.obs_len(), 6);
        let depth_obs = test_values(grid.obs_len(), 7);
        let wide_obs: Vec<f32> = grid_obs.iter().chain(&depth_obs).copied().collect();
        let mut ws = Workspace::default();
        let want = grid.forward_steps(&grid_obs, (&maps, MapInput::LocalMaps), 1, k, &mut ws).to_vec();
        let got = wide.forward_steps(&wide_obs, (&maps, MapInput::LocalMaps), 1, k, &mut ws).to_vec();
        assert_eq!(got, want, "zero depth weights: the grid network's likelihoods");

        nudge_second_channel(&mut wide, "o_"); // the depth channel
        let changed = wide.forward_steps(&wide_obs, (&maps, MapInput::LocalMaps), 1, k, &mut ws).to_vec();
        assert_ne!(changed, want, "a depth weight reaches the likelihoods");
    }

    #[test]
    fn only_one_sensor_widens_to_both() {
        let both = PfNet::new(PfNetConfig::named("compact").unwrap().observing(Observation::GridAndDepth), 0);
        let e = both.unwrap().widened_to(Observation::Grid).unwrap_err();
        assert!(e.contains("`grid_and_depth` network cannot start a `grid` one"), "{e}");
        let depth = PfNet::new(PfNetConfig::named("compact").unwrap().observing(Observation::Depth), 0);
        assert!(depth.unwrap().widened_to(Observation::GridAndDepth).is_ok());
    }

    /// A wide view starts out unheard: the widened network scores every particle as the one-view
    /// one, whatever the wide channels hold; a wide map weight then reaches the likelihoods.
    #[test]
    fn a_wide_view_is_silent_until_trained() {
        let narrow =
            PfNet::new(PfNetConfig::named("compact").unwrap().observing(Observation::GridAndDepth), 3);
        let narrow = narrow.unwrap();
        let view = WideView { map_cell_m: 0.2, grid_extent_m: 10.0, own_map_encoder: false };
        let mut wide = narrow.with_wide_view(view).unwrap();
        assert_eq!((wide.config.map_channels, wide.config.obs_channels), (2, 3));
        let (k, side) = (4, narrow.local_map_len());
        let maps = test_values(k * side, 5);
        let obs = test_values(narrow.obs_len(), 6);
        // Each particle's two map channels: its own, then anything.
        let anything = test_values(side, 8);
        let wide_maps: Vec<f32> = maps.chunks(side).flat_map(|m| [m, &anything[..]].concat()).collect();
        let wide_obs: Vec<f32> = obs.iter().copied().chain(test_values(narrow.obs_len() / 2, 7)).collect();
        let mut ws = Workspace::default();
        let want = narrow.forward_steps(&obs, (&maps, MapInput::LocalMaps), 1, k, &mut ws).to_vec();
        let got = wide.forward_steps(&wide_obs, (&wide_maps, MapInput::LocalMaps), 1, k, &mut ws).to_vec();
        assert_eq!(got, want, "zero wide weights: the one-view network's likelihoods");

        let id = nudge_second_channel(&mut wide, "m_"); // the wide map channel
        let changed =
            wide.forward_steps(&wide_obs, (&wide_maps, MapInput::LocalMaps), 1, k, &mut ws).to_vec();
        assert_ne!(changed, want, "a wide map weight reaches the likelihoods");

        assert_eq!(wide.with_wide_view(view).unwrap().params.get(id), wide.params.get(id), "already wide");
        let other = WideView { grid_extent_m: 8.0, ..view };
        assert!(wide.with_wide_view(other).unwrap_err().contains("cannot start one with"));
        let e = wide.widened_to(Observation::Depth).unwrap_err();
        assert!(e.contains("with a wide view cannot start"), "{e}");
    }

    /// A wide map encoder of its own starts as a copy of the paper one and unheard: the widened
    /// network scores every particle as the one-view one (to rounding); its joint weights then
    /// reach them.
    #[test]
    fn a_wide_map_encoder_starts_as_a_silent_copy() {
        let narrow = PfNet::new(PfNetConfig::named("compact").unwrap(), 3).unwrap();
        let view = WideView { map_cell_m: 0.2, grid_extent_m: 10.0, own_map_encoder: true };
        let mut wide = narrow.with_wide_view(view).unwrap();
        assert_eq!((wide.config.map_channels, wide.config.obs_channels), (2, 2));
        assert_eq!(wide.map_feature_len(), 2 * narrow.map_feature_len());
        for (name, copy) in
            [("m_c3/kernel", "mw_c3/kernel"), ("m2_c5/bias", "mw2_c5/bias"), ("m_ln2/gamma", "mw_ln2/gamma")]
        {
            let (a, b) = (narrow.params.find(name).unwrap(), wide.params.find(copy).unwrap());
            assert_eq!(narrow.params.get(a), wide.params.get(b), "{copy} starts as {name}");
        }
        let (k, side) = (4, narrow.local_map_len());
        let maps = test_values(k * side, 5);
        let anything = test_values(side, 8);
        let wide_maps: Vec<f32> = maps.chunks(side).flat_map(|m| [m, &anything[..]].concat()).collect();
        let obs = test_values(narrow.obs_len(), 6);
        let wide_obs: Vec<f32> = obs.iter().copied().chain(test_values(narrow.obs_len(), 7)).collect();
        let mut ws = Workspace::default();
        let want = narrow.forward_steps(&obs, (&maps, MapInput::LocalMaps), 1, k, &mut ws).to_vec();
        let got = wide.forward_steps(&wide_obs, (&wide_maps, MapInput::LocalMaps), 1, k, &mut ws).to_vec();
        // To rounding: the joint stage's products now run over twice the map channels.
        let close = got.iter().zip(&want).all(|(g, w)| (g - w).abs() <= 1e-6 * w.abs().max(1.0));
        assert!(
            close,
            "zero joint weights on the wide features: the one-view likelihoods, {got:?} against {want:?}"
        );

        // Every tap's wide-feature channels (after the 4 fine ones) of the 3 × 3 layer.
        let quarter = (narrow.config.local_map.cells / 2).pow(2);
        let (fine, channels) =
            (narrow.map_feature_len() / quarter, (wide.map_feature_len() + wide.obs_feature_len()) / quarter);
        let id = wide.params.find("j_lc3/kernel").unwrap();
        for tap in wide.params.get_mut(id).chunks_exact_mut(channels) {
            tap[fine..2 * fine].fill(0.1);
        }
        let changed =
            wide.forward_steps(&wide_obs, (&wide_maps, MapInput::LocalMaps), 1, k, &mut ws).to_vec();
        assert_ne!(changed, want, "the wide encoder's features reach the likelihoods");
    }
}
