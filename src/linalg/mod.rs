//! Small dense linear-algebra helpers shared by the filter, model and parameter code.
//!
//! Dimensions come from problem files at run time, so the public types are nalgebra's
//! dynamic matrices; the catalog's filters compute on fixed-size matrices inside. The
//! helpers a filter step needs ([`symmetrize`], [`cholesky`], [`mahalanobis_sq`]) take
//! either, and [`to_fixed`], [`to_dynamic`] and [`store`] cross between the two.

use nalgebra::allocator::Allocator;
use nalgebra::{
    Cholesky, DMatrix, DVector, DefaultAllocator, Dim, Dyn, IsContiguous, Matrix, OMatrix, OVector,
    RawStorage, SMatrix, SymmetricEigen,
};

pub mod products;

/// Relative tolerance for symmetry and positive-semidefiniteness checks on user input.
///
/// Problem files are typed by hand with a handful of significant digits, so anything
/// tighter than about 1e-9 relative would reject matrices that are symmetric "as written".
pub const SYMMETRY_RTOL: f64 = 1e-9;

/// Replace `m` by `(m + m') / 2`, removing the asymmetry that rounding leaves after
/// covariance updates. Any square size, fixed or dynamic.
pub fn symmetrize<D: Dim>(m: &mut OMatrix<f64, D, D>)
where
    DefaultAllocator: Allocator<D, D>,
{
    // On the column-major slice: with (row, column) indexing and its bounds checks, the
    // catalog's 4-state EKF ran a few percent slower.
    let n = m.nrows();
    let s = m.as_mut_slice();
    for j in 0..n {
        for i in (j + 1)..n {
            let v = 0.5 * (s[i + j * n] + s[j + i * n]);
            s[i + j * n] = v;
            s[j + i * n] = v;
        }
    }
}

/// Whether `a` and `b` have the same shape and the same bits in every entry (−0 is not 0,
/// a NaN equals only its own bits): the test of a memo whose value is a pure function of
/// the matrix. Every entry is compared, without an early exit, so that the loop
/// vectorizes (the Kalman filter's memo asks it four times a step of every run).
pub fn same_bits(a: &DMatrix<f64>, b: &DMatrix<f64>) -> bool {
    a.shape() == b.shape()
        && a.as_slice()
            .iter()
            .zip(b.as_slice())
            .fold(true, |all, (x, y)| all & (x.to_bits() == y.to_bits()))
}

/// The largest absolute entry of `m` (0 for an empty matrix).
pub fn max_abs(m: &DMatrix<f64>) -> f64 {
    m.iter().fold(0.0_f64, |a, v| a.max(v.abs()))
}

/// Whether `m` is square and symmetric to [`SYMMETRY_RTOL`] relative to its largest entry.
/// Returns the first offending `(row, col)` when it is not.
pub fn asymmetry(m: &DMatrix<f64>) -> Option<(usize, usize)> {
    let scale = max_abs(m).max(f64::MIN_POSITIVE);
    let n = m.nrows();
    for i in 0..n {
        for j in (i + 1)..n {
            if (m[(i, j)] - m[(j, i)]).abs() > SYMMETRY_RTOL * scale {
                return Some((i, j));
            }
        }
    }
    None
}

/// Jacobi scaling `M = S C S` with `S = diag(√M_ii)` (1 where `M_ii ≤ 0`), so that `C` has a
/// unit diagonal wherever `M` has a positive one. Numerical-rank decisions on `C` do not
/// depend on units: a state with variance 1e-10 next to one with 1e4 keeps its noise.
pub fn jacobi_scaled(m: &DMatrix<f64>) -> (DMatrix<f64>, DVector<f64>) {
    let n = m.nrows();
    let sc = DVector::from_fn(n, |i, _| {
        let d = m[(i, i)];
        if d > 0.0 { d.sqrt() } else { 1.0 }
    });
    let mut c = DMatrix::from_fn(n, n, |i, j| m[(i, j)] / (sc[i] * sc[j]));
    symmetrize(&mut c);
    (c, sc)
}

