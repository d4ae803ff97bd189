//! The actor's and critics' heads: dense layers with ReLU between them and a linear output.

use crate::nn::activation::{relu_backward, relu_forward};
use crate::nn::buffers::{sized, zeroed};
use crate::nn::dense::Dense;
use crate::nn::params::Params;
use crate::nn::sac::layer::WeightBias;
use std::ops::Range;

#[derive(Clone, Debug, PartialEq)]
pub struct Mlp {
    layers: Vec<(Dense, WeightBias)>,
}

/// Outputs of every layer of one forward pass (post-ReLU for hidden layers), and the backward's
/// buffers, reused across calls.
#[derive(Clone, Debug, Default)]
pub struct MlpActivations {
    outputs: Vec<Vec<f32>>,
    d_out: Vec<f32>,
    d_in: Vec<f32>,
}

impl MlpActivations {
    /// The last layer's output, `[n][outputs]`.
    pub fn output(&self) -> &[f32] {
        self.outputs.last().expect("forward ran")
    }
}

impl Mlp {
    /// `sizes` = [inputs, hidden…, outputs]; tensors `name/dense{i}`.
    pub fn new(params: &mut Params, name: &str, sizes: &[usize]) -> Self {
        let layers = sizes
            .windows(2)
            .enumerate()
            .map(|(i, io)| {
                let wb = WeightBias::add(params, &format!("{name}/dense{i}"), &[io[0], io[1]], io[1]);
                (Dense { inputs: io[0], outputs: io[1] }, wb)
            })
            .collect();
        Self { layers }
    }

    pub fn inputs(&self) -> usize {
        self.layers[0].0.inputs
    }

    /// Where the MLP's tensors lie in the arena: one run, added in order by `new`.
    pub fn params(&self) -> Range<usize> {
        let first = &self.layers.first().expect("at least one layer").1;
        let last = &self.layers.last().expect("at least one layer").1;
        first.weight.start..last.bias.end
    }

    pub fn init(&self, params: &mut Params, rng: &mut impl rand::Rng) {
        for (d, wb) in &self.layers {
            wb.init(params, d.inputs, d.outputs, rng);
        }
    }

    /// `x`: `[n][inputs]`.
    pub fn forward(&self, values: &[f32], x: &[f32], n: usize, acts: &mut MlpActivations) {
        acts.outputs.resize(self.layers.len(), Vec::new());
        let last = self.layers.len() - 1;
        for (i, (d, wb)) in self.layers.iter().enumerate() {
            let (done, rest) = acts.outputs.split_at_mut(i);
            let input = if i == 0 { x } else { &done[i - 1] };
            let y = &mut rest[0];
            y.resize(n * d.outputs, 0.0);
            d.forward(wb.weight(values), wb.bias(values), input, n, y);
            if i < last {
                relu_forward(y);
            }
        }
    }

    /// Backpropagates `d_output` (gradient w.r.t. the last layer's output). Accumulates the
    /// weights' gradients into `grads` when given (the MLP's own part of the arena's gradient,
    /// `[self.params()]`, so networks can write theirs side by side; None: the weights are frozen)
    /// and the input's into `dx` when given.
    #[allow(clippy::too_many_arguments)]
    pub fn backward(
        &self,
        values: &[f32],
        x: &[f32],
        n: usize,
        acts: &mut MlpActivations,
        d_output: &[f32],
        mut grads: Option<&mut [f32]>,
        dx: Option<&mut [f32]>,
    ) {
        let MlpActivations { outputs, d_out, d_in } = acts;
        let first = self.params().start;
        if let Some(g) = grads.as_deref() {
            assert_eq!(g.len(), self.params().len(), "grads: the MLP's own part of the gradient");
        }
        d_out.clear();
        d_out.extend_from_slice(d_output);
        for (i, (d, wb)) in self.layers.iter().enumerate().rev() {
            let input = if i == 0 { x } else { &outputs[i - 1] };
            zeroed(d_in, n * d.inputs);
            let w = wb.weight(values);
            match grads.as_deref_mut() {
                Some(g) => {
                    let (dw, db) = wb.split_mut_from(g, first);
                    d.backward(w, input, n, d_out, dw, db, Some(d_in));
                }
                None => d.backward_input(w, n, d_out, d_in),
            }
            if i == 0 {
                break;
            }
            // Through the ReLU of the layer below: d_out ← d_in · [y > 0].
            sized(d_out, d_in.len());
            relu_backward(input, d_in, d_out);
        }
        if let Some(dx) = dx {
            dx.iter_mut().zip(d_in.iter()).for_each(|(a, b)| *a += b);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::nn::gradcheck::{assert_close, numerical_grad, test_values};

    #[test]
    fn backward_matches_finite_differences_with_and_without_weight_grads() {
        // Another tensor first, so the MLP's gradient slice starts past the arena's start.
        let mut params = Params::new();
        params.add("before", &[3]);
        let mlp = Mlp::new(&mut params, "mlp", &[5, 6, 4, 2]);
        params.values = [vec![0.0; 3], test_values(mlp.params().len(), 3)].concat();
        let n = 3;
        let x = test_values(n * 5, 4);
        let r = test_values(n * 2, 5);
        let loss = |values: &[f32], x: &[f32]| -> f64 {
            let mut a = MlpActivations::default();
            mlp.forward(values, x, n, &mut a);
            a.output().iter().zip(&r).map(|(y, r)| f64::from(y * r)).sum()
        };
        let mut acts = MlpActivations::default();
        mlp.forward(&params.values, &x, n, &mut acts);
        let (mut grads, mut dx) = (vec![0.0; mlp.params().len()], vec![0.0; x.len()]);
        mlp.backward(&params.values, &x, n, &mut acts, &r, Some(&mut grads), Some(&mut dx));
        let f64s = |v: &[f32]| v.iter().map(|&a| f64::from(a)).collect::<Vec<_>>();
        let f32s = |v: &[f64]| v.iter().map(|&a| a as f32).collect::<Vec<_>>();
        let numeric = numerical_grad(&f64s(&params.values), 1e-2, |v| loss(&f32s(v), &x));
        assert_close(&grads, &numeric[mlp.params()], 1e-2, "mlp weight gradient");
        let numeric_x = numerical_grad(&f64s(&x), 1e-2, |v| loss(&params.values, &f32s(v)));
        assert_close(&dx, &numeric_x, 1e-2, "mlp input gradient");

        let mut dx_frozen = vec![0.0; x.len()];
        mlp.backward(&params.values, &x, n, &mut acts, &r, None, Some(&mut dx_frozen));
        assert_eq!(dx_frozen, dx, "frozen weights give the same input gradient");
    }
}
