//! The chunk's vector kernels: products and reductions over one run per row.

use nalgebra::DMatrix;

/// `Σ a_i b_i` with four independent partial sums, so the additions pipeline instead of
/// forming one long dependency chain (the order is fixed, so results stay reproducible).
#[inline(always)]
pub(super) fn dot(a: &[f64], b: &[f64]) -> f64 {
    let mut p = [0.0; 4];
    let (ca, cb) = (a.chunks_exact(4), b.chunks_exact(4));
    let (ra, rb) = (ca.remainder(), cb.remainder());
    for (x, y) in ca.zip(cb) {
        for l in 0..4 {
            p[l] += x[l] * y[l];
        }
    }
    let tail: f64 = ra.iter().zip(rb).map(|(x, y)| x * y).sum();
    (p[0] + p[1]) + (p[2] + p[3]) + tail
}

/// `c ← α a b + β c` where `a` and `c` hold one run per row (B × k and B × n) and `b` is a
/// small k × n matrix. Each output column is a sum of k scaled columns of `a`, so the inner
/// loop runs over the B runs on contiguous memory and vectorizes. (nalgebra's `gemm` takes
/// the same approach below six columns but through strided generic iterators that cost
/// several times more per element here.)
#[inline(always)]
pub(super) fn gemm_rows(
    c: &mut DMatrix<f64>,
    alpha: f64,
    a: &DMatrix<f64>,
    b: &DMatrix<f64>,
    beta: f64,
) {
    let rows = a.nrows();
    debug_assert_eq!(a.ncols(), b.nrows());
    debug_assert_eq!(c.shape(), (rows, b.ncols()));
    for j in 0..b.ncols() {
        let cj = col_mut(c, j);
        if beta == 0.0 {
            cj.fill(0.0);
        } else if beta != 1.0 {
            cj.iter_mut().for_each(|v| *v *= beta);
        }
        for l in 0..a.ncols() {
            let s = alpha * b[(l, j)];
            if s != 0.0 {
                for (x, y) in cj.iter_mut().zip(col(a, l)) {
                    *x += s * y;
                }
            }
        }
    }
}

/// Column `j` of a column-major B-row matrix as a slice.
#[inline(always)]
pub(super) fn col(m: &DMatrix<f64>, j: usize) -> &[f64] {
    let b = m.nrows();
    &m.as_slice()[j * b..(j + 1) * b]
}

#[inline(always)]
pub(super) fn col_mut(m: &mut DMatrix<f64>, j: usize) -> &mut [f64] {
    let b = m.nrows();
    &mut m.as_mut_slice()[j * b..(j + 1) * b]
}

/// The largest magnitude in `v` as a bit pattern: the bits of `|x|` order as the numbers do
/// and a NaN's lie above infinity's, so one integer maximum (which vectorizes) finds both.
#[inline(always)]
pub(super) fn max_abs_bits(acc: i64, v: f64) -> i64 {
    acc.max(v.to_bits() as i64 & i64::MAX)
}

/// `|x|` from [`max_abs_bits`].
#[inline(always)]
pub(super) fn from_abs_bits(b: i64) -> f64 {
    f64::from_bits(b as u64)
}

/// Per-row `Σ_j mat[r, j]²` into `sq`, and its total.
#[inline(always)]
pub(super) fn row_norms(sq: &mut [f64], mat: &DMatrix<f64>) -> f64 {
    sq.fill(0.0);
    for j in 0..mat.ncols() {
        for (s, v) in sq.iter_mut().zip(col(mat, j)) {
            *s += v * v;
        }
    }
    sq.iter().sum::<f64>()
}

/// Zero row `r` of each matrix.
pub(super) fn zero_row(r: usize, mats: &mut [&mut DMatrix<f64>]) {
    for m in mats.iter_mut() {
        m.row_mut(r).fill(0.0);
    }
}