/// A factor `L` (n × r) of a symmetric positive-semidefinite matrix, `L L' = M`, where r is
/// the numerical rank. Used to draw Gaussian samples with a possibly singular covariance
/// (a DWNA process noise has rank 1 per axis) from only r standard normals. The rank is
/// judged on the Jacobi-scaled matrix (`jacobi_scaled`), so it does not depend on units.
///
/// Returns `Err(lambda_min)` (of the scaled matrix) when `M` has an eigenvalue below
/// `-SYMMETRY_RTOL·max|λ|` there.
pub fn psd_factor(m: &DMatrix<f64>) -> Result<DMatrix<f64>, f64> {
    let n = m.nrows();
    if n == 0 {
        return Ok(DMatrix::zeros(0, 0));
    }
    let (c, sc) = jacobi_scaled(m);
    let eig = SymmetricEigen::new(c);
    let lmax = eig.eigenvalues.iter().fold(0.0_f64, |a, v| a.max(v.abs()));
    let tol = SYMMETRY_RTOL * lmax.max(f64::MIN_POSITIVE);
    let lmin = eig.eigenvalues.iter().fold(f64::INFINITY, |a, &v| a.min(v));
    if lmin < -tol {
        return Err(lmin);
    }
    let keep: Vec<usize> = (0..n).filter(|&i| eig.eigenvalues[i] > tol).collect();
    let mut l = DMatrix::zeros(n, keep.len());
    for (col, &i) in keep.iter().enumerate() {
        let s = eig.eigenvalues[i].sqrt();
        for r in 0..n {
            l[(r, col)] = sc[r] * eig.eigenvectors[(r, i)] * s;
        }
    }
    Ok(l)
}

/// What is wrong with `m` as a covariance (symmetric, finite, positive semidefinite, and
/// positive definite too when `definite`), as a sentence for an error message; `None` when
/// nothing is. The problem loader and the Rust builders refuse a matrix with the same words.
pub fn covariance_defect(m: &DMatrix<f64>, definite: bool) -> Option<String> {
    if let Some((i, j)) = asymmetry(m) {
        return Some(format!(
            "not symmetric: entry [{i}][{j}] = {} but [{j}][{i}] = {}",
            m[(i, j)],
            m[(j, i)]
        ));
    }
    if let Some(k) = m.iter().position(|v| !v.is_finite()) {
        let (i, j) = (k % m.nrows(), k / m.nrows());
        return Some(format!("entry [{i}][{j}] is {} (overflow)", m[(i, j)]));
    }
    // Judge the matrix scaled to unit size, so that huge entries cannot overflow the
    // eigenvalue computation.
    let scale = max_abs(m).max(f64::MIN_POSITIVE);
    let unit = m / scale;
    let lmin = min_eigenvalue(&unit) * scale;
    if psd_factor(&unit).is_err() {
        return Some(format!(
            "not positive semidefinite (smallest eigenvalue {lmin:.3e})"
        ));
    }
    if definite && !is_positive_definite(m) {
        // A positive smallest eigenvalue that is still refused is one too small next to
        // the largest to invert reliably: say so, rather than "not positive definite".
        let message = if lmin > 0.0 {
            let lmax = unit.symmetric_eigenvalues().max() * scale;
            format!(
                "numerically singular: its smallest eigenvalue {lmin:.3e} is positive, but its condition number {:.3e} is too large to invert reliably",
                lmax / lmin
            )
        } else {
            format!("not positive definite (smallest eigenvalue {lmin:.3e})")
        };
        return Some(message);
    }
    None
}

/// Whether a symmetric matrix is positive definite, judged scale-free: every diagonal
/// entry positive and the Jacobi-scaled matrix's smallest eigenvalue above 1e-12.
pub fn is_positive_definite(m: &DMatrix<f64>) -> bool {
    if (0..m.nrows()).any(|i| m[(i, i)].is_nan() || m[(i, i)] <= 0.0) {
        return false;
    }
    min_eigenvalue(&jacobi_scaled(m).0) > 1e-12
}

/// The smallest eigenvalue of the symmetric part of `m`.
pub fn min_eigenvalue(m: &DMatrix<f64>) -> f64 {
    let mut sym = m.clone();
    symmetrize(&mut sym);
    SymmetricEigen::new(sym)
        .eigenvalues
        .iter()
        .fold(f64::INFINITY, |a, &v| a.min(v))
}

