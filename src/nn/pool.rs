//! 2-D max pooling over a square window, TensorFlow semantics: `Same` pads with −∞ (padded taps never
//! win), ties go to the first maximum in window order (row-major over kh, kw). The winner of each window
//! is kept as a u8 index `kh * kernel + kw` so backward needs neither x nor y.

use crate::nn::conv::Padding;

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct MaxPool2d {
    pub kernel: usize,
    pub stride: usize,
    pub padding: Padding,
}

/// One output row or column: first input index (may be negative with `Same`) and the range of taps
/// that fall inside the input.
#[derive(Clone, Copy)]
struct Span {
    start: isize,
    k0: usize,
    k1: usize,
}

impl MaxPool2d {
    /// (oh, ow) for an h × w input.
    pub fn output_size(&self, h: usize, w: usize) -> (usize, usize) {
        (self.axis(h).0, self.axis(w).0)
    }

    fn axis(&self, size: usize) -> (usize, usize) {
        self.padding.output_and_pad_before(size, self.kernel, self.stride, 1)
    }

    fn span(&self, o: usize, pad: usize, size: usize) -> Span {
        let start = (o * self.stride) as isize - pad as isize;
        let k0 = (-start).max(0) as usize;
        let k1 = (size as isize - start).clamp(0, self.kernel as isize) as usize;
        debug_assert!(k0 < k1, "window entirely in padding");
        Span { start, k0, k1 }
    }

    fn check(
        &self,
        planes: usize,
        h: usize,
        w: usize,
        x_len: usize,
        y_len: usize,
        arg_len: usize,
    ) -> [usize; 4] {
        assert!(self.kernel > 0 && self.stride > 0, "MaxPool2d: zero kernel or stride");
        assert!(self.kernel * self.kernel <= 256, "MaxPool2d: window index must fit in u8");
        let (oh, ph) = self.axis(h);
        let (ow, pw) = self.axis(w);
        assert_eq!(x_len, planes * h * w, "MaxPool2d: x length");
        assert!(y_len == planes * oh * ow && arg_len == y_len, "MaxPool2d: y/argmax length");
        [oh, ph, ow, pw]
    }

    /// x: [planes][h][w] (planes = n·c) → y [planes][oh][ow], argmax [planes][oh][ow].
    /// Padded taps never win (TF pads with −∞); a NaN in a window wins, so divergence stays visible.
    pub fn forward(&self, x: &[f32], planes: usize, h: usize, w: usize, y: &mut [f32], argmax: &mut [u8]) {
        let [oh, ph, ow, pw] = self.check(planes, h, w, x.len(), y.len(), argmax.len());
        let k = self.kernel;
        for p in 0..planes {
            let xp = &x[p * h * w..][..h * w];
            let yp = &mut y[p * oh * ow..][..oh * ow];
            let ap = &mut argmax[p * oh * ow..][..oh * ow];
            for i in 0..oh {
                let row = self.span(i, ph, h);
                let yr = &mut yp[i * ow..][..ow];
                let ar = &mut ap[i * ow..][..ow];
                for (j, (out, arg)) in yr.iter_mut().zip(ar.iter_mut()).enumerate() {
                    let col = self.span(j, pw, w);
                    let mut best = f32::NEG_INFINITY;
                    let mut best_at = row.k0 * k + col.k0;
                    for kh in row.k0..row.k1 {
                        let base = (row.start + kh as isize) as usize * w;
                        let taps = &xp[(base as isize + col.start) as usize + col.k0..][..col.k1 - col.k0];
                        for (kw, &v) in (col.k0..).zip(taps) {
                            // Strict `>`: the first maximum in window order wins ties, as in TF.
                            if v > best || (v.is_nan() && !best.is_nan()) {
                                best = v;
                                best_at = kh * k + kw;
                            }
                        }
                    }
                    *out = best;
                    *arg = best_at as u8;
                }
            }
        }
    }

