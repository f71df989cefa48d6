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
    /// Column j's entries are `entries[start[j]..start[j + 1]]`, as (row, value): the
    /// products read no more (16 bytes an entry, where the column beside them made 24 and
    /// a sixth of a misfit trial's time went through these loops).
    start: Vec<usize>,
    entries: Vec<(usize, f64)>,
    /// The same of the transpose (the rows of the matrix).
    t_start: Vec<usize>,
    t_entries: Vec<(usize, f64)>,
}

/// The nonzero entries of the column-major `r × c` slice `m`, column by column, and where
/// each column starts: of the matrix, or of its transpose.
fn by_columns(
    m: &[f64],
    r: usize,
    c: usize,
    transpose: bool,
    start: &mut Vec<usize>,
    entries: &mut Vec<(usize, f64)>,
) {
    let (outer, inner) = if transpose { (r, c) } else { (c, r) };
    start.clear();
    entries.clear();
    start.reserve(outer + 1);
    entries.reserve(m.len());
    start.push(0);
    for j in 0..outer {
        for i in 0..inner {
            let v = if transpose {
                m[j + i * r]
            } else {
                m[i + j * r]
            };
            if v != 0.0 {
                entries.push((i, v));
            }
        }
        start.push(entries.len());
    }
}

impl Sparse {
    /// The nonzero entries of `m`.
    pub fn new(m: &DMatrix<f64>) -> Self {
        let mut s = Sparse {
            nrows: 0,
            ncols: 0,
            start: Vec::new(),
            entries: Vec::new(),
            t_start: Vec::new(),
            t_entries: Vec::new(),
        };
        s.reset(m);
        s
    }

    /// `self · b` (b: ncols × c).
    pub fn left(&self, b: &DMatrix<f64>) -> DMatrix<f64> {
        let mut out = DMatrix::zeros(0, 0);
        self.left_into(b.as_slice(), b.ncols(), &mut out);
        out
    }

    /// `self · b` into `out` (reshaped to nrows × c, its storage reused), for `b` the
    /// column-major `ncols × c` slice: [`Sparse::left`] without an allocation per product
    /// (the moment recursions make a few dozen a step), the same sums in the same order.
    pub fn left_into(&self, b: &[f64], c: usize, out: &mut DMatrix<f64>) {
        let (r, k) = (self.nrows, self.ncols);
        assert_eq!(k * c, b.len(), "Sparse::left: inner dimensions differ");
        zeroed(out, r, c);
        if r == 0 || k == 0 {
            return;
        }
        for (col, b_col) in out
            .as_mut_slice()
            .chunks_exact_mut(r)
            .zip(b.chunks_exact(k))
        {
            // Column p of self scaled by b's entry p: the entries in their stored order (so
            // the sums are the same), a zero multiplier's column skipped (the windows and
            // block-structured moments have many).
            for (p, &bp) in b_col.iter().enumerate() {
                if bp == 0.0 {
                    continue;
                }
                for &(i, v) in &self.entries[self.start[p]..self.start[p + 1]] {
                    col[i] += v * bp;
                }
            }
        }
    }

    /// `b · self` (b: r × nrows).
    pub fn right(&self, b: &DMatrix<f64>) -> DMatrix<f64> {
        let mut out = DMatrix::zeros(0, 0);
        self.right_into(b, &mut out);
        out
    }

    /// `b · self'` (b: r × ncols).
    pub fn right_tr(&self, b: &DMatrix<f64>) -> DMatrix<f64> {
        let mut out = DMatrix::zeros(0, 0);
        self.right_tr_into(b, &mut out);
        out
    }

    /// [`Sparse::right`] into `out` (reshaped, its storage reused).
    pub fn right_into(&self, b: &DMatrix<f64>, out: &mut DMatrix<f64>) {
        right(b, self.nrows, self.ncols, &self.start, &self.entries, out);
    }

    /// [`Sparse::right_tr`] into `out` (reshaped, its storage reused).
    pub fn right_tr_into(&self, b: &DMatrix<f64>, out: &mut DMatrix<f64>) {
        right(
            b,
            self.ncols,
            self.nrows,
            &self.t_start,
            &self.t_entries,
            out,
        );
    }

    /// `(self · x)_j`, row j's product with `x` (ncols): one entry of [`Sparse::left`]
    /// without the others, the same sum in the same order.
    pub fn row_dot(&self, j: usize, x: &[f64]) -> f64 {
        self.t_entries[self.t_start[j]..self.t_start[j + 1]]
            .iter()
            .fold(0.0, |s, &(p, v)| s + v * x[p])
    }

    /// `(self · s · self')_jj`, row j's quadratic form in `s` (ncols × ncols).
    pub fn row_quadratic(&self, j: usize, s: &DMatrix<f64>) -> f64 {
        let row = &self.t_entries[self.t_start[j]..self.t_start[j + 1]];
        row.iter()
            .map(|&(p, a)| a * row.iter().map(|&(q, b)| s[(p, q)] * b).sum::<f64>())
            .sum()
    }

    /// `self · s · c'` (s: ncols × c.ncols).
    pub fn sandwich(&self, s: &DMatrix<f64>, c: &Sparse) -> DMatrix<f64> {
        self.left(&c.right_tr(s))
    }

