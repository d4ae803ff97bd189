//! Matrix transpose on AVX-512 in 16 × 16 blocks, for the layout changes of `strided.rs`
//! (channel-major ↔ pixel-major). One float at a time, the transposes of its outputs cost as much
//! as the first layers' arithmetic; in registers a block takes 16 loads, 64 shuffles, 16 stores.

use std::arch::x86_64::{
    __m512, __m512d, __mmask16, _mm512_add_ps, _mm512_castpd_ps, _mm512_castps_pd, _mm512_mask_storeu_ps,
    _mm512_maskz_loadu_ps, _mm512_shuffle_f32x4, _mm512_unpackhi_pd, _mm512_unpackhi_ps, _mm512_unpacklo_pd,
    _mm512_unpacklo_ps,
};

const LANES: usize = 16;

/// dst [cols][rows] ← (or, if `add`, +=) the transpose of src [rows][cols].
pub fn transpose(src: &[f32], rows: usize, cols: usize, dst: &mut [f32], add: bool) {
    assert!(super::direct::available(), "transpose needs AVX-512F");
    assert_eq!((src.len(), dst.len()), (rows * cols, rows * cols), "transpose lengths");
    // SAFETY: AVX-512F checked above; loads and stores are masked to the block's rows and
    // columns, which lie inside `src` and `dst`.
    unsafe { blocks(src, rows, cols, dst, add) }
}

fn first(n: usize) -> __mmask16 {
    ((1u32 << n) - 1) as __mmask16
}

/// Full 16-row, 16-column loops whatever the block's size (the tails are masked, a lane or a
/// whole vector at a time), so the block stays in registers: loops cut short spilled it to the stack.
#[target_feature(enable = "avx512f")]
fn blocks(src: &[f32], rows: usize, cols: usize, dst: &mut [f32], add: bool) {
    for i0 in (0..rows).step_by(LANES) {
        let mr = (rows - i0).min(LANES);
        for j0 in (0..cols).step_by(LANES) {
            let mc = (cols - j0).min(LANES);
            let block: [__m512; LANES] = std::array::from_fn(|r| {
                let m = if r < mr { first(mc) } else { 0 };
                // SAFETY (pointer): wrapping, as rows past the block's are never touched (mask 0).
                unsafe { _mm512_maskz_loadu_ps(m, src.as_ptr().wrapping_add((i0 + r) * cols + j0)) }
            });
            let block = transpose16(block);
            for (c, v) in block.iter().enumerate() {
                let m = if c < mc { first(mr) } else { 0 };
                let at = dst.as_mut_ptr().wrapping_add((j0 + c) * rows + i0);
                unsafe {
                    let v = if add { _mm512_add_ps(*v, _mm512_maskz_loadu_ps(m, at)) } else { *v };
                    _mm512_mask_storeu_ps(at, m, v);
                }
            }
        }
    }
}

/// Row c of the result is column c of `r`: 32-bit, 64-bit, then two 128-bit interleaving stages.
#[target_feature(enable = "avx512f")]
fn transpose16(r: [__m512; LANES]) -> [__m512; LANES] {
    let pd = _mm512_castps_pd;
    let ps = _mm512_castpd_ps;
    // Within each 128-bit lane: pairs of rows interleaved, then pairs of pairs.
    let t: [__m512; LANES] = std::array::from_fn(|i| {
        let (a, b) = (r[i & !1], r[i | 1]);
        if i % 2 == 0 { _mm512_unpacklo_ps(a, b) } else { _mm512_unpackhi_ps(a, b) }
    });
    let u: [__m512d; LANES] = std::array::from_fn(|i| {
        // u[4g + m]: m = 0, 1 from t[4g], t[4g + 2]; m = 2, 3 from t[4g + 1], t[4g + 3].
        let (g, m) = (i / 4, i % 4);
        let (a, b) = (pd(t[4 * g + m / 2]), pd(t[4 * g + 2 + m / 2]));
        if m % 2 == 0 { _mm512_unpacklo_pd(a, b) } else { _mm512_unpackhi_pd(a, b) }
    });
    // Then 128-bit blocks across rows 4 apart, and across rows 8 apart.
    let v: [__m512; LANES] = std::array::from_fn(|i| {
        let (half, m) = (i / 8, i % 8);
        let (a, b) = (ps(u[8 * half + m % 4]), ps(u[8 * half + 4 + m % 4]));
        if m < 4 { _mm512_shuffle_f32x4::<0x88>(a, b) } else { _mm512_shuffle_f32x4::<0xdd>(a, b) }
    });
    std::array::from_fn(|i| {
        let (quarter, m) = (i / 4, i % 4);
        let (a, b) = (v[m + 4 * (quarter % 2)], v[8 + m + 4 * (quarter % 2)]);
        if quarter < 2 { _mm512_shuffle_f32x4::<0x88>(a, b) } else { _mm512_shuffle_f32x4::<0xdd>(a, b) }
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::nn::gradcheck::test_values;

    #[test]
    fn transpose_matches_scalar_on_block_tails() {
        if !super::super::direct::available() {
            return;
        }
        for (rows, cols) in [(16, 16), (1, 1), (4, 32), (37, 16), (32, 25), (17, 33)] {
            let src = test_values(rows * cols, (rows * 100 + cols) as u64);
            let base = test_values(rows * cols, 7);
            let (mut copied, mut added) = (vec![f32::NAN; rows * cols], base.clone());
            transpose(&src, rows, cols, &mut copied, false);
            transpose(&src, rows, cols, &mut added, true);
            for i in 0..rows {
                for j in 0..cols {
                    let (want, at) = (src[i * cols + j], j * rows + i);
                    assert_eq!(copied[at], want, "{rows}×{cols} copy at ({i}, {j})");
                    assert_eq!(added[at], base[at] + want, "{rows}×{cols} add at ({i}, {j})");
                }
            }
        }
    }
}
