//! One supervised training step of PF-net, as in the paper: B sequences × T filter steps × K
//! particles. Particle weights accumulate over a sequence (no resampling), so the loss at step t
//! depends on the log-likelihoods of steps 1…t. Each sequence is one parallel task with its own
//! gradient buffer; buffers are summed in task order, so the bytes do not depend on the thread
//! count.

use super::batch::Workspaces;
use super::loss::PoseLoss;
use super::model::{MapInput, PfNet, Workspace};
use crate::nn::adam::Adam;
use rayon::prelude::*;

/// A training batch, flattened over B × T filter steps.
#[derive(Clone, Copy, Debug)]
pub struct StepBatch<'a> {
    /// [steps][obs_len]
    pub obs: &'a [f32],
    /// [steps][k][local_map_len], or [steps][k][map_feature_len] when `input` is `Features`
    pub maps: &'a [f32],
    pub input: MapInput,
    /// [steps][k] particle poses (x, y, θ)
    pub states: &'a [[f32; 3]],
    /// [steps] true poses
    pub targets: &'a [[f32; 3]],
    /// Particles per step.
    pub k: usize,
    /// Filter steps per sequence (T); weights carry over within a sequence. 1: independent steps.
    pub sequence: usize,
}

impl StepBatch<'_> {
    pub fn steps(&self) -> usize {
        self.targets.len()
    }
}

/// Gradient buffers, one per sequence, kept between steps.
#[derive(Clone, Debug, Default)]
pub struct GradBuffers {
    tasks: Vec<Vec<f32>>,
    /// The batch's gradient (sum over sequences), laid out like the parameters.
    pub total: Vec<f32>,
}

impl PfNet {
    /// The batch's loss and its gradient in `grads.total`. `loss.scale` should average over the
    /// batch (1 / steps for the paper's mean over B and T).
    pub fn batch_gradient(
        &self,
        batch: &StepBatch,
        loss: &PoseLoss,
        grads: &mut GradBuffers,
        pool: &Workspaces,
    ) -> f64 {
        let sequences = batch.steps().div_ceil(batch.sequence.max(1));
        grads.tasks.resize_with(sequences, Vec::new);
        let losses: Vec<f64> = grads
            .tasks
            .par_iter_mut()
            .enumerate()
            .map(|(sequence, buffer)| {
                buffer.clear();
                buffer.resize(self.params.len(), 0.0);
                self.sequence_gradient(batch, sequence, loss, buffer, pool)
            })
            .collect();
        grads.total.clear();
        grads.total.resize(self.params.len(), 0.0);
        for buffer in &grads.tasks {
            for (t, g) in grads.total.iter_mut().zip(buffer) {
                *t += g;
            }
        }
        losses.iter().sum()
    }

    /// The batch's loss without gradients (validation).
    pub fn batch_loss(&self, batch: &StepBatch, loss: &PoseLoss, pool: &Workspaces) -> f64 {
        let sequences = batch.steps().div_ceil(batch.sequence.max(1));
        let losses: Vec<f64> = (0..sequences)
            .into_par_iter()
            .map(|sequence| pool.with(|ws| self.sequence_forward(batch, sequence, loss, ws).0))
            .collect();
        losses.iter().sum()
    }

    /// One sequence forward, all its steps in one pass (`forward_steps`, which leaves the
    /// activations in `ws.acts` for the backward): every step's log-likelihoods accumulate into
    /// log-weights, every step's weighted mean is scored. Returns the loss and d loss / d loglik
    /// [steps·k] (a step's log-likelihoods count in every later step's weights: the sum of later
    /// d loss / d log_w).
    fn sequence_forward(
        &self,
        batch: &StepBatch,
        sequence: usize,
        loss: &PoseLoss,
        ws: &mut Workspace,
    ) -> (f64, Vec<f32>) {
        let (steps, k) = (self.sequence_steps(batch, sequence), batch.k);
        let loglik = self.forward_steps(
            self.steps_obs(batch, &steps),
            self.steps_maps(batch, &steps),
            steps.len(),
            k,
            ws,
        );
        let mut log_w = vec![0.0f32; k];
        let (mut value, mut dloglik) = (0.0, Vec::with_capacity(loglik.len()));
        for (s, step_loglik) in steps.zip(loglik.chunks_exact(k)) {
            log_w.iter_mut().zip(step_loglik).for_each(|(w, l)| *w += l);
            let (l, d) = loss.evaluate(&log_w, &batch.states[s * k..(s + 1) * k], batch.targets[s]);
            value += l;
            dloglik.extend(d);
        }
        for t in (k..dloglik.len()).step_by(k).rev() {
            let (earlier, later) = dloglik.split_at_mut(t);
            earlier[t - k..].iter_mut().zip(&later[..k]).for_each(|(e, l)| *e += l);
        }
        (value, dloglik)
    }

