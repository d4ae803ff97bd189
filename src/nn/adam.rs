//! Adam with bias correction in Keras's formulation (the reference model was trained with Keras):
//! t += 1; m = β1·m + (1−β1)·g; v = β2·v + (1−β2)·g²;
//! p −= lr·sqrt(1−β2^t)/(1−β1^t) · m / (sqrt(v) + ε).
//! Note ε is added to sqrt(v) *before* bias correction, unlike the paper's ε̂.

use crate::nn::PARALLEL_SLICE;
use rayon::prelude::*;

/// Hyper-parameters; defaults are Keras's.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct AdamConfig {
    pub learning_rate: f32,
    pub beta1: f32,
    pub beta2: f32,
    pub epsilon: f32,
}

impl Default for AdamConfig {
    fn default() -> Self {
        Self { learning_rate: 1e-3, beta1: 0.9, beta2: 0.999, epsilon: 1e-7 }
    }
}

impl AdamConfig {
    /// `Err("field: expected …")` for values with which Adam diverges or divides by zero.
    pub fn check(&self) -> Result<(), String> {
        let positive = |v: f32| v > 0.0 && v.is_finite();
        if !positive(self.learning_rate) {
            return Err(format!("learning_rate: expected a positive number, found {}", self.learning_rate));
        }
        for (field, beta) in [("beta1", self.beta1), ("beta2", self.beta2)] {
            if !(0.0..1.0).contains(&beta) {
                return Err(format!("{field}: expected a decay rate in [0, 1), found {beta}"));
            }
        }
        if !positive(self.epsilon) {
            return Err(format!("epsilon: expected a positive number, found {}", self.epsilon));
        }
        Ok(())
    }
}

/// Optimizer state over a whole parameter arena: `m` and `v` are laid out like `Params::values`.
#[derive(Clone, Debug, PartialEq)]
pub struct Adam {
    pub config: AdamConfig,
    /// Number of updates done so far (Keras's `iterations`); the next update uses t = step + 1.
    pub step: u64,
    pub m: Vec<f32>,
    pub v: Vec<f32>,
}

impl Adam {
    pub fn new(config: AdamConfig, len: usize) -> Self {
        Self { config, step: 0, m: vec![0.0; len], v: vec![0.0; len] }
    }

    /// One step over the whole arena: `values` and `grads` are laid out like `m` and `v`.
    pub fn update(&mut self, values: &mut [f32], grads: &[f32]) {
        let n = self.m.len();
        assert!(
            values.len() == n && grads.len() == n && self.v.len() == n,
            "Adam::update: values {}, grads {}, m {}, v {} must all have the same length",
            values.len(),
            grads.len(),
            n,
            self.v.len()
        );
        self.step += 1;
        let AdamConfig { learning_rate, beta1, beta2, epsilon } = self.config;
        // Bias correction in f64: β^t for large t loses digits in f32.
        let t = self.step as f64;
        let (b1, b2) = (f64::from(beta1), f64::from(beta2));
        let lr_t = (f64::from(learning_rate) * (1.0 - b2.powf(t)).sqrt() / (1.0 - b1.powf(t))) as f32;
        let step = Step { lr_t, beta1, beta2, epsilon };
        // Fixed-size slices, so the thread count never changes which element goes where (and
        // each element's arithmetic is its own: the bytes are the same on any number of threads).
        values
            .par_chunks_mut(PARALLEL_SLICE)
            .zip(grads.par_chunks(PARALLEL_SLICE))
            .zip(self.m.par_chunks_mut(PARALLEL_SLICE))
            .zip(self.v.par_chunks_mut(PARALLEL_SLICE))
            .for_each(|(((p, g), m), v)| step.apply(p, g, m, v));
    }
}

/// One step's factors.
#[derive(Clone, Copy)]
struct Step {
    lr_t: f32,
    beta1: f32,
    beta2: f32,
    epsilon: f32,
}

impl Step {
    fn apply(self, p: &mut [f32], g: &[f32], m: &mut [f32], v: &mut [f32]) {
        #[cfg(target_arch = "x86_64")]
        if is_x86_feature_detected!("avx512f") {
            // SAFETY: the CPU has AVX-512F.
            return unsafe { self.apply_avx512(p, g, m, v) };
        }
        self.apply_impl(p, g, m, v);
    }

    /// Compiled for AVX-512 (the crate's baseline is SSE2); IEEE square root and division give
    /// the same bits at any vector width.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx512f")]
    fn apply_avx512(self, p: &mut [f32], g: &[f32], m: &mut [f32], v: &mut [f32]) {
        self.apply_impl(p, g, m, v);
    }

