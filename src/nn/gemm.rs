//! The one call into the GEMM kernel: `C = A·B` or `C += A·B` over strided views, single-threaded
//! (parallelism lives one level up, over particle chunks, so pools never nest).

/// A read-only matrix view: element (i, j) is `data[i * row_stride + j * col_stride]`.
#[derive(Clone, Copy, Debug)]
pub struct MatRef<'a> {
    pub data: &'a [f32],
    pub rows: usize,
    pub cols: usize,
    pub row_stride: usize,
    pub col_stride: usize,
}

/// A writable matrix view, same addressing as [`MatRef`].
#[derive(Debug)]
pub struct MatMut<'a> {
    pub data: &'a mut [f32],
    pub rows: usize,
    pub cols: usize,
    pub row_stride: usize,
    pub col_stride: usize,
}

impl<'a> MatRef<'a> {
    /// A dense row-major `rows × cols` matrix.
    pub fn row_major(data: &'a [f32], rows: usize, cols: usize) -> Self {
        Self { data, rows, cols, row_stride: cols, col_stride: 1 }
    }

    /// The same elements read as the transpose (no copy).
    pub fn t(self) -> Self {
        Self {
            rows: self.cols,
            cols: self.rows,
            row_stride: self.col_stride,
            col_stride: self.row_stride,
            ..self
        }
    }

    fn last_index(&self) -> usize {
        last_index(self.rows, self.cols, self.row_stride, self.col_stride)
    }
}

impl<'a> MatMut<'a> {
    /// A dense row-major `rows × cols` matrix.
    pub fn row_major(data: &'a mut [f32], rows: usize, cols: usize) -> Self {
        Self { data, rows, cols, row_stride: cols, col_stride: 1 }
    }

    fn last_index(&self) -> usize {
        last_index(self.rows, self.cols, self.row_stride, self.col_stride)
    }
}

fn last_index(rows: usize, cols: usize, row_stride: usize, col_stride: usize) -> usize {
    if rows == 0 || cols == 0 { 0 } else { (rows - 1) * row_stride + (cols - 1) * col_stride }
}

/// `c = a·b`, or `c += a·b` when `accumulate`.
///
/// # Panics
/// If the shapes disagree or a view reaches past its slice.
pub fn matmul(c: MatMut<'_>, a: MatRef<'_>, b: MatRef<'_>, accumulate: bool) {
    assert_eq!(a.cols, b.rows, "inner dimensions");
    assert_eq!((c.rows, c.cols), (a.rows, b.cols), "output shape");
    if c.rows == 0 || c.cols == 0 {
        return;
    }
    if a.cols == 0 {
        if !accumulate {
            for i in 0..c.rows {
                for j in 0..c.cols {
                    c.data[i * c.row_stride + j * c.col_stride] = 0.0;
                }
            }
        }
        return;
    }
    assert!(a.last_index() < a.data.len() && b.last_index() < b.data.len(), "input view out of bounds");
    assert!(c.last_index() < c.data.len(), "output view out of bounds");
    // SAFETY: every index the kernel touches is (i·rs + j·cs) for i < rows, j < cols of its view,
    // and the asserts above bound the largest of them by the slice length; `c` is borrowed mutably,
    // so it cannot alias `a` or `b`. gemm's `alpha` scales the old `dst`, `beta` the product.
    unsafe {
        gemm::gemm(
            c.rows,
            c.cols,
            a.cols,
            c.data.as_mut_ptr(),
            c.col_stride as isize,
            c.row_stride as isize,
            accumulate,
            a.data.as_ptr(),
            a.col_stride as isize,
            a.row_stride as isize,
            b.data.as_ptr(),
            b.col_stride as isize,
            b.row_stride as isize,
            1.0,
            1.0,
            false,
            false,
            false,
            gemm::Parallelism::None,
        );
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn naive(a: &MatRef, b: &MatRef) -> Vec<f32> {
        let mut c = vec![0.0; a.rows * b.cols];
        for i in 0..a.rows {
            for j in 0..b.cols {
                for k in 0..a.cols {
                    c[i * b.cols + j] += a.data[i * a.row_stride + k * a.col_stride]
                        * b.data[k * b.row_stride + j * b.col_stride];
                }
            }
        }
        c
    }

    #[test]
    fn matmul_matches_naive_with_transposes_and_accumulation() {
        let a_data: Vec<f32> = (0..35).map(|i| (i as f32 * 0.37).sin()).collect();
        let b_data: Vec<f32> = (0..77).map(|i| (i as f32 * 0.11).cos()).collect();
        let a = MatRef::row_major(&a_data, 5, 7);
        let b = MatRef::row_major(&b_data, 11, 7).t(); // 7 × 11, column-major storage
        let want = naive(&a, &b);
        let mut c = vec![1.0; 55];
        matmul(MatMut::row_major(&mut c, 5, 11), a, b, false);
        for (x, y) in c.iter().zip(&want) {
            assert!((x - y).abs() < 1e-5, "overwrite: {x} vs {y}");
        }
        matmul(MatMut::row_major(&mut c, 5, 11), a, b, true);
        for (x, y) in c.iter().zip(&want) {
            assert!((x - 2.0 * y).abs() < 1e-4, "accumulate: {x} vs {}", 2.0 * y);
        }
    }

    #[test]
    #[should_panic(expected = "out of bounds")]
    fn matmul_refuses_views_past_the_slice() {
        let a = vec![0.0; 6];
        let mut c = vec![0.0; 4];
        matmul(
            MatMut::row_major(&mut c, 2, 2),
            MatRef::row_major(&a, 2, 4),
            MatRef::row_major(&a, 4, 2),
            false,
        );
    }
}
