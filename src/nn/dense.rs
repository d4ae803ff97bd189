//! Fully-connected layer `y = x·W + b` (SAC's MLPs, PF-net's head): one GEMM each way.

use crate::nn::gemm::{MatMut, MatRef, matmul};

/// Weight `[inputs][outputs]` (Keras layout), bias `[outputs]`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Dense {
    pub inputs: usize,
    pub outputs: usize,
}

impl Dense {
    /// x: `[n][inputs]` → y: `[n][outputs]` (overwritten). No activation.
    pub fn forward(&self, weight: &[f32], bias: &[f32], x: &[f32], n: usize, y: &mut [f32]) {
        let (i, o) = (self.inputs, self.outputs);
        assert_eq!(weight.len(), i * o, "weight length");
        assert_eq!(bias.len(), o, "bias length");
        assert_eq!(x.len(), n * i, "x length");
        assert_eq!(y.len(), n * o, "y length");
        // Start from the bias so the GEMM can accumulate onto it.
        for row in y.chunks_exact_mut(o.max(1)) {
            row.copy_from_slice(bias);
        }
        matmul(MatMut::row_major(y, n, o), MatRef::row_major(x, n, i), MatRef::row_major(weight, i, o), true);
    }

    /// Accumulates `dweight += xᵀ·dy`, `dbias += Σ_n dy`, `dx += dy·Wᵀ` (if given).
    #[allow(clippy::too_many_arguments)]
    pub fn backward(
        &self,
        weight: &[f32],
        x: &[f32],
        n: usize,
        dy: &[f32],
        dweight: &mut [f32],
        dbias: &mut [f32],
        dx: Option<&mut [f32]>,
    ) {
        let (i, o) = (self.inputs, self.outputs);
        assert_eq!(weight.len(), i * o, "weight length");
        assert_eq!(x.len(), n * i, "x length");
        assert_eq!(dy.len(), n * o, "dy length");
        assert_eq!(dweight.len(), i * o, "dweight length");
        assert_eq!(dbias.len(), o, "dbias length");
        matmul(
            MatMut::row_major(dweight, i, o),
            MatRef::row_major(x, n, i).t(),
            MatRef::row_major(dy, n, o),
            true,
        );
        for row in dy.chunks_exact(o.max(1)) {
            for (b, &d) in dbias.iter_mut().zip(row) {
                *b += d;
            }
        }
        if let Some(dx) = dx {
            self.backward_input(weight, n, dy, dx);
        }
    }

    /// Accumulates only `dx += dy·Wᵀ`: backpropagating through a layer whose weights are frozen
    /// (SAC's actor loss flows through the critics without training them).
    pub fn backward_input(&self, weight: &[f32], n: usize, dy: &[f32], dx: &mut [f32]) {
        let (i, o) = (self.inputs, self.outputs);
        assert_eq!(weight.len(), i * o, "weight length");
        assert_eq!(dy.len(), n * o, "dy length");
        assert_eq!(dx.len(), n * i, "dx length");
        let dy_m = MatRef::row_major(dy, n, o);
        matmul(MatMut::row_major(dx, n, i), dy_m, MatRef::row_major(weight, i, o).t(), true);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::nn::gradcheck::{assert_close, numerical_grad, test_values};

    fn to64(v: &[f32]) -> Vec<f64> {
        v.iter().map(|&a| f64::from(a)).collect()
    }

    fn naive(d: Dense, w: &[f64], b: &[f64], x: &[f64], n: usize) -> Vec<f64> {
        let mut y = vec![0.0; n * d.outputs];
        for s in 0..n {
            for o in 0..d.outputs {
                y[s * d.outputs + o] =
                    b[o] + (0..d.inputs).map(|i| x[s * d.inputs + i] * w[i * d.outputs + o]).sum::<f64>();
            }
        }
        y
    }

    #[test]
    fn forward_and_backward_match_naive_and_finite_differences() {
        let (d, n) = (Dense { inputs: 7, outputs: 5 }, 3);
        let (w, b, x) = (test_values(35, 1), test_values(5, 2), test_values(21, 3));
        let r = test_values(15, 4);
        let mut y = vec![9.0; 15];
        d.forward(&w, &b, &x, n, &mut y);
        assert_close(&y, &naive(d, &to64(&w), &to64(&b), &to64(&x), n), 1e-5, "dense forward");

        let (mut dw, mut db, mut dx) = (vec![0.0; 35], vec![0.0; 5], vec![0.0; 21]);
        d.backward(&w, &x, n, &r, &mut dw, &mut db, Some(&mut dx));
        let (w64, b64, x64, r64) = (to64(&w), to64(&b), to64(&x), to64(&r));
        let loss = |w: &[f64], b: &[f64], x: &[f64]| -> f64 {
            naive(d, w, b, x, n).iter().zip(&r64).map(|(y, r)| y * r).sum()
        };
        assert_close(&dw, &numerical_grad(&w64, 1e-3, |w| loss(w, &b64, &x64)), 1e-4, "dense dweight");
        assert_close(&db, &numerical_grad(&b64, 1e-3, |b| loss(&w64, b, &x64)), 1e-4, "dense dbias");
        assert_close(&dx, &numerical_grad(&x64, 1e-3, |x| loss(&w64, &b64, x)), 1e-4, "dense dx");

        // Backward accumulates: a second call doubles every gradient (dx may be None).
        let (dw1, db1, dx1) = (dw.clone(), db.clone(), dx.clone());
        d.backward(&w, &x, n, &r, &mut dw, &mut db, Some(&mut dx));
        for (got, once) in [(&dw, &dw1), (&db, &db1), (&dx, &dx1)] {
            assert!(got.iter().zip(once).all(|(g, o)| (g - 2.0 * o).abs() <= 1e-5 * (1.0 + o.abs())));
        }
        d.backward(&w, &x, n, &r, &mut dw, &mut db, None);
        assert!(dw.iter().zip(&dw1).all(|(g, o)| (g - 3.0 * o).abs() <= 1e-5 * (1.0 + o.abs())));
    }
}