    /// One sequence's loss and gradient: the forward pass above, then its backward from the
    /// activations it left (the README's speed table has the peak memory this costs).
    fn sequence_gradient(
        &self,
        batch: &StepBatch,
        sequence: usize,
        loss: &PoseLoss,
        grads: &mut [f32],
        pool: &Workspaces,
    ) -> f64 {
        pool.with(|ws| {
            let (value, dloglik) = self.sequence_forward(batch, sequence, loss, ws);
            let steps = self.sequence_steps(batch, sequence);
            let (obs, maps) = (self.steps_obs(batch, &steps), self.steps_maps(batch, &steps));
            self.backward_steps(obs, maps, (steps.len(), batch.k), &dloglik, grads, ws);
            value
        })
    }

    fn sequence_steps(&self, batch: &StepBatch, sequence: usize) -> std::ops::Range<usize> {
        let t = batch.sequence.max(1);
        sequence * t..((sequence + 1) * t).min(batch.steps())
    }

    fn steps_obs<'a>(&self, batch: &StepBatch<'a>, steps: &std::ops::Range<usize>) -> &'a [f32] {
        &batch.obs[steps.start * self.obs_len()..steps.end * self.obs_len()]
    }

    fn steps_maps<'a>(&self, batch: &StepBatch<'a>, steps: &std::ops::Range<usize>) -> (&'a [f32], MapInput) {
        let per_particle = match batch.input {
            MapInput::LocalMaps => self.local_map_len(),
            MapInput::Features => self.map_feature_len(),
        };
        let len = per_particle * batch.k;
        (&batch.maps[steps.start * len..steps.end * len], batch.input)
    }

    /// forward → loss → backward → Adam; returns the loss before the update.
    pub fn train_step(
        &mut self,
        batch: &StepBatch,
        loss: &PoseLoss,
        adam: &mut Adam,
        grads: &mut GradBuffers,
        pool: &Workspaces,
    ) -> f64 {
        let value = self.batch_gradient(batch, loss, grads, pool);
        adam.update(&mut self.params.values, &grads.total);
        value
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::nn::pfnet::{PfNetConfig, ScanOnMap, WideView, is_map_encoder_param};

    /// A tiny random batch: 6 steps × 4 particles (2 sequences of 3 unless told otherwise).
    struct TestBatch {
        obs: Vec<f32>,
        maps: Vec<f32>,
        states: Vec<[f32; 3]>,
        targets: Vec<[f32; 3]>,
    }

    impl TestBatch {
        fn new(model: &PfNet) -> Self {
            let values =
                crate::nn::gradcheck::test_values(6 * model.obs_len() + 24 * model.local_map_len(), 9);
            let (obs, maps) = values.split_at(6 * model.obs_len());
            let unit = |v: f32| (v + 1.0) / 2.0;
            Self {
                obs: obs.iter().map(|&v| unit(v)).collect(),
                maps: maps.iter().map(|&v| unit(v)).collect(),
                states: (0..24)
                    .map(|i| [i as f32 * 0.1, 0.05 * (i % 5) as f32, 0.2 * (i % 3) as f32])
                    .collect(),
                targets: (0..6).map(|i| [0.5, 0.1 * i as f32, 0.1]).collect(),
            }
        }

        /// Its local maps in sequences of `sequence` steps.
        fn batch(&self, sequence: usize) -> StepBatch<'_> {
            self.with_maps(&self.maps, MapInput::LocalMaps, sequence)
        }

        fn with_maps<'a>(&'a self, maps: &'a [f32], input: MapInput, sequence: usize) -> StepBatch<'a> {
            let (obs, states, targets) = (&self.obs, &self.states, &self.targets);
            StepBatch { obs, maps, states, targets, k: 4, sequence, input }
        }
    }

    const LOSS: PoseLoss =
        PoseLoss { weights: [1.0, 1.0, 0.36], wrap_heading: true, scale: 1.0 / 6.0, mixture: None };

    #[test]
    fn train_step_lowers_the_loss_on_a_fixed_batch() {
        let mut model = PfNet::new(PfNetConfig::compact(), 1).unwrap();
        let data = TestBatch::new(&model);
        let (batch, loss) = (data.batch(3), LOSS);
        let config = crate::nn::adam::AdamConfig { learning_rate: 1e-3, ..Default::default() };
        let mut adam = Adam::new(config, model.params.len());
        let (mut grads, pool) = (GradBuffers::default(), Workspaces::for_current_pool());
        let first = model.train_step(&batch, &loss, &mut adam, &mut grads, &pool);
        for _ in 0..5 {
            model.train_step(&batch, &loss, &mut adam, &mut grads, &pool);
        }
        let last = model.batch_gradient(&batch, &loss, &mut grads, &pool);
        assert!(last < first, "six Adam steps on one batch must lower its loss: {first} → {last}");
    }

    #[test]
    fn a_sequence_in_one_pass_equals_its_steps_one_by_one() {
        // forward_steps over 3 steps must give each step the likelihoods it gets alone (its own
        // observation for its own particles), and backward_steps the sum of the steps' gradients,
        // so batching a sequence changes only the speed.
        let model = PfNet::new(PfNetConfig::compact(), 5).unwrap();
        let data = TestBatch::new(&model);
        let (batch, mut ws) = (data.batch(3), Workspace::default());
        let dloglik: Vec<f32> = (0..12).map(|i| 0.1 * (i as f32 - 5.5)).collect();
        let steps = |r: std::ops::Range<usize>| (model.steps_obs(&batch, &r), model.steps_maps(&batch, &r));
        let close = |a: f32, b: f32, scale: f32| (a - b).abs() <= 1e-4 * scale.max(1e-3);

        let (obs, maps) = steps(0..3);
        let together = model.forward_steps(obs, maps, 3, 4, &mut ws).to_vec();
        let mut grads_together = vec![0.0; model.params.len()];
        model.backward_steps(obs, maps, (3, 4), &dloglik, &mut grads_together, &mut ws);

        let mut grads_alone = vec![0.0; model.params.len()];
        for s in 0..3 {
            let (obs, maps) = steps(s..s + 1);
            let alone = model.forward_steps(obs, maps, 1, 4, &mut ws).to_vec();
            for (a, b) in alone.iter().zip(&together[4 * s..4 * s + 4]) {
                assert!(close(*a, *b, a.abs()), "step {s}: alone {a} vs together {b}");
            }
            model.backward_steps(obs, maps, (1, 4), &dloglik[4 * s..4 * s + 4], &mut grads_alone, &mut ws);
        }
        for (id, spec) in model.params.specs() {
            let (want, got) = (model.params.of(&grads_alone, id), model.params.of(&grads_together, id));
            let scale = want.iter().fold(0.0f32, |m, g| m.max(g.abs()));
            for (w, g) in want.iter().zip(got) {
                assert!(close(*w, *g, scale), "{}: steps one by one {w} vs together {g}", spec.name);
            }
        }
    }

    #[test]
    fn kept_activations_of_an_earlier_batch_do_not_leak_into_the_next() {
        // A warm workspace holds the last batch's activations (and a longer sequence's); the
        // gradient must be the one a fresh workspace computes, bit for bit.
        let model = PfNet::new(PfNetConfig::compact(), 3).unwrap();
        let data = TestBatch::new(&model);
        let gradient = |pool: &Workspaces| {
            let mut grads = GradBuffers::default();
            model.batch_gradient(&data.batch(2), &LOSS, &mut grads, pool);
            grads.total
        };
        let warm = Workspaces::for_current_pool();
        model.batch_gradient(&data.batch(6), &LOSS, &mut GradBuffers::default(), &warm);
        assert_eq!(gradient(&warm), gradient(&Workspaces::for_current_pool()));
    }

    /// The compact network, and one whose laid scan has encoders of its own.
    fn with_and_without_scan_encoders() -> [PfNetConfig; 2] {
        let scan = ScanOnMap { grid_extent_m: 5.0, own_encoder: true };
        [PfNetConfig::compact(), PfNetConfig { scan_on_map: Some(scan), ..PfNetConfig::compact() }]
    }

    #[test]
    fn features_as_input_give_the_local_maps_gradient_with_a_frozen_map_encoder() {
        // Fed the map encoder's own outputs, a `Features` batch must see the same loss and the
        // same gradient for every weight after the encoder (the scan's encoders too: they are on
        // the observation's side), and none for the encoder's weights.
        for config in with_and_without_scan_encoders() {
            frozen_map_encoder_keeps_the_other_gradients(config);
        }
    }

    fn frozen_map_encoder_keeps_the_other_gradients(config: PfNetConfig) {
        let model = PfNet::new(config, 4).unwrap();
        let data = TestBatch::new(&model);
        let pool = Workspaces::for_current_pool();
        let mut features = vec![0.0; 24 * model.map_feature_len()];
        model.encode_local_maps_par(&data.maps, &mut features, &pool);
        let run = |batch: StepBatch| {
            let mut grads = GradBuffers::default();
            (model.batch_gradient(&batch, &LOSS, &mut grads, &pool), grads.total)
        };
        let (exact_loss, exact) = run(data.batch(3));
        let (feature_loss, frozen) = run(data.with_maps(&features, MapInput::Features, 3));
        assert_eq!(exact_loss, feature_loss);
        for (id, spec) in model.params.specs() {
            let (want, got) = (model.params.of(&exact, id), model.params.of(&frozen, id));
            if is_map_encoder_param(&spec.name) {
                assert!(got.iter().all(|&g| g == 0.0), "{}: the map encoder must get no gradient", spec.name);
            } else {
                assert_eq!(got, want, "{}", spec.name);
            }
        }
    }

    #[test]
    fn sequence_gradient_matches_finite_differences() {
        // The loss through accumulated weights, differentiated numerically in a head weight and
        // in weights of the laid scan's own encoders: in each tensor, the weight of the largest
        // gradient, so that the difference stands clear of the f32 forward's rounding. A
        // first-stage weight moves activations across ReLU and pool switches, so its step is
        // smaller, and that rounding then needs a wider tolerance.
        // With `map_context` the first stage reads its margin: its most dilated branch, which
        // reaches farthest into it.
        let [plain, scan] = with_and_without_scan_encoders();
        let laid = Some(ScanOnMap { grid_extent_m: 5.0, own_encoder: false });
        let context = PfNetConfig { scan_on_map: laid, map_context: true, ..PfNetConfig::compact() };
        let weights = [
            (plain, "j_out/kernel", 1e-2, 2e-2),
            (scan.clone(), "s_c5/kernel", 5e-4, 3e-2),
            (scan, "s2_c3/kernel", 5e-4, 3e-2),
            (context, "m_c7d3/kernel", 5e-4, 3e-2),
        ];
        for (config, name, h, tolerance) in weights {
            let model = PfNet::new(config, 2).unwrap();
            let data = TestBatch::new(&model);
            let (batch, loss) = (data.batch(3), LOSS);
            let (mut grads, pool) = (GradBuffers::default(), Workspaces::for_current_pool());
            model.batch_gradient(&batch, &loss, &mut grads, &pool);
            let range = model.params.range(model.params.find(name).unwrap());
            let at =
                range.clone().max_by(|&a, &b| grads.total[a].abs().total_cmp(&grads.total[b].abs())).unwrap();
            let shifted = |delta: f32| {
                let mut m = model.clone();
                m.params.values[at] += delta;
                m.batch_gradient(&batch, &loss, &mut GradBuffers::default(), &pool)
            };
            let numeric = (shifted(h) - shifted(-h)) / f64::from(2.0 * h);
            let analytic = f64::from(grads.total[at]);
            assert!(
                (numeric - analytic).abs() <= tolerance * numeric.abs().max(1e-6),
                "d loss / d {name}[{}]: analytic {analytic:e} vs numeric {numeric:e}",
                at - range.start
            );
        }
    }

    /// With a wide view of its own map encoder a particle's features are both encoders' side by
    /// side, and each encoder must get the gradient of its own half. As widening leaves it (the
    /// wide half unweighed), the paper encoder's gradient is the one-view network's and the wide
    /// one's zero; made symmetric (both local maps one image, the wide encoder the paper one's copy,
    /// as widening starts it, and both halves weighed alike) the two gradients are equal.
    #[test]
    fn each_map_encoder_gets_the_gradient_of_its_own_features() {
        let narrow = PfNet::new(PfNetConfig::compact(), 2).unwrap();
        let view = WideView { map_cell_m: 0.2, grid_extent_m: 10.0, own_map_encoder: true };
        let mut wide = narrow.with_wide_view(view).unwrap();
        let data = TestBatch::new(&narrow);
        let twice = |values: &[f32], len: usize| -> Vec<f32> {
            values.chunks(len).flat_map(|v| [v, v].concat()).collect()
        };
        let wide_data = TestBatch {
            obs: twice(&data.obs, narrow.obs_len()),
            maps: twice(&data.maps, narrow.local_map_len()),
            states: data.states.clone(),
            targets: data.targets.clone(),
        };
        let pool = Workspaces::for_current_pool();
        let gradient = |model: &PfNet, data: &TestBatch| {
            let mut grads = GradBuffers::default();
            model.batch_gradient(&data.batch(3), &LOSS, &mut grads, &pool);
            grads.total
        };
        let of = |model: &PfNet, grads: &[f32], name: &str| {
            grads[model.params.range(model.params.find(name).unwrap())].to_vec()
        };
        let assert_close = |a: &[f32], b: &[f32], what: &str| {
            let scale = b.iter().fold(0.0f32, |m, v| m.max(v.abs()));
            let worst = a.iter().zip(b).fold(0.0f32, |m, (x, y)| m.max((x - y).abs()));
            assert!(scale > 0.0 && worst <= 1e-4 * scale, "{what}: differ by {worst} at scale {scale}");
        };
        let names = ["m_c3/kernel", "m_c7d3/bias", "m_ln1/gamma", "m2_c5/kernel", "m_ln2/beta"];

        let (one_view, unweighed) = (gradient(&narrow, &data), gradient(&wide, &wide_data));
        for name in names {
            assert_close(&of(&wide, &unweighed, name), &of(&narrow, &one_view, name), name);
            let copy = format!("mw{}", &name[1..]);
            assert!(of(&wide, &unweighed, &copy).iter().all(|&g| g == 0.0), "{copy}: unweighed, no gradient");
        }

        let quarter = (narrow.config.local_map.cells / 2).pow(2);
        let fine = narrow.map_feature_len() / quarter;
        let channels = (wide.map_feature_len() + wide.obs_feature_len()) / quarter;
        for layer in ["j_lc3/kernel", "j_lc5/kernel"] {
            let id = wide.params.find(layer).unwrap();
            for tap in wide.params.get_mut(id).chunks_exact_mut(channels) {
                let (paper, rest) = tap.split_at_mut(fine);
                rest[..fine].copy_from_slice(paper);
            }
        }
        let symmetric = gradient(&wide, &wide_data);
        for name in names {
            let copy = format!("mw{}", &name[1..]);
            assert_close(&of(&wide, &symmetric, &copy), &of(&wide, &symmetric, name), &copy);
        }
    }
}
