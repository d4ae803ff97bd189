//! Exact Euclidean distance transform on a grid (Felzenszwalb & Huttenlocher, "Distance
//! Transforms of Sampled Functions", 2012): the one kernel behind the traversable map's erosion
//! and the likelihood field's distances.

/// Squared Euclidean distance, in cells², from every cell centre to the nearest cell for which
/// `is_source(index)` holds; `f32::INFINITY` when there is none. Felzenszwalb & Huttenlocher's
/// lower envelope of parabolas, along rows then along columns: O(cells), exact.
pub(super) fn squared_edt(w: usize, h: usize, is_source: impl Fn(usize) -> bool) -> Vec<f32> {
    let mut grid: Vec<f32> = (0..w * h).map(|k| if is_source(k) { 0.0 } else { f32::INFINITY }).collect();
    let mut scratch = Envelope::default();
    let (mut f, mut d) = (vec![0.0f32; w.max(h)], vec![0.0f32; w.max(h)]);
    for row in grid.chunks_exact_mut(w.max(1)) {
        f[..w].copy_from_slice(row);
        scratch.transform(&f[..w], &mut d[..w]);
        row.copy_from_slice(&d[..w]);
    }
    for i in 0..w {
        for j in 0..h {
            f[j] = grid[j * w + i];
        }
        scratch.transform(&f[..h], &mut d[..h]);
        for j in 0..h {
            grid[j * w + i] = d[j];
        }
    }
    grid
}

/// Reusable buffers of the 1D transform: parabola vertices and the left end of each one's reign.
#[derive(Default)]
struct Envelope {
    vertex: Vec<usize>,
    start: Vec<f64>,
}

impl Envelope {
    /// `d[q] = min_p (q − p)² + f[p]` over the finite `f[p]`; infinite where none is finite.
    fn transform(&mut self, f: &[f32], d: &mut [f32]) {
        let (v, z) = (&mut self.vertex, &mut self.start);
        v.clear();
        z.clear();
        let lifted = |p: usize| f64::from(f[p]) + (p * p) as f64;
        for q in (0..f.len()).filter(|&q| f[q].is_finite()) {
            loop {
                let Some(&p) = v.last() else {
                    v.push(q);
                    z.push(f64::NEG_INFINITY);
                    break;
                };
                let s = (lifted(q) - lifted(p)) / (2.0 * (q - p) as f64);
                if z.last().is_some_and(|&zl| s <= zl) {
                    v.pop();
                    z.pop();
                } else {
                    v.push(q);
                    z.push(s);
                    break;
                }
            }
        }
        if v.is_empty() {
            d.fill(f32::INFINITY);
            return;
        }
        let mut k = 0;
        for (q, out) in d.iter_mut().enumerate() {
            while k + 1 < v.len() && z[k + 1] < q as f64 {
                k += 1;
            }
            let p = v[k];
            *out = ((q as f64 - p as f64).powi(2) + f64::from(f[p])) as f32;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::world::rng::stream;
    use rand::Rng;

    #[test]
    fn squared_edt_equals_brute_force() {
        let mut rng = stream(&[42]);
        let (w, h) = (23, 17);
        let sources: Vec<bool> = (0..w * h).map(|_| rng.random::<f32>() < 0.04).collect();
        let d2 = squared_edt(w, h, |k| sources[k]);
        for (k, &d) in d2.iter().enumerate() {
            let brute = (0..w * h)
                .filter(|&s| sources[s])
                .map(|s| ((s % w).abs_diff(k % w).pow(2) + (s / w).abs_diff(k / w).pow(2)) as f32)
                .fold(f32::INFINITY, f32::min);
            assert_eq!(d, brute, "cell ({}, {})", k % w, k / w);
        }
    }

    #[test]
    fn squared_edt_without_sources_is_infinite() {
        assert!(squared_edt(4, 3, |_| false).iter().all(|d| d.is_infinite()), "no source: infinitely far");
        assert!(squared_edt(0, 0, |_| true).is_empty(), "empty grid");
        assert_eq!(squared_edt(5, 1, |k| k == 4), vec![16.0, 9.0, 4.0, 1.0, 0.0], "a single row");
    }
}