/// Cholesky factorization that refuses matrices with non-finite entries. Any square size,
/// fixed or dynamic.
pub fn cholesky<D: Dim>(m: &OMatrix<f64, D, D>) -> Option<Cholesky<f64, D>>
where
    DefaultAllocator: Allocator<D, D>,
{
    if m.iter().any(|v| !v.is_finite()) {
        return None;
    }
    Cholesky::new(m.clone())
}

/// [`cholesky`] of a matrix the caller gives up: factored in its own storage, without the
/// copy (a records reader factors a fresh P and S at every step).
pub fn cholesky_owned<D: Dim>(m: OMatrix<f64, D, D>) -> Option<Cholesky<f64, D>>
where
    DefaultAllocator: Allocator<D, D>,
{
    if m.iter().any(|v| !v.is_finite()) {
        return None;
    }
    Cholesky::new(m)
}

/// [`cholesky`] of `m` in the storage of `old`, a factor its owner gives up (of any size):
/// [`cholesky_owned`] of a copy of `m` made there, the same bits as [`cholesky`], without
/// allocating a matrix at each step of a recursion.
pub fn cholesky_reusing(
    m: &DMatrix<f64>,
    old: Option<Cholesky<f64, Dyn>>,
) -> Option<Cholesky<f64, Dyn>> {
    let mut storage = old.map_or_else(|| DMatrix::zeros(0, 0), Cholesky::unpack_dirty);
    if storage.shape() != m.shape() {
        storage = DMatrix::zeros(m.nrows(), m.ncols());
    }
    storage.copy_from(m);
    cholesky_owned(storage)
}

/// Factor a symmetric positive-definite `m` (n × n) in place into its lower Cholesky
/// factor L (the strict upper triangle is left as it was): the arithmetic of
/// [`Cholesky::new`], operation for operation and so bit for bit, without its generic
/// views, which at the sizes of a filter's state (4 to 15) cost as much as the arithmetic.
/// `false` (and `m` partly overwritten) when a pivot is zero, negative or not a number.
pub fn cholesky_in_place(m: &mut DMatrix<f64>) -> bool {
    let n = m.nrows();
    debug_assert_eq!(n, m.ncols());
    let a = m.as_mut_slice();
    for j in 0..n {
        let (left, right) = a.split_at_mut(j * n);
        let col_j = &mut right[..n];
        for k in 0..j {
            let col_k = &left[k * n..k * n + n];
            let factor = -col_k[j];
            // nalgebra's axpy: y = a·x·1 + 1·y, two roundings, no fused multiply-add.
            for (y, x) in col_j[j..].iter_mut().zip(&col_k[j..]) {
                *y += factor * *x;
            }
        }
        let diag = col_j[j];
        if diag.is_nan() || diag <= 0.0 {
            return false;
        }
        let denom = diag.sqrt();
        col_j[j] = denom;
        for y in &mut col_j[j + 1..] {
            *y /= denom;
        }
    }
    true
}

/// `v' M^{-1} v` from the Cholesky factor `L` of `M`, by one triangular solve:
/// `|L^{-1} v|²`.
pub fn mahalanobis_sq<D: Dim>(chol: &Cholesky<f64, D>, v: &OVector<f64, D>) -> f64
where
    DefaultAllocator: Allocator<D, D> + Allocator<D>,
{
    let w = chol
        .l_dirty()
        .solve_lower_triangular(v)
        .expect("a Cholesky factor has a nonzero diagonal");
    w.norm_squared()
}

/// The inverse of the lower-triangular Cholesky factor, `L^{-1}`, so that
/// `v' M^{-1} v = |L^{-1} v|²` costs one matrix-vector product when `M` is shared.
pub fn inverse_cholesky_factor(chol: &Cholesky<f64, Dyn>) -> DMatrix<f64> {
    let l = chol.l();
    let n = l.nrows();
    l.solve_lower_triangular(&DMatrix::identity(n, n))
        .expect("a Cholesky factor has a nonzero diagonal")
}

