//! A layer's weight and bias as ranges of the parameter arena, so one network definition runs
//! on the online weights, the target copy and the gradient buffer alike.

use crate::nn::params::{ParamId, Params};
use std::ops::Range;

#[derive(Clone, Debug, PartialEq)]
pub struct WeightBias {
    pub weight_id: ParamId,
    pub bias_id: ParamId,
    pub weight: Range<usize>,
    pub bias: Range<usize>,
}

impl WeightBias {
    /// Adds `name/kernel` and `name/bias` to the arena, in that order (the bias right after the
    /// weight, which [`WeightBias::split_mut`] relies on).
    pub fn add(params: &mut Params, name: &str, kernel_shape: &[usize], outputs: usize) -> Self {
        let weight_id = params.add(&format!("{name}/kernel"), kernel_shape);
        let bias_id = params.add(&format!("{name}/bias"), &[outputs]);
        Self { weight_id, bias_id, weight: params.range(weight_id), bias: params.range(bias_id) }
    }

    pub fn weight<'a>(&self, values: &'a [f32]) -> &'a [f32] {
        &values[self.weight.clone()]
    }

    pub fn bias<'a>(&self, values: &'a [f32]) -> &'a [f32] {
        &values[self.bias.clone()]
    }

    /// The weight's and the bias's gradients, borrowed together.
    pub fn split_mut<'a>(&self, grads: &'a mut [f32]) -> (&'a mut [f32], &'a mut [f32]) {
        self.split_mut_from(grads, 0)
    }

    /// `split_mut` of a gradient slice that starts at arena index `first` (a network's own part).
    pub fn split_mut_from<'a>(&self, grads: &'a mut [f32], first: usize) -> (&'a mut [f32], &'a mut [f32]) {
        debug_assert_eq!(self.weight.end, self.bias.start, "bias must follow its weight");
        grads[self.weight.start - first..self.bias.end - first].split_at_mut(self.weight.len())
    }

    /// Glorot-uniform weights (`fan_in`, `fan_out` as Keras counts them), zero bias.
    pub fn init(&self, params: &mut Params, fan_in: usize, fan_out: usize, rng: &mut impl rand::Rng) {
        params.fill_uniform(self.weight_id, (6.0 / (fan_in + fan_out) as f32).sqrt(), rng);
        params.fill(self.bias_id, 0.0);
    }
}
