//! Products of the small matrices that the exact scoring propagates (a few to a few dozen
//! states), for [`crate::montecarlo`]'s moment recursions.
//!
//! A general matrix multiplication packs its operands into blocks first. At these sizes the
//! packing costs as much as the arithmetic. The models are also block-structured: axes that
//! do not couple, a transition matrix with a few entries per row, an H that reads positions
//! only. So the model's matrix is held by its nonzero entries ([`Sparse`]) and the products
//! run over them with no packing. A dropped zero would have multiplied a finite entry: the
//! moments are finite wherever the recursion goes on (an overflow stops the test).

use nalgebra::DMatrix;

/// A matrix held by its nonzero entries, column by column, and its transpose likewise: the
/// sparse operand of a product with a dense matrix on either side. Exact zeros are dropped.
pub struct Sparse {
    nrows: usize,
    ncols: usize,
    /// Column j's entries are `entries[start[j]..start[j + 1]]`, as (row, column, value).
    start: Vec<usize>,
    entries: Vec<(usize, usize, f64)>,
    /// The same of the transpose (the rows of the matrix).
    t_start: Vec<usize>,
    t_entries: Vec<(usize, usize, f64)>,
}

/// The nonzero entries of the column-major `r × c` slice `m`, column by column, and where
/// each column starts: of the matrix, or of its transpose.
fn by_columns(
    m: &[f64],
    r: usize,
    c: usize,
    transpose: bool,
) -> (Vec<usize>, Vec<(usize, usize, f64)>) {
    let (outer, inner) = if transpose { (r, c) } else { (c, r) };
    let mut start = Vec::with_capacity(outer + 1);
    let mut entries = Vec::with_capacity(m.len());
    start.push(0);
    for j in 0..outer {
        for i in 0..inner {
            let v = if transpose {
                m[j + i * r]
            } else {
                m[i + j * r]
            };
            if v != 0.0 {
                entries.push((i, j, v));
            }
        }
        start.push(entries.len());
    }
    (start, entries)
}

impl Sparse {
    /// The nonzero entries of `m`.
    pub fn new(m: &DMatrix<f64>) -> Self {
        let (r, c) = m.shape();
        let (start, entries) = by_columns(m.as_slice(), r, c, false);
        let (t_start, t_entries) = by_columns(m.as_slice(), r, c, true);
        Sparse {
            nrows: r,
            ncols: c,
            start,
            entries,
            t_start,
            t_entries,
        }
    }

    /// `self · b` (b: ncols × c).
    pub fn left(&self, b: &DMatrix<f64>) -> DMatrix<f64> {
        assert_eq!(
            self.ncols,
            b.nrows(),
            "Sparse::left: inner dimensions differ"
        );
        let (r, k) = (self.nrows, self.ncols);
        let mut out = DMatrix::zeros(r, b.ncols());
        if r == 0 || k == 0 {
            return out;
        }
        for (col, b_col) in out
            .as_mut_slice()
            .chunks_exact_mut(r)
            .zip(b.as_slice().chunks_exact(k))
        {
            // Column p of self scaled by b's entry p: the entries in their stored order (so
            // the sums are the same), a zero multiplier's column skipped (the windows and
            // block-structured moments have many).
            for (p, &bp) in b_col.iter().enumerate() {
                if bp == 0.0 {
                    continue;
                }
                for &(i, _, v) in &self.entries[self.start[p]..self.start[p + 1]] {
                    col[i] += v * bp;
                }
            }
        }
        out
    }

    /// `b · self` (b: r × nrows).
    pub fn right(&self, b: &DMatrix<f64>) -> DMatrix<f64> {
        right(b, self.nrows, self.ncols, &self.start, &self.entries)
    }

    /// `b · self'` (b: r × ncols).
    pub fn right_tr(&self, b: &DMatrix<f64>) -> DMatrix<f64> {
        right(b, self.ncols, self.nrows, &self.t_start, &self.t_entries)
    }

    /// `(self · x)_j`, row j's product with `x` (ncols): one entry of [`Sparse::left`]
    /// without the others, the same sum in the same order.
    pub fn row_dot(&self, j: usize, x: &[f64]) -> f64 {
        self.t_entries[self.t_start[j]..self.t_start[j + 1]]
            .iter()
            .fold(0.0, |s, &(p, _, v)| s + v * x[p])
    }

