//! A one-sensor PF-net as the start of a grid + depth one. Every weight carries over; the
//! observation encoder's first convolutions read the old sensor's channel with the old weights
//! and the new sensor's with zeros. The widened network's likelihoods are then the old one's,
//! whatever the new sensor sees, so training starts from the one-sensor model and can only add
//! what the second channel tells — where a grid + depth model trained from scratch starts over.

use super::model::PfNet;
use super::observation::Observation;
use crate::nn::conv::widen_input_channels;

impl PfNet {
    /// This network observing `observation`: itself if it already does, else a `grid` or `depth`
    /// network widened to `grid_and_depth` (its sensor's channel keeps its weights, the other
    /// channel's are zero).
    ///
    /// # Errors
    /// Any other pair of observations, naming both.
    pub fn widened_to(&self, observation: Observation) -> Result<PfNet, String> {
        let from = self.config.observation;
        if from == observation {
            return Ok(self.clone());
        }
        let kept_channel = match (from, observation) {
            (Observation::Grid, Observation::GridAndDepth) => 0,
            (Observation::Depth, Observation::GridAndDepth) => 1,
            _ => {
                return Err(format!(
                    "a `{}` network cannot start a `{}` one; expected a `grid` or `depth` network \
                     to widen to `grid_and_depth`",
                    from.name(),
                    observation.name()
                ));
            }
        };
        let mut wide = PfNet::new(self.config.clone().observing(observation), 0)?;
        let names: Vec<String> = wide.params.specs().map(|(_, s)| s.name.clone()).collect();
        for name in names {
            let id = wide.params.find(&name).expect("listed above");
            let old_id = self.params.find(&name).ok_or_else(|| format!("`{name}` missing"))?;
            let (old_shape, shape) = (&self.params.spec(old_id).shape, wide.params.spec(id).shape.clone());
            let old = self.params.get(old_id);
            let new = wide.params.get_mut(id);
            if *old_shape == shape {
                new.copy_from_slice(old);
            } else if let ([c_out, 1, kh, kw], [c_out2, _, kh2, kw2]) = (&old_shape[..], &shape[..])
                && (c_out, kh, kw) == (c_out2, kh2, kw2)
            {
                widen_input_channels(old, new, *c_out, kh * kw, kept_channel);
            } else {
                return Err(format!("`{name}`: shape {old_shape:?} does not widen to {shape:?}"));
            }
        }
        Ok(wide)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::nn::gradcheck::test_values;
    use crate::nn::pfnet::{MapInput, PfNetConfig, Workspace};

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

        let id = (wide.params.specs())
            .find(|(_, s)| s.name.starts_with("o_") && s.name.ends_with("/kernel"))
            .map(|(id, _)| id)
            .unwrap();
        let taps = wide.params.spec(id).shape[2] * wide.params.spec(id).shape[3];
        wide.params.get_mut(id)[taps] = 0.5; // output channel 0, depth channel, first tap
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
}