/// `M⁻¹` (n × n, symmetric) from the lower Cholesky factor `l` of `M` (its lower triangle
/// is read): `L⁻¹` by forward substitution, then `L⁻ᵀ L⁻¹`, in plain loops. The exact
/// scoring weighs every step's quadratic forms by the same P⁻¹ and S⁻¹; at a filter's sizes
/// nalgebra's column-by-column triangular solves cost several times these loops.
pub fn spd_inverse(l: &DMatrix<f64>) -> DMatrix<f64> {
    let mut out = DMatrix::zeros(0, 0);
    spd_inverse_into(l, &mut Vec::new(), &mut out);
    out
}

/// [`spd_inverse`] into `out` (reshaped to n × n, its storage kept where it has that shape),
/// `L⁻¹` in `w`'s storage: the same loops, without allocating at each step of a recursion.
pub fn spd_inverse_into(l: &DMatrix<f64>, w: &mut Vec<f64>, out: &mut DMatrix<f64>) {
    let n = l.nrows();
    let lv = l.as_slice();
    // W = L⁻¹, lower triangular, column-major.
    w.clear();
    w.resize(n * n, 0.0);
    for j in 0..n {
        w[j + j * n] = 1.0 / lv[j + j * n];
        for i in j + 1..n {
            let s: f64 = (j..i).map(|k| lv[i + k * n] * w[k + j * n]).sum();
            w[i + j * n] = -s / lv[i + i * n];
        }
    }
    // Every entry is written below.
    products::shaped(out, n, n);
    for j in 0..n {
        for i in j..n {
            let s: f64 = (i..n).map(|k| w[k + i * n] * w[k + j * n]).sum();
            out[(i, j)] = s;
            out[(j, i)] = s;
        }
    }
}

/// The fixed-size copy of a dynamic matrix or vector, or `None` when its shape is not
/// `R × C`.
#[inline]
pub fn to_fixed<const R: usize, const C: usize, RD: Dim, CD: Dim, S>(
    m: &Matrix<f64, RD, CD, S>,
) -> Option<SMatrix<f64, R, C>>
where
    S: RawStorage<f64, RD, CD> + IsContiguous,
{
    (m.shape() == (R, C)).then(|| SMatrix::from_column_slice(m.as_slice()))
}

/// The dynamic copy of a fixed-size matrix.
#[inline]
pub fn to_dynamic<const R: usize, const C: usize>(m: &SMatrix<f64, R, C>) -> DMatrix<f64> {
    DMatrix::from_column_slice(R, C, m.as_slice())
}

/// Write a fixed-size matrix (or vector, `C = 1`) into a dynamic one, in place when the
/// shapes agree (a filter's estimate keeps its allocations from step to step), replacing it
/// otherwise.
#[inline]
pub fn store<CD: Dim, const R: usize, const C: usize>(
    dst: &mut OMatrix<f64, Dyn, CD>,
    src: &SMatrix<f64, R, C>,
) where
    DefaultAllocator: Allocator<Dyn, CD>,
{
    if dst.shape() == (R, C) {
        dst.as_mut_slice().copy_from_slice(src.as_slice());
    } else {
        *dst = OMatrix::from_column_slice_generic(Dyn(R), CD::from_usize(C), src.as_slice());
    }
}

/// Matrix exponential `e^M` of a square matrix (Padé approximation with scaling and
/// squaring, as implemented by nalgebra).
pub fn expm(m: &DMatrix<f64>) -> DMatrix<f64> {
    m.clone().exp()
}

/// Principal matrix logarithm `log M` of a square matrix with no eigenvalue on the closed
/// negative real axis, by inverse scaling and squaring: square roots (Denman–Beavers) until
/// `M^(1/2^k)` is within 0.25 of the identity, where the series of `log(I + Y)` converges
/// fast, then `2^k` times that series. `None` when a square root does not converge (a
/// singular matrix, or an eigenvalue on the negative real axis: no real logarithm).
pub fn logm(m: &DMatrix<f64>) -> Option<DMatrix<f64>> {
    let n = m.nrows();
    let id = DMatrix::<f64>::identity(n, n);
    let mut x = m.clone();
    let mut k = 0;
    while (&x - &id).norm() > 0.25 {
        if k == 40 {
            return None;
        }
        x = sqrtm(&x)?;
        k += 1;
    }
    let y = &x - &id;
    let mut power = y.clone();
    let mut sum = y.clone();
    for j in 2..=80 {
        power = &power * &y;
        let sign = if j % 2 == 0 { -1.0 } else { 1.0 };
        sum += &power * (sign / j as f64);
        if power.norm() < 1e-17 {
            break;
        }
    }
    let log = sum * 2f64.powi(k);
    log.iter().all(|v| v.is_finite()).then_some(log)
}

