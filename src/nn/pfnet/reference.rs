//! The Keras reference implementation's weights and its check case (`pfnet_oracle/`): layout
//! conversion into ours, and the comparison `apfn pfnet verify` prints.

use super::config::PfNetConfig;
use super::loss::PoseLoss;
use super::model::{PfNet, Workspace};
use crate::nn::checkpoint::{Checkpoint, CheckpointError};
use crate::nn::conv::weight_from_hwio;
use crate::nn::locally_connected::weight_from_keras;
use std::path::{Path, PathBuf};

/// What went wrong reading the reference folder.
#[derive(Debug, thiserror::Error)]
pub enum ReferenceError {
    #[error(transparent)]
    Checkpoint(#[from] CheckpointError),
    #[error("{path}: tensor '{name}' {problem}")]
    Tensor { path: PathBuf, name: String, problem: String },
}

/// How far our network is from the reference on its case.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct VerifyReport {
    pub loglik_max_abs_err: f64,
    pub loss_rel_err: f64,
    pub grad_rel_err_max: f64,
    /// The parameter whose gradient is farthest off.
    pub worst_grad: String,
}

/// Converts a tensor from the reference's layout (`keras_shape`) to ours, by the name's kind:
/// conv kernels HWIO → OIHW, locally-connected kernels [pos][patch][f] → [pos][f][patch], the
/// head's kernel from (h, w, c) flattening to our (c, h, w); everything else is shared.
pub fn from_keras_layout(name: &str, keras_shape: &[usize], data: &[f32]) -> Vec<f32> {
    match (name, keras_shape) {
        (n, &[kh, _, c_in, c_out]) if n.ends_with("/kernel") => weight_from_hwio(data, kh, c_in, c_out),
        (n, &[positions, patch, filters]) if n.ends_with("/kernel") => {
            weight_from_keras(data, positions, patch, filters)
        }
        ("j_out/kernel", &[inputs, 1]) => {
            // 5 × 5 × 16 in (h, w, c) order → (c, h, w).
            let channels = 16.min(inputs);
            let side = ((inputs / channels) as f64).sqrt() as usize;
            let mut out = vec![0.0; inputs];
            for h in 0..side {
                for w in 0..side {
                    for c in 0..channels {
                        out[(c * side + h) * side + w] = data[(h * side + w) * channels + c];
                    }
                }
            }
            out
        }
        _ => data.to_vec(),
    }
}

/// The paper network with the reference's weights (`weights.safetensors` in Keras layout).
pub fn load_reference_model(dir: &Path) -> Result<PfNet, ReferenceError> {
    let path = dir.join("weights.safetensors");
    let weights = Checkpoint::load(&path)?;
    let mut model = PfNet::new(PfNetConfig::paper(), 0).expect("the paper configuration is valid");
    let mut values = std::mem::take(&mut model.params.values);
    read_keras_buffer(&model, &weights, "", &path, &mut values)?;
    model.params.values = values;
    Ok(model)
}

/// Every parameter of `model` from tensors `prefix + name` in Keras layout, into `buf`.
fn read_keras_buffer(
    model: &PfNet,
    file: &Checkpoint,
    prefix: &str,
    path: &Path,
    buf: &mut [f32],
) -> Result<(), ReferenceError> {
    for (id, spec) in model.params.specs() {
        let name = format!("{prefix}{}", spec.name);
        let problem =
            |problem: String| ReferenceError::Tensor { path: path.into(), name: name.clone(), problem };
        let tensor = file.tensor(&name).ok_or_else(|| problem("is missing".into()))?;
        let want: usize = spec.shape.iter().product();
        if tensor.data.len() != want {
            return Err(problem(format!(
                "has shape {:?}, expected {} values like {:?}",
                tensor.shape, want, spec.shape
            )));
        }
        let range = model.params.range(id);
        buf[range].copy_from_slice(&from_keras_layout(&spec.name, &tensor.shape, &tensor.data));
    }
    Ok(())
}

/// Runs the reference case through our network and compares outputs, loss and every gradient.
pub fn verify(dir: &Path) -> Result<VerifyReport, ReferenceError> {
    let model = load_reference_model(dir)?;
    let path = dir.join("case.safetensors");
    let case = Checkpoint::load(&path)?;
    let get = |name: &str| {
        case.tensor(name).ok_or_else(|| ReferenceError::Tensor {
            path: path.clone(),
            name: name.into(),
            problem: "is missing".into(),
        })
    };
    let (obs, maps, states, targets) = (get("obs")?, get("local_maps")?, get("states")?, get("targets")?);
    let (want_loglik, want_loss) = (get("loglik")?, get("loss")?);
    let (steps, k) = (maps.shape[0], maps.shape[1]);
    let loss =
        PoseLoss { weights: [1.0; 3], wrap_heading: false, scale: 1.0 / (steps * 3) as f32, mixture: None };

    let mut grads = vec![0.0; model.params.len()];
    let mut ws = Workspace::default();
    let (mut total_loss, mut loglik_err) = (0.0, 0.0f64);
    for step in 0..steps {
        let particle_states: Vec<[f32; 3]> =
            (0..k).map(|i| std::array::from_fn(|c| states.data[(step * k + i) * 3 + c])).collect();
        let target = std::array::from_fn(|c| targets.data[step * 3 + c]);
        let step_obs = &obs.data[step * model.obs_len()..(step + 1) * model.obs_len()];
        let step_maps = &maps.data[step * k * model.local_map_len()..(step + 1) * k * model.local_map_len()];
        total_loss += model.step_gradient(
            step_obs,
            step_maps,
            k,
            |loglik| {
                for (i, &l) in loglik.iter().enumerate() {
                    loglik_err = loglik_err.max(f64::from((l - want_loglik.data[step * k + i]).abs()));
                }
                loss.evaluate(loglik, &particle_states, target)
            },
            &mut grads,
            &mut ws,
        );
    }

    let mut want_grads = vec![0.0; model.params.len()];
    read_keras_buffer(&model, &case, "grad/", &path, &mut want_grads)?;
    // The head's bias gets no gradient in exact arithmetic (the softmax ignores a shift of every
    // log-likelihood), so the reference holds float noise there (≈ 2e-9): relative errors are
    // taken against at least 1e-4 of the whole gradient's norm, not against noise.
    let floor = 1e-4 * norm(&want_grads);
    let (mut grad_rel_err_max, mut worst_grad) = (0.0, String::new());
    for (id, spec) in model.params.specs() {
        let (got, want) = (model.params.of(&grads, id), model.params.of(&want_grads, id));
        let diff: Vec<f32> = got.iter().zip(want).map(|(g, w)| g - w).collect();
        let err = norm(&diff) / norm(want).max(floor);
        if err > grad_rel_err_max {
            (grad_rel_err_max, worst_grad) = (err, spec.name.clone());
        }
    }
    let want_loss = f64::from(want_loss.data[0]);
    Ok(VerifyReport {
        loglik_max_abs_err: loglik_err,
        loss_rel_err: (total_loss - want_loss).abs() / want_loss.abs().max(1e-30),
        grad_rel_err_max,
        worst_grad,
    })
}

fn norm(values: &[f32]) -> f64 {
    values.iter().map(|&v| f64::from(v).powi(2)).sum::<f64>().sqrt()
}
