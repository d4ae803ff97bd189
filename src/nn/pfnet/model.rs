//! PF-net's observation model (Karkus et al. 2018; APFN's configuration): for each particle,
//! log p(observation | particle's local map). The map encoder runs per particle, the observation
//! encoder once per step, the joint stage per particle on both (the observation's share of its
//! products once per step).

use super::config::PfNetConfig;
use super::joint::{Joint, JointActivations};
use super::map_encoder::{MapActivations, MapEncoder};
use super::obs_encoder::{ObsActivations, ObsEncoder};
use super::stage::ChannelScratch;
use crate::nn::buffers::sized;
use crate::nn::params::Params;
use rand::SeedableRng;
use rand_pcg::Pcg64Mcg;

/// The network: its configuration, its parameters in one arena, and the three parts.
#[derive(Clone, Debug)]
pub struct PfNet {
    pub config: PfNetConfig,
    pub params: Params,
    map: MapEncoder,
    /// The wide local map's own encoder (`WideView::own_map_encoder`), its features after the
    /// paper encoder's.
    wide_map: Option<MapEncoder>,
    obs: ObsEncoder,
    /// The laid scan's own encoders, one per view (`ScanOnMap::own_encoder`), their features
    /// after the observation encoder's.
    scans: Vec<MapEncoder>,
    joint: Joint,
}

/// What a training step feeds the joint stage per particle.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum MapInput {
    /// [k][local_map_len] local maps, through the map encoder (the paper).
    #[default]
    LocalMaps,
    /// [k][map_feature_len] map features made elsewhere (the feature cache's crops): the map
    /// encoder is not run, and gets no gradient.
    Features,
}

/// What a forward pass leaves for its backward.
#[derive(Clone, Debug, Default)]
pub struct StepActivations {
    pub map: MapActivations,
    pub wide_map: MapActivations,
    /// Both encoders' features side by side, [n][map_feature_len] (with a wide map encoder).
    pub(super) map_features: Vec<f32>,
    pub obs: ObsActivations,
    pub scan: ScanActivations,
    pub joint: JointActivations,
}

/// The scan encoders' share of a pass (`ScanOnMap::own_encoder`).
#[derive(Clone, Debug, Default)]
pub struct ScanActivations {
    /// Their input, [n][views][pixels] (`lay_scans`).
    laid: Vec<f32>,
    encoders: Vec<MapActivations>,
    /// The observation encoder's features, then each scan encoder's, [n][obs_feature_len].
    features: Vec<f32>,
    /// d loss / d features split between the observation encoder and each scan encoder.
    grads: Vec<Vec<f32>>,
}

/// Buffers for one thread's share of the work; reused across calls (they only grow).
#[derive(Clone, Debug, Default)]
pub struct Workspace {
    pub acts: StepActivations,
    /// A parallel task's map features before the joint stage (see `batch.rs`).
    pub chunk_map_features: Vec<f32>,
    grad_map_features: Vec<f32>,
    grad_obs_features: Vec<f32>,
    /// grad_map_features split between the two map encoders.
    grad_split: [Vec<f32>; 2],
    /// `scan_terms`' laid scan and its convolution buffers.
    pub(super) laid_scan: Vec<f32>,
    pub(super) channel: ChannelScratch,
}

/// Parameter counts per part.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
pub struct ParamCounts {
    pub map_encoder: usize,
    pub obs_encoder: usize,
    pub joint: usize,
    pub total: usize,
}

impl PfNet {
    /// A freshly initialised network (Keras's initialisers), deterministic for `seed`.
    ///
    /// # Errors
    /// The configuration's own check, `"field: expected …"`.
    pub fn new(config: PfNetConfig, seed: u64) -> Result<Self, String> {
        config.check()?;
        let mut rng = Pcg64Mcg::seed_from_u64(seed);
        let mut params = Params::new();
        let channels = config.map_encoder_channels();
        let map = MapEncoder::new(&mut params, &config, ("m", 0, channels), &mut rng);
        let wide_map = config
            .wide_map_encoder()
            .then(|| MapEncoder::new(&mut params, &config, ("mw", 1, channels), &mut rng));
        let obs = ObsEncoder::new(&mut params, &config, &mut rng);
        let views = if config.scan_encoders() { config.map_channels } else { 0 };
        let scans: Vec<MapEncoder> = (0..views)
            .map(|view| MapEncoder::new(&mut params, &config, (["s", "sw"][view], view, 1), &mut rng))
            .collect();
        let map_features = map.feature_len() + wide_map.as_ref().map_or(0, MapEncoder::feature_len);
        let obs_features = obs.feature_len() + scans.iter().map(MapEncoder::feature_len).sum::<usize>();
        let (map_channels, obs_channels) = (map_features / quarter(&config), obs_features / quarter(&config));
        let joint = Joint::new(&mut params, &config, map_channels, obs_channels, &mut rng);
        Ok(Self { config, params, map, wide_map, obs, scans, joint })
    }