    /// `(self · s · self')_jj`, row j's quadratic form in `s` (ncols × ncols).
    pub fn row_quadratic(&self, j: usize, s: &DMatrix<f64>) -> f64 {
        let row = &self.t_entries[self.t_start[j]..self.t_start[j + 1]];
        row.iter()
            .map(|&(p, _, a)| a * row.iter().map(|&(q, _, b)| s[(p, q)] * b).sum::<f64>())
            .sum()
    }

    /// `self · s · c'` (s: ncols × c.ncols).
    pub fn sandwich(&self, s: &DMatrix<f64>, c: &Sparse) -> DMatrix<f64> {
        self.left(&c.right_tr(s))
    }
}

/// `b · a` for `a` (k × c) by the columns `start`, `entries`: each output column a sum of
/// `b`'s columns.
fn right(
    b: &DMatrix<f64>,
    k: usize,
    c: usize,
    start: &[usize],
    entries: &[(usize, usize, f64)],
) -> DMatrix<f64> {
    assert_eq!(b.ncols(), k, "Sparse::right: inner dimensions differ");
    let r = b.nrows();
    let mut out = DMatrix::zeros(r, c);
    if r == 0 {
        return out;
    }
    let bv = b.as_slice();
    for (j, col) in out.as_mut_slice().chunks_exact_mut(r).enumerate() {
        for &(p, _, v) in &entries[start[j]..start[j + 1]] {
            axpy(col, &bv[p * r..(p + 1) * r], v);
        }
    }
    out
}

/// `y += a x` over a column.
#[inline]
fn axpy(y: &mut [f64], x: &[f64], a: f64) {
    for (y, x) in y.iter_mut().zip(x) {
        *y += a * x;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A matrix with about a third of its entries exactly zero and the rest of mixed sign
    /// and magnitude (a fixed pseudo-random pattern).
    fn sparse(r: usize, c: usize, seed: u64) -> DMatrix<f64> {
        let mut state = seed
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        DMatrix::from_fn(r, c, |_, _| {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            let u = (state >> 11) as f64 / (1u64 << 53) as f64;
            if u < 0.33 {
                0.0
            } else {
                (u - 0.6) * 10f64.powf(3.0 * u - 1.0)
            }
        })
    }

    fn close(a: &DMatrix<f64>, b: &DMatrix<f64>) -> bool {
        let scale = b.iter().fold(0.0f64, |m, v| m.max(v.abs())).max(1e-300);
        a.shape() == b.shape()
            && a.iter()
                .zip(b.iter())
                .all(|(x, y)| (x - y).abs() <= 1e-14 * scale)
    }

    #[test]
    fn products_equal_nalgebras_on_every_shape() {
        // Shapes around the sizes met (1 to 24 states, 1 to 6 readings), empty ones included.
        for (i, &(r, k, c)) in [
            (1, 1, 1),
            (3, 6, 3),
            (6, 6, 6),
            (12, 12, 12),
            (9, 6, 3),
            (24, 7, 18),
            (0, 3, 2),
            (3, 0, 2),
            (2, 3, 0),
        ]
        .iter()
        .enumerate()
        {
            let seed = i as u64;
            let a = sparse(r, k, seed);
            let b = sparse(k, c, seed + 100);
            let bt = b.transpose();
            let s = sparse(k, k, seed + 200);
            let cm = sparse(c, k, seed + 300);
            let (sa, sb, sc) = (Sparse::new(&a), Sparse::new(&b), Sparse::new(&cm));
            assert!(close(&sa.left(&b), &(&a * &b)), "Sparse::left {r}×{k}×{c}");
            assert!(
                close(&sb.right(&a), &(&a * &b)),
                "Sparse::right {r}×{k}×{c}"
            );
            assert!(
                close(&Sparse::new(&bt).right_tr(&a), &(&a * &b)),
                "Sparse::right_tr {r}×{k}×{c}"
            );
            assert!(
                close(&sa.sandwich(&s, &sc), &(&a * &s * cm.transpose())),
                "Sparse::sandwich {r}×{k}×{c}"
            );
            // One entry of `left` alone is that entry, to the bit (the whiteness sums read
            // only the diagonal of each lag's block).
            let full = sa.left(&b);
            for i in 0..r {
                for j in 0..c {
                    let one = sa.row_dot(i, b.column(j).as_slice());
                    assert_eq!(one.to_bits(), full[(i, j)].to_bits(), "row_dot {i},{j}");
                }
            }
        }
    }
}