/// Principal square root by the Denman–Beavers iteration; `None` when it does not converge.
fn sqrtm(a: &DMatrix<f64>) -> Option<DMatrix<f64>> {
    let n = a.nrows();
    let mut y = a.clone();
    let mut z = DMatrix::<f64>::identity(n, n);
    for _ in 0..100 {
        let yi = y.clone().try_inverse()?;
        let zi = z.clone().try_inverse()?;
        let y_next = (&y + zi) * 0.5;
        let z_next = (&z + yi) * 0.5;
        let change = (&y_next - &y).norm();
        y = y_next;
        z = z_next;
        if !y.iter().all(|v| v.is_finite()) {
            return None;
        }
        if change <= 1e-14 * y.norm() {
            return Some(y);
        }
    }
    None
}

/// `M^s` for a real exponent `s`, as `e^{s log M}` ([`logm`]); `None` without a real
/// logarithm. A transition matrix over one step `dt` raised to `s` is the transition over
/// `s · dt` for a time-invariant system.
pub fn real_power(m: &DMatrix<f64>, s: f64) -> Option<DMatrix<f64>> {
    logm(m).map(|l| expm(&(l * s)))
}

/// Van Loan's method: the discrete covariance `∫₀^dt e^{Aτ} Qc e^{A'τ} dτ` of white noise
/// with spectral density `Qc` driving `ẋ = A x`, over one sample period `dt` (s).
pub fn van_loan(a: &DMatrix<f64>, qc: &DMatrix<f64>, dt: f64) -> DMatrix<f64> {
    let n = a.nrows();
    let mut m = DMatrix::zeros(2 * n, 2 * n);
    m.view_mut((0, 0), (n, n)).copy_from(&(-a * dt));
    m.view_mut((0, n), (n, n)).copy_from(&(qc * dt));
    m.view_mut((n, n), (n, n)).copy_from(&(a.transpose() * dt));
    let e = expm(&m);
    let f_t = e.view((n, n), (n, n)).clone_owned();
    let upper = e.view((0, n), (n, n)).clone_owned();
    let mut q = f_t.transpose() * upper;
    symmetrize(&mut q);
    q
}

/// Wrap an angle, rad, to (−π, π] (NaN stays NaN): bearing innovations and heading errors.
pub fn wrap_angle(a: f64) -> f64 {
    use std::f64::consts::{PI, TAU};
    let r = (a + PI).rem_euclid(TAU) - PI;
    if r <= -PI { r + TAU } else { r }
}

#[cfg(test)]
mod tests {
    use nalgebra::{Cholesky, DMatrix};

    #[test]
    fn spd_inverse_inverts_ill_scaled_matrices() {
        // Sizes 1 to 12, entries spanning six decades (a position beside a rate), checked
        // against LU's inverse and by the product with M.
        for n in 1..=12usize {
            let b = DMatrix::from_fn(n, n, |i, j| ((i * 7 + j * 3) % 11) as f64 - 5.0);
            let d = DMatrix::from_fn(n, n, |i, j| {
                if i == j {
                    10f64.powi(i as i32 % 6 - 3)
                } else {
                    0.0
                }
            });
            let m = &d * (&b * b.transpose() + DMatrix::identity(n, n)) * &d;
            let l = Cholesky::new(m.clone()).unwrap().l();
            let inv = super::spd_inverse(&l);
            let lu = m.clone().try_inverse().unwrap();
            let scale = lu.amax();
            assert!((&inv - &lu).amax() <= 1e-9 * scale, "n = {n}");
            assert_eq!(inv, inv.transpose());
            let id = &d * (&inv * &m) * d.try_inverse().unwrap();
            assert!((id - DMatrix::identity(n, n)).amax() < 1e-9, "n = {n}");
        }
    }