    /// [`Sparse::sandwich`] into `out`, through `scratch` (both reshaped, their storage
    /// reused).
    pub fn sandwich_into(
        &self,
        s: &DMatrix<f64>,
        c: &Sparse,
        scratch: &mut DMatrix<f64>,
        out: &mut DMatrix<f64>,
    ) {
        c.right_tr_into(s, scratch);
        self.left_into(scratch.as_slice(), scratch.ncols(), out);
    }

    /// Hold the nonzero entries of `m` instead, keeping the storage.
    pub fn reset(&mut self, m: &DMatrix<f64>) {
        let (r, c) = m.shape();
        self.nrows = r;
        self.ncols = c;
        by_columns(
            m.as_slice(),
            r,
            c,
            false,
            &mut self.start,
            &mut self.entries,
        );
        by_columns(
            m.as_slice(),
            r,
            c,
            true,
            &mut self.t_start,
            &mut self.t_entries,
        );
    }
}

/// `out` as an `r × c` matrix of zeros, its storage reused where the size allows.
pub fn zeroed(out: &mut DMatrix<f64>, r: usize, c: usize) {
    if out.shape() == (r, c) {
        out.as_mut_slice().fill(0.0);
    } else {
        shaped(out, r, c);
    }
}

/// `out` as an `r × c` matrix whose entries the caller writes over, every one: its old
/// entries are kept where it has that shape already (filling a buffer with zeros only to
/// overwrite it cost a twentieth of a misfit trial), zeros where it is reshaped.
pub fn shaped(out: &mut DMatrix<f64>, r: usize, c: usize) {
    if out.shape() != (r, c) {
        // The buffer's storage, reshaped: no copy of the old entries (resize_mut keeps them).
        let mut v: Vec<f64> = std::mem::replace(out, DMatrix::zeros(0, 0)).data.into();
        v.clear();
        v.resize(r * c, 0.0);
        *out = DMatrix::from_vec(r, c, v);
    }
}

/// `b · a` for `a` (k × c) by the columns `start`, `entries`: each output column a sum of
/// `b`'s columns.
fn right(
    b: &DMatrix<f64>,
    k: usize,
    c: usize,
    start: &[usize],
    entries: &[(usize, f64)],
    out: &mut DMatrix<f64>,
) {
    assert_eq!(b.ncols(), k, "Sparse::right: inner dimensions differ");
    let r = b.nrows();
    zeroed(out, r, c);
    if r == 0 {
        return;
    }
    let bv = b.as_slice();
    for (j, col) in out.as_mut_slice().chunks_exact_mut(r).enumerate() {
        for &(p, v) in &entries[start[j]..start[j + 1]] {
            axpy(col, &bv[p * r..(p + 1) * r], v);
        }
    }
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
    fn shaped_keeps_a_buffer_of_its_shape_and_reshapes_another() {
        let mut buf = DMatrix::from_element(2, 3, 7.0);
        let storage = buf.as_slice().as_ptr();
        shaped(&mut buf, 2, 3);
        assert_eq!(buf.as_slice().as_ptr(), storage, "the same storage");
        assert!(
            buf.iter().all(|&v| v == 7.0),
            "its entries left for the caller"
        );
        shaped(&mut buf, 3, 1);
        assert_eq!(buf.shape(), (3, 1));
        assert!(
            buf.iter().all(|&v| v == 0.0),
            "a reshaped buffer holds zeros"
        );
        zeroed(&mut buf, 3, 1);
        buf[(1, 0)] = 2.0;
        zeroed(&mut buf, 3, 1);
        assert!(
            buf.iter().all(|&v| v == 0.0),
            "zeroed clears a buffer of its shape"
        );
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
            // Into a buffer of another shape holding other values (the moment recursions'
            // buffers are reused from product to product): the same bits as a fresh product.
            let same = |x: &DMatrix<f64>, y: &DMatrix<f64>| {
                x.shape() == y.shape()
                    && x.iter()
                        .zip(y.iter())
                        .all(|(p, q)| p.to_bits() == q.to_bits())
            };
            let mut buf = DMatrix::from_element(2, 5, 7.0);
            sa.left_into(b.as_slice(), c, &mut buf);
            assert!(same(&buf, &sa.left(&b)), "Sparse::left_into {r}×{k}×{c}");
            sb.right_into(&a, &mut buf);
            assert!(same(&buf, &sb.right(&a)), "Sparse::right_into {r}×{k}×{c}");
            let sbt = Sparse::new(&bt);
            sbt.right_tr_into(&a, &mut buf);
            assert!(
                same(&buf, &sbt.right_tr(&a)),
                "Sparse::right_tr_into {r}×{k}×{c}"
            );
            let mut scratch = DMatrix::from_element(1, 1, -3.0);
            sa.sandwich_into(&s, &sc, &mut scratch, &mut buf);
            assert!(
                same(&buf, &sa.sandwich(&s, &sc)),
                "Sparse::sandwich_into {r}×{k}×{c}"
            );
            // A matrix held anew in an operand's storage is the operand of that matrix.
            let mut held = Sparse::new(&s);
            held.reset(&a);
            assert!(
                same(&held.left(&b), &sa.left(&b)),
                "Sparse::reset {r}×{k}×{c}"
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