    pub fn param_counts(&self) -> ParamCounts {
        let count = |part: fn(&str) -> bool| {
            self.params
                .specs()
                .filter(|(_, s)| part(&s.name))
                .map(|(_, s)| s.shape.iter().product::<usize>())
                .sum()
        };
        let (map_encoder, obs_encoder, joint) =
            (count(is_map_encoder_param), count(is_observation_param), count(|name| name.starts_with("j_")));
        ParamCounts { map_encoder, obs_encoder, joint, total: self.params.len() }
    }

    /// Values of one particle's input (its local maps, with `scan_on_map` each followed by the
    /// scan laid on it: `crop_inputs`), one observation, one particle's map features, one
    /// observation's features.
    pub fn local_map_len(&self) -> usize {
        self.config.map_channels * self.config.channels_per_local_map() * self.config.map_input_cells().pow(2)
    }
    pub fn obs_len(&self) -> usize {
        self.config.obs_channels * self.config.obs_cells.pow(2)
    }
    pub fn map_feature_len(&self) -> usize {
        self.map_encoders().map(MapEncoder::feature_len).sum()
    }
    pub fn obs_feature_len(&self) -> usize {
        self.obs.feature_len() + self.scans.iter().map(MapEncoder::feature_len).sum::<usize>()
    }

    /// Values of one observation's share of the joint stage (`observation_terms`).
    pub fn obs_term_len(&self) -> usize {
        self.joint.term_len()
    }

    /// obs [n][obs_len] → terms [n][obs_term_len]: the observation encoder, then the observation
    /// features' share of the joint stage's locally-connected layers, computed once per
    /// observation instead of once per particle.
    pub fn observation_terms(&self, obs: &[f32], n: usize, terms: &mut [f32], ws: &mut Workspace) {
        let acts = &mut ws.acts;
        let features = self.encode_observations(obs, n, (&mut acts.obs, &mut acts.scan));
        self.joint.observation_terms(&self.params, features, n, terms, &mut acts.joint);
    }