    /// Accumulates dy ([planes][oh][ow]) into dx ([planes][h][w]) at the argmax positions.
    pub fn backward(&self, dy: &[f32], argmax: &[u8], planes: usize, h: usize, w: usize, dx: &mut [f32]) {
        let [oh, ph, ow, pw] = self.check(planes, h, w, dx.len(), dy.len(), argmax.len());
        let k = self.kernel;
        for p in 0..planes {
            let dxp = &mut dx[p * h * w..][..h * w];
            let dyp = &dy[p * oh * ow..][..oh * ow];
            let ap = &argmax[p * oh * ow..][..oh * ow];
            for i in 0..oh {
                let top = (i * self.stride) as isize - ph as isize;
                for j in 0..ow {
                    let left = (j * self.stride) as isize - pw as isize;
                    let a = usize::from(ap[i * ow + j]);
                    let ih = (top + (a / k) as isize) as usize;
                    let iw = (left + (a % k) as isize) as usize;
                    dxp[ih * w + iw] += dyp[i * ow + j];
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::nn::gradcheck::{assert_close, numerical_grad};

    /// Distinct values (a permutation of k/len), so no ties and finite differences are valid.
    fn distinct(len: usize) -> Vec<f32> {
        (0..len).map(|i| ((i * 7919 + 13) % len) as f32 / len as f32 - 0.5).collect()
    }

    fn r_values(len: usize) -> Vec<f32> {
        (0..len).map(|i| ((i as f32) * 0.73).sin()).collect()
    }

    /// Naive f64 pooling: every tap of every window, out-of-range taps read as −∞.
    fn naive(pool: &MaxPool2d, x: &[f64], planes: usize, h: usize, w: usize) -> Vec<f64> {
        let (oh, ph) = pool.padding.output_and_pad_before(h, pool.kernel, pool.stride, 1);
        let (ow, pw) = pool.padding.output_and_pad_before(w, pool.kernel, pool.stride, 1);
        let mut y = Vec::with_capacity(planes * oh * ow);
        for p in 0..planes {
            for i in 0..oh {
                for j in 0..ow {
                    let mut best = f64::NEG_INFINITY;
                    for kh in 0..pool.kernel {
                        for kw in 0..pool.kernel {
                            let ih = (i * pool.stride + kh) as isize - ph as isize;
                            let iw = (j * pool.stride + kw) as isize - pw as isize;
                            if (0..h as isize).contains(&ih) && (0..w as isize).contains(&iw) {
                                best = best.max(x[(p * h + ih as usize) * w + iw as usize]);
                            }
                        }
                    }
                    y.push(best);
                }
            }
        }
        y
    }

    fn check(pool: MaxPool2d, planes: usize, h: usize, w: usize) {
        let x = distinct(planes * h * w);
        let x64: Vec<f64> = x.iter().map(|&v| f64::from(v)).collect();
        let (oh, ow) = pool.output_size(h, w);
        let mut y = vec![0.0; planes * oh * ow];
        let mut arg = vec![0u8; y.len()];
        pool.forward(&x, planes, h, w, &mut y, &mut arg);
        let want = naive(&pool, &x64, planes, h, w);
        assert_close(&y, &want, 1e-7, "forward");

        let r = r_values(y.len());
        let loss =
            |x: &[f64]| naive(&pool, x, planes, h, w).iter().zip(&r).map(|(a, &b)| a * f64::from(b)).sum();
        let want = numerical_grad(&x64, 1e-6, loss);
        let mut dx = vec![0.0; x.len()];
        pool.backward(&r, &arg, planes, h, w, &mut dx);
        assert_close(&dx, &want, 1e-4, "dx");
        pool.backward(&r, &arg, planes, h, w, &mut dx);
        let twice: Vec<f64> = want.iter().map(|a| 2.0 * a).collect();
        assert_close(&dx, &twice, 1e-4, "dx accumulated");
    }

    #[test]
    fn output_sizes_follow_tensorflow() {
        let same = MaxPool2d { kernel: 3, stride: 2, padding: Padding::Same };
        let valid = MaxPool2d { padding: Padding::Valid, ..same };
        assert_eq!(same.output_size(28, 56), (14, 28));
        assert_eq!(valid.output_size(12, 11), (5, 5));
        // Even sizes: TF pads 0 before, 1 after; odd sizes pad 1 on each side.
        assert_eq!(same.axis(56), (28, 0));
        assert_eq!(same.axis(7), (4, 1));
    }

    #[test]
    fn same_even_and_odd_sizes_match_naive_and_finite_differences() {
        let pool = MaxPool2d { kernel: 3, stride: 2, padding: Padding::Same };
        check(pool, 3, 8, 6);
        check(pool, 2, 7, 9);
    }

    #[test]
    fn valid_matches_naive_and_finite_differences() {
        check(MaxPool2d { kernel: 3, stride: 2, padding: Padding::Valid }, 3, 12, 11);
        check(MaxPool2d { kernel: 2, stride: 2, padding: Padding::Valid }, 2, 6, 5);
    }

    #[test]
    fn ties_go_to_the_first_unpadded_tap() {
        // Odd size, Same: one row/column of padding before, so the corner window's first real tap is
        // (1, 1) = 4; an interior window's is 0.
        let pool = MaxPool2d { kernel: 3, stride: 2, padding: Padding::Same };
        let x = vec![-2.0f32; 25];
        let mut y = vec![0.0; 9];
        let mut arg = vec![0u8; 9];
        pool.forward(&x, 1, 5, 5, &mut y, &mut arg);
        assert!(y.iter().all(|&v| v == -2.0));
        assert_eq!(arg, [4, 3, 3, 1, 0, 0, 1, 0, 0]);
    }
}