    #[inline(always)]
    fn apply_impl(self, p: &mut [f32], g: &[f32], m: &mut [f32], v: &mut [f32]) {
        let Self { lr_t, beta1, beta2, epsilon } = self;
        let (one_m_b1, one_m_b2) = (1.0 - beta1, 1.0 - beta2);
        for (((p, &g), m), v) in p.iter_mut().zip(g).zip(m).zip(v) {
            *m = beta1 * *m + one_m_b1 * g;
            *v = beta2 * *v + one_m_b2 * g * g;
            *p -= lr_t * *m / (v.sqrt() + epsilon);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The formula written out in f64, one scalar at a time.
    fn reference(cfg: &AdamConfig, p0: f64, grads: &[f64]) -> Vec<f64> {
        let (lr, b1, b2, eps) =
            (cfg.learning_rate as f64, cfg.beta1 as f64, cfg.beta2 as f64, cfg.epsilon as f64);
        let (mut p, mut m, mut v) = (p0, 0.0, 0.0);
        let mut out = vec![];
        for (i, &g) in grads.iter().enumerate() {
            let t = (i + 1) as i32;
            m = b1 * m + (1.0 - b1) * g;
            v = b2 * v + (1.0 - b2) * g * g;
            p -= lr * (1.0 - b2.powi(t)).sqrt() / (1.0 - b1.powi(t)) * m / (v.sqrt() + eps);
            out.push(p);
        }
        out
    }

    #[test]
    fn two_steps_match_formula() {
        let cfg = AdamConfig { learning_rate: 0.1, beta1: 0.8, beta2: 0.9, epsilon: 1e-3 };
        let mut adam = Adam::new(cfg.clone(), 3);
        let mut p = vec![1.0f32, -2.0, 0.5];
        let g1 = [0.5f32, -1.0, 0.0];
        let g2 = [0.25f32, 3.0, -2.0];
        adam.update(&mut p, &g1);
        adam.update(&mut p, &g2);
        assert_eq!(adam.step, 2);
        for i in 0..3 {
            let want = reference(&cfg, [1.0, -2.0, 0.5][i], &[g1[i] as f64, g2[i] as f64]);
            assert!((p[i] as f64 - want[1]).abs() < 1e-6, "param {i}: {} vs {}", p[i], want[1]);
        }
        // Hand-computed for param 0, step 1: m = 0.1, v = 0.025, lr_t = 0.1·sqrt(0.1)/0.2,
        // p = 1 − lr_t · 0.1 / (sqrt(0.025) + 1e-3).
        let mut q = [1.0f32];
        Adam::new(cfg, 1).update(&mut q, &[0.5]);
        let lr_t = 0.1 * 0.1f64.sqrt() / 0.2;
        let want = 1.0 - lr_t * 0.1 / (0.025f64.sqrt() + 1e-3);
        assert!((q[0] as f64 - want).abs() < 1e-6, "{} vs {want}", q[0]);
    }

    #[test]
    fn minimises_a_quadratic() {
        // f(p) = Σ a_i (p_i − c_i)², gradient 2 a_i (p_i − c_i); badly scaled on purpose.
        let a = [1.0f32, 10.0, 0.1, 3.0];
        let c = [0.5f32, -1.5, 2.0, 0.0];
        let mut p = vec![0.0f32, 0.0, 0.0, 3.0];
        let mut adam = Adam::new(AdamConfig { learning_rate: 0.05, ..Default::default() }, 4);
        let mut g = vec![0.0; 4];
        for _ in 0..500 {
            for i in 0..4 {
                g[i] = 2.0 * a[i] * (p[i] - c[i]);
            }
            adam.update(&mut p, &g);
        }
        for i in 0..4 {
            assert!((p[i] - c[i]).abs() < 1e-2, "p[{i}] = {} not near {}", p[i], c[i]);
        }
    }

    #[test]
    fn config_defaults_and_strict_fields() {
        let cfg: AdamConfig = serde_json::from_str(r#"{"learning_rate": 0.01}"#).unwrap();
        assert_eq!(cfg, AdamConfig { learning_rate: 0.01, ..AdamConfig::default() });
        assert_eq!(AdamConfig::default().epsilon, 1e-7);
        assert!(serde_json::from_str::<AdamConfig>(r#"{"lr": 0.01}"#).is_err());
        assert_eq!(AdamConfig::default().check(), Ok(()));
        let err = |c: AdamConfig| c.check().unwrap_err();
        assert_eq!(
            err(AdamConfig { beta2: 1.0, ..cfg.clone() }),
            "beta2: expected a decay rate in [0, 1), found 1"
        );
        assert_eq!(
            err(AdamConfig { epsilon: 0.0, ..cfg.clone() }),
            "epsilon: expected a positive number, found 0"
        );
        assert_eq!(
            err(AdamConfig { learning_rate: f32::NAN, ..cfg }),
            "learning_rate: expected a positive number, found NaN"
        );
    }

    #[test]
    #[should_panic(expected = "same length")]
    fn length_mismatch_panics() {
        Adam::new(AdamConfig::default(), 2).update(&mut [0.0; 2], &[0.0; 3]);
    }
}