    #[test]
    fn cholesky_in_place_is_nalgebras_factor_bit_for_bit() {
        // Covariances of every size from 1 to 16, from B B' + εI with B's entries spread
        // over six decades (so rounding is exercised), and matrices nalgebra refuses: the
        // factor must be nalgebra's in every bit, and the refusals the same.
        let mut state = 0x9E37_79B9_7F4A_7C15_u64;
        let mut next = move || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 11) as f64 / (1u64 << 53) as f64 - 0.5
        };
        for n in 1..=16 {
            for trial in 0..20 {
                let b = DMatrix::from_fn(n, n, |_, _| next() * 10f64.powf(6.0 * next()));
                let mut m = &b * b.transpose() + DMatrix::identity(n, n) * 1e-9;
                if trial % 5 == 4 {
                    m[(n - 1, n - 1)] = -m[(n - 1, n - 1)];
                }
                let want = Cholesky::new(m.clone()).map(|c| c.unpack_dirty());
                let mut got = m.clone();
                let ok = super::cholesky_in_place(&mut got);
                match want {
                    Some(w) => {
                        assert!(ok, "n = {n}, trial {trial}: refused");
                        let bits =
                            |x: &DMatrix<f64>| x.iter().map(|v| v.to_bits()).collect::<Vec<_>>();
                        assert_eq!(bits(&got), bits(&w), "n = {n}, trial {trial}");
                    }
                    None => assert!(!ok, "n = {n}, trial {trial}: nalgebra refuses"),
                }
            }
        }
    }

    #[test]
    fn logm_inverts_expm_and_powers_a_constant_velocity_transition() {
        // A constant-velocity F over 1 s: its log is the nilpotent [[0, 1], [0, 0]], and
        // F^0.5 is the transition over 0.5 s.
        let f = nalgebra::DMatrix::from_row_slice(2, 2, &[1.0, 1.0, 0.0, 1.0]);
        let l = super::logm(&f).unwrap();
        let want = nalgebra::DMatrix::from_row_slice(2, 2, &[0.0, 1.0, 0.0, 0.0]);
        assert!((&l - &want).norm() < 1e-12, "{l}");
        let half = super::real_power(&f, 0.5).unwrap();
        let want = nalgebra::DMatrix::from_row_slice(2, 2, &[1.0, 0.5, 0.0, 1.0]);
        assert!((&half - &want).norm() < 1e-12, "{half}");
        // A damped rotation (complex eigenvalues): log(e^A) = A for A of small norm.
        let a = nalgebra::DMatrix::from_row_slice(
            3,
            3,
            &[-0.1, 0.8, 0.0, -0.8, -0.2, 0.3, 0.1, 0.0, -0.5],
        );
        let back = super::logm(&super::expm(&a)).unwrap();
        assert!((&back - &a).norm() < 1e-10, "{back}");
        // No real logarithm: a reflection has eigenvalue −1.
        let r = nalgebra::DMatrix::from_row_slice(2, 2, &[-1.0, 0.0, 0.0, 1.0]);
        assert!(super::logm(&r).is_none());
    }

    use super::*;
    use approx::assert_relative_eq;

    #[test]
    fn psd_factor_reproduces_singular_matrix() {
        // DWNA block: rank one.
        let g = DMatrix::from_column_slice(2, 1, &[0.5, 1.0]);
        let q = &g * g.transpose() * 3.0;
        let l = psd_factor(&q).unwrap();
        assert_eq!(l.ncols(), 1);
        assert_relative_eq!(&l * l.transpose(), q, epsilon = 1e-12);
    }

    #[test]
    fn psd_factor_keeps_tiny_variances_next_to_huge_ones() {
        let m = DMatrix::from_diagonal(&DVector::from_column_slice(&[1e-10, 1e4]));
        let l = psd_factor(&m).unwrap();
        assert_eq!(l.ncols(), 2);
        assert_relative_eq!(&l * l.transpose(), m, max_relative = 1e-12);
        assert!(is_positive_definite(&m));
        assert!(!is_positive_definite(&DMatrix::from_diagonal(
            &DVector::from_column_slice(&[0.0, 1.0])
        )));
    }

    #[test]
    fn psd_factor_rejects_indefinite() {
        let m = DMatrix::from_row_slice(2, 2, &[1.0, 2.0, 2.0, 1.0]);
        let err = psd_factor(&m).unwrap_err();
        assert_relative_eq!(err, -1.0, epsilon = 1e-12);
    }

    #[test]
    fn van_loan_matches_cwna_closed_form() {
        // ẋ = [[0,1],[0,0]] x + [0,1]' w, spectral density q: Q = q [[dt³/3, dt²/2],[dt²/2, dt]].
        let a = DMatrix::from_row_slice(2, 2, &[0.0, 1.0, 0.0, 0.0]);
        let qc = DMatrix::from_row_slice(2, 2, &[0.0, 0.0, 0.0, 2.0]);
        let dt = 0.1;
        let q = van_loan(&a, &qc, dt);
        let want = DMatrix::from_row_slice(
            2,
            2,
            &[
                2.0 * dt.powi(3) / 3.0,
                2.0 * dt.powi(2) / 2.0,
                2.0 * dt.powi(2) / 2.0,
                2.0 * dt,
            ],
        );
        assert_relative_eq!(q, want, max_relative = 1e-10);
    }

    #[test]
    fn mahalanobis_matches_explicit_inverse() {
        let m = DMatrix::from_row_slice(2, 2, &[4.0, 1.0, 1.0, 3.0]);
        let v = DVector::from_column_slice(&[1.0, -2.0]);
        let chol = cholesky(&m).unwrap();
        let want = (v.transpose() * m.try_inverse().unwrap() * &v)[(0, 0)];
        assert_relative_eq!(mahalanobis_sq(&chol, &v), want, max_relative = 1e-13);
        let w = inverse_cholesky_factor(&chol) * &v;
        assert_relative_eq!(w.norm_squared(), want, max_relative = 1e-13);
    }

    #[test]
    fn same_bits_tells_negative_zero_from_zero_and_a_nan_by_its_bits() {
        let m = |v: &[f64]| DMatrix::from_column_slice(2, 1, v);
        assert!(same_bits(&m(&[1.0, f64::NAN]), &m(&[1.0, f64::NAN])));
        assert!(!same_bits(&m(&[1.0, 0.0]), &m(&[1.0, -0.0])));
        assert!(!same_bits(&m(&[1.0, 2.0]), &m(&[1.0, 2.0 + 4e-16])));
        assert!(!same_bits(
            &m(&[1.0, 2.0]),
            &DMatrix::from_column_slice(1, 2, &[1.0, 2.0])
        ));
        assert!(same_bits(&DMatrix::zeros(0, 3), &DMatrix::zeros(0, 3)));
    }

    #[test]
    fn a_factor_in_reused_storage_is_choleskys_and_a_bad_matrix_has_none() {
        let a = DMatrix::from_row_slice(3, 3, &[4.0, 1.0, 0.5, 1.0, 3.0, -0.2, 0.5, -0.2, 2.0]);
        let b = DMatrix::from_row_slice(2, 2, &[2.0, 0.3, 0.3, 1.0]);
        // Storage of another shape, then of the same shape, then none.
        let from_b = cholesky_reusing(&a, cholesky(&b)).unwrap();
        let again = cholesky_reusing(&a, Some(from_b)).unwrap();
        assert_eq!(again.l_dirty(), cholesky(&a).unwrap().l_dirty());
        assert_eq!(
            cholesky_reusing(&b, None).unwrap().l_dirty(),
            cholesky(&b).unwrap().l_dirty()
        );
        let mut nan = a.clone();
        nan[(2, 1)] = f64::NAN;
        assert!(cholesky_reusing(&nan, Some(again)).is_none());
        let indefinite = DMatrix::from_row_slice(2, 2, &[1.0, 2.0, 2.0, 1.0]);
        assert!(cholesky_reusing(&indefinite, cholesky(&b)).is_none());
    }
}
