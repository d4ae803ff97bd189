//! One supervised training step of PF-net, as in the paper: a batch of B sequences × T filter
//! steps × K particles → loss → gradients → Adam. Filter steps are split into fixed tasks whose
//! gradients are summed in task order, so the bytes do not depend on the thread count.

use super::batch::Workspaces;
use super::loss::PoseLoss;
use super::model::PfNet;
use crate::nn::adam::Adam;
use rayon::prelude::*;

/// Filter steps per parallel task (each task owns one gradient buffer).
pub const STEPS_PER_TASK: usize = 8;

/// A training batch, flattened over B × T filter steps.
#[derive(Clone, Copy, Debug)]
pub struct StepBatch<'a> {
    /// [steps][obs_len]
    pub obs: &'a [f32],
    /// [steps][k][local_map_len]
    pub maps: &'a [f32],
    /// [steps][k] particle poses (x, y, θ)
    pub states: &'a [[f32; 3]],
    /// [steps] true poses
    pub targets: &'a [[f32; 3]],
    /// Particles per step.
    pub k: usize,
}

impl StepBatch<'_> {
    pub fn steps(&self) -> usize {
        self.targets.len()
    }
}

/// Gradient buffers, one per task, kept between steps.
#[derive(Clone, Debug, Default)]
pub struct GradBuffers {
    tasks: Vec<Vec<f32>>,
    /// The batch's gradient (sum over tasks), laid out like the parameters.
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
        let (steps, k) = (batch.steps(), batch.k);
        let (obs_len, map_len) = (self.obs_len(), self.local_map_len() * k);
        let tasks = steps.div_ceil(STEPS_PER_TASK);
        grads.tasks.resize_with(tasks, Vec::new);
        let losses: Vec<f64> = grads
            .tasks
            .par_iter_mut()
            .enumerate()
            .map(|(task, buffer)| {
                buffer.clear();
                buffer.resize(self.params.len(), 0.0);
                let range = task * STEPS_PER_TASK..((task + 1) * STEPS_PER_TASK).min(steps);
                pool.with(|ws| {
                    range
                        .map(|s| {
                            let obs = &batch.obs[s * obs_len..(s + 1) * obs_len];
                            let maps = &batch.maps[s * map_len..(s + 1) * map_len];
                            let states = &batch.states[s * k..(s + 1) * k];
                            let target = batch.targets[s];
                            self.step_gradient(
                                obs,
                                maps,
                                k,
                                |ll| loss.evaluate(ll, states, target),
                                buffer,
                                ws,
                            )
                        })
                        .sum()
                })
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
