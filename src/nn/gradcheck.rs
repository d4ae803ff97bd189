//! Test support for the layers: central finite differences in f64 and a norm-relative comparison.

/// d f / d x by central differences with step `h`, every coordinate of `x`.
pub fn numerical_grad(x: &[f64], h: f64, f: impl Fn(&[f64]) -> f64) -> Vec<f64> {
    let mut probe = x.to_vec();
    (0..x.len())
        .map(|i| {
            probe[i] = x[i] + h;
            let up = f(&probe);
            probe[i] = x[i] - h;
            let down = f(&probe);
            probe[i] = x[i];
            (up - down) / (2.0 * h)
        })
        .collect()
}

/// ‖got − want‖ / max(‖want‖, 1e-12), the measure the oracle check uses too.
pub fn relative_error(got: &[f32], want: &[f64]) -> f64 {
    assert_eq!(got.len(), want.len(), "lengths differ");
    let diff: f64 = got.iter().zip(want).map(|(&g, &w)| (f64::from(g) - w).powi(2)).sum();
    let norm: f64 = want.iter().map(|w| w * w).sum();
    diff.sqrt() / norm.sqrt().max(1e-12)
}

/// Panics with `what` unless `relative_error(got, want) ≤ tol`.
pub fn assert_close(got: &[f32], want: &[f64], tol: f64, what: &str) {
    let err = relative_error(got, want);
    assert!(err <= tol, "{what}: relative error {err:.3e} > {tol:.1e}");
}

/// Deterministic pseudo-random values in [-1, 1) for test inputs (a tiny LCG: tests need no RNG crate).
pub fn test_values(n: usize, seed: u64) -> Vec<f32> {
    let mut s = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
    (0..n)
        .map(|_| {
            s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            ((s >> 40) as f32 / (1u64 << 24) as f32) * 2.0 - 1.0
        })
        .collect()
}