    /// The observation encoder, and the scan encoders on the laid scans, over `n` observations →
    /// [n][obs_feature_len], each observation's features then its scans'.
    fn encode_observations<'a>(
        &self,
        obs: &[f32],
        n: usize,
        (obs_acts, scan): (&'a mut ObsActivations, &'a mut ScanActivations),
    ) -> &'a [f32] {
        self.obs.forward(&self.params, obs, n, obs_acts);
        let own = self.obs.feature_len();
        if self.scans.is_empty() {
            return &obs_acts.features[..n * own];
        }
        self.lay_scans(obs, n, &mut scan.laid);
        scan.encoders.resize_with(self.scans.len(), MapActivations::default);
        for (encoder, acts) in self.scans.iter().zip(&mut scan.encoders) {
            encoder.forward(&self.params, &scan.laid, n, acts);
        }
        let len = self.obs_feature_len();
        sized(&mut scan.features, n * len);
        for (i, out) in scan.features.chunks_exact_mut(len).enumerate() {
            let (head, mut rest) = out.split_at_mut(own);
            head.copy_from_slice(&obs_acts.features[i * own..][..own]);
            for (encoder, acts) in self.scans.iter().zip(&scan.encoders) {
                let f = encoder.feature_len();
                let (part, tail) = rest.split_at_mut(f);
                part.copy_from_slice(&acts.features[i * f..][..f]);
                rest = tail;
            }
        }
        &scan.features
    }

    /// The backward of `encode_observations` from d loss / d features [n][obs_feature_len].
    fn backward_observations(
        &self,
        obs: &[f32],
        n: usize,
        dfeatures: &[f32],
        grads: &mut [f32],
        (obs_acts, scan): (&mut ObsActivations, &mut ScanActivations),
    ) {
        let p = &self.params;
        if self.scans.is_empty() {
            return self.obs.backward(p, obs, n, obs_acts, dfeatures, grads);
        }
        let lens: Vec<usize> = std::iter::once(self.obs.feature_len())
            .chain(self.scans.iter().map(MapEncoder::feature_len))
            .collect();
        scan.grads.resize_with(lens.len(), Vec::new);
        for (part, &len) in scan.grads.iter_mut().zip(&lens) {
            sized(part, n * len);
        }
        for (i, mut row) in dfeatures.chunks_exact(self.obs_feature_len()).enumerate() {
            for (part, &len) in scan.grads.iter_mut().zip(&lens) {
                part[i * len..][..len].copy_from_slice(&row[..len]);
                row = &row[len..];
            }
        }
        self.obs.backward(p, obs, n, obs_acts, &scan.grads[0], grads);
        for ((encoder, acts), d) in self.scans.iter().zip(&mut scan.encoders).zip(&scan.grads[1..]) {
            encoder.backward(p, &scan.laid, n, acts, d, grads);
        }
    }

    /// local maps [n][local_map_len] → features [n][map_feature_len].
    pub fn encode_local_maps(&self, maps: &[f32], n: usize, features: &mut [f32], ws: &mut Workspace) {
        let acts = &mut ws.acts;
        features.copy_from_slice(self.encode_maps(
            maps,
            n,
            (&mut acts.map, &mut acts.wide_map, &mut acts.map_features),
        ));
    }

    /// The map encoders over `n` particles' local maps → [n][map_feature_len], each particle's
    /// features of the paper encoder, then the wide map encoder's.
    fn encode_maps<'a>(
        &self,
        maps: &[f32],
        n: usize,
        acts: (&'a mut MapActivations, &'a mut MapActivations, &'a mut Vec<f32>),
    ) -> &'a [f32] {
        self.encode_maps_with(n, acts, |_, encoder, acts| encoder.forward(&self.params, maps, n, acts))
    }

    /// `n` particles' features, each map encoder run by `run(index, encoder, its activations)`
    /// (0 the paper's, 1 a wide view's), side by side as `encode_maps` lays them.
    pub(super) fn encode_maps_with<'a>(
        &self,
        n: usize,
        (fine_acts, wide_acts, both): (&'a mut MapActivations, &'a mut MapActivations, &'a mut Vec<f32>),
        mut run: impl FnMut(usize, &MapEncoder, &mut MapActivations),
    ) -> &'a [f32] {
        run(0, &self.map, fine_acts);
        let Some(wide) = &self.wide_map else { return &fine_acts.features[..n * self.map.feature_len()] };
        run(1, wide, wide_acts);
        let (fine_len, wide_len) = (self.map.feature_len(), wide.feature_len());
        sized(both, n * (fine_len + wide_len));
        let parts = fine_acts.features.chunks_exact(fine_len).zip(wide_acts.features.chunks_exact(wide_len));
        for (out, (fine, far)) in both.chunks_exact_mut(fine_len + wide_len).zip(parts) {
            out[..fine_len].copy_from_slice(fine);
            out[fine_len..].copy_from_slice(far);
        }
        both
    }

    /// The map encoders' backward from d loss / d features [n][map_feature_len] (`encode_maps`).
    fn backward_maps(
        &self,
        maps: &[f32],
        n: usize,
        dfeatures: &[f32],
        grads: &mut [f32],
        ws: &mut Workspace,
    ) {
        let (p, acts) = (&self.params, &mut ws.acts);
        let Some(wide) = &self.wide_map else {
            return self.map.backward(p, maps, n, &mut acts.map, dfeatures, grads);
        };
        let (fine_len, wide_len) = (self.map.feature_len(), wide.feature_len());
        let [dfine, dwide] = &mut ws.grad_split;
        sized(dfine, n * fine_len);
        sized(dwide, n * wide_len);
        let split = dfine.chunks_exact_mut(fine_len).zip(dwide.chunks_exact_mut(wide_len));
        for (both, (fine, far)) in dfeatures.chunks_exact(fine_len + wide_len).zip(split) {
            fine.copy_from_slice(&both[..fine_len]);
            far.copy_from_slice(&both[fine_len..]);
        }
        self.map.backward(p, maps, n, &mut acts.map, dfine, grads);
        wide.backward(p, maps, n, &mut acts.wide_map, dwide, grads);
    }

    /// The joint stage for `owner.len()` particles: map features [n][map_feature_len], and
    /// particle i's observation terms at row `owner[i]` of `obs_terms` → loglik [n].
    pub fn joint_log_likelihoods(
        &self,
        map_features: &[f32],
        obs_terms: &[f32],
        owner: &[u32],
        loglik: &mut [f32],
        ws: &mut Workspace,
    ) {
        let acts = &mut ws.acts.joint;
        self.joint.forward_shared(&self.params, map_features, obs_terms, owner, acts);
        loglik.copy_from_slice(&acts.loglik[..owner.len()]);
    }

    /// The log-likelihoods of `steps` filter steps of `k` particles each, the particles of a step
    /// sharing its observation: obs [steps][obs_len], maps [steps·k][…] → loglik [steps·k],
    /// leaving the activations in `ws.acts` for `backward_steps`. A training sequence passes its
    /// T steps at once (no step's likelihoods depend on another's): T·K particles keep the joint
    /// stage's products wide, where a step's K = 30 leave them bound by per-call overhead.
    pub fn forward_steps<'w>(
        &self,
        obs: &[f32],
        (maps, input): (&[f32], MapInput),
        steps: usize,
        k: usize,
        ws: &'w mut Workspace,
    ) -> &'w [f32] {
        let (p, acts, n) = (&self.params, &mut ws.acts, steps * k);
        let obs_features = self.encode_observations(obs, steps, (&mut acts.obs, &mut acts.scan));
        let map_features = match input {
            MapInput::LocalMaps => {
                self.encode_maps(maps, n, (&mut acts.map, &mut acts.wide_map, &mut acts.map_features))
            }
            MapInput::Features => maps,
        };
        self.joint.forward(
            p,
            &map_features[..n * self.map_feature_len()],
            obs_features,
            (steps, k),
            &mut acts.joint,
        );
        &acts.joint.loglik[..n]
    }

    /// The backward pass of the `forward_steps` whose activations are in `ws.acts`: from
    /// d loss / d loglik of its `steps·k` particles, accumulates every weight gradient into
    /// `grads` (laid out like `params`).
    pub fn backward_steps(
        &self,
        obs: &[f32],
        (maps, input): (&[f32], MapInput),
        (steps, k): (usize, usize),
        dloglik: &[f32],
        grads: &mut [f32],
        ws: &mut Workspace,
    ) {
        let (p, n) = (&self.params, steps * k);
        let mut dmap = std::mem::take(&mut ws.grad_map_features);
        let (acts, dobs) = (&mut ws.acts, &mut ws.grad_obs_features);
        sized(&mut dmap, n * self.map_feature_len());
        sized(dobs, steps * self.obs_feature_len());
        let map_features = match input {
            MapInput::LocalMaps => match self.wide_map {
                Some(_) => &acts.map_features,
                None => &acts.map.features[..n * self.map_feature_len()],
            },
            MapInput::Features => maps,
        };
        self.joint.backward(p, map_features, (steps, k), &mut acts.joint, dloglik, grads, &mut dmap, dobs);
        self.backward_observations(obs, steps, dobs, grads, (&mut acts.obs, &mut acts.scan));
        if input == MapInput::LocalMaps {
            self.backward_maps(maps, n, &dmap, grads, ws);
        }
        ws.grad_map_features = dmap;
    }

    /// One filter step on its own: forward, `loss` turns the log-likelihoods into (loss,
    /// d loss / d loglik), backward into `grads`. Returns the loss.
    pub fn step_gradient(
        &self,
        obs: &[f32],
        maps: &[f32],
        k: usize,
        loss: impl FnOnce(&[f32]) -> (f64, Vec<f32>),
        grads: &mut [f32],
        ws: &mut Workspace,
    ) -> f64 {
        let maps = (maps, MapInput::LocalMaps);
        let (value, dloglik) = loss(self.forward_steps(obs, maps, 1, k, ws));
        self.backward_steps(obs, maps, (1, k), &dloglik, grads, ws);
        value
    }

    /// The map encoders, the paper's first, for the feature cache's whole-map windows.
    pub(super) fn map_encoders(&self) -> impl Iterator<Item = &MapEncoder> {
        std::iter::once(&self.map).chain(&self.wide_map)
    }
}

/// Whether the parameter `name` belongs to a map encoder (the part `MapInput::Features` freezes).
pub fn is_map_encoder_param(name: &str) -> bool {
    ["m_", "m2_", "mw_", "mw2_"].iter().any(|prefix| name.starts_with(prefix))
}

/// Whether the parameter `name` belongs to the observation's side: its encoder, and the laid
/// scan's encoders.
fn is_observation_param(name: &str) -> bool {
    ["o_", "o2_", "s_", "s2_", "sw_", "sw2_"].iter().any(|prefix| name.starts_with(prefix))
}

/// Pixels of a feature map where the two encoders meet (paper: 14 × 14).
fn quarter(config: &PfNetConfig) -> usize {
    (config.local_map.cells / 2).pow(2)
}
