//! The Joseph-form covariance update, written once for every filter and size: the KF and
//! the EKF call it on dynamic matrices, the catalog's fixed-size EKFs on static ones.
//!
//! From the prior `P⁻` (n × n), the measurement matrix or Jacobian `H` (m × n) and the
//! noise `R` (m × m):
//!
//! ```text
//! S = (H P⁻) H' + R                         symmetrized, Cholesky-factored
//! K = (S⁻¹ (H P⁻))'                          two triangular solves, no inverse
//! P = (I − K H) P⁻ (I − K H)' + K R K'       symmetrized
//! ```
//!
//! The Joseph form keeps `P` positive semidefinite for any gain, not only the optimal one
//! (Bar-Shalom, Li and Kirubarajan 2001, §5.2.3). The products are written in this one
//! association for every size, so a filter's numbers do not depend on which of them runs it.

#![allow(non_snake_case)]

use nalgebra::allocator::Allocator;
use nalgebra::{Cholesky, DMatrix, DefaultAllocator, Dim, Dyn, OMatrix};

use super::FilterError;
use crate::linalg::products::{Sparse, shaped};
use crate::linalg::{cholesky, cholesky_reusing, symmetrize};

/// The data-independent half of a Kalman update, for state dimension `N` and measurement
/// dimension `M` (dynamic by default).
#[derive(Debug, Clone)]
pub struct CovarianceUpdate<N: Dim = Dyn, M: Dim = Dyn>
where
    DefaultAllocator: Allocator<N, N> + Allocator<N, M> + Allocator<M, M>,
{
    /// Gain, n × m.
    pub K: OMatrix<f64, N, M>,
    /// Innovation covariance, m × m.
    pub S: OMatrix<f64, M, M>,
    /// Cholesky factor of S.
    pub chol: Cholesky<f64, M>,
    /// Posterior covariance, n × n.
    pub P: OMatrix<f64, N, N>,
    /// `I − K H`, n × n.
    pub IKH: OMatrix<f64, N, N>,
}

/// The covariance half of a Kalman update with measurement matrix (or Jacobian) `H`
/// (m × n) and noise `R` (m × m) from the prior `P⁻` (n × n, symmetric): gain `K` solving
/// `S K' = H P⁻` by Cholesky (no inverse), `S = H P⁻ H' + R`, and the Joseph-form posterior
/// `(I − K H) P⁻ (I − K H)' + K R K'`, symmetrized.
///
/// Fails with [`FilterError::NotPositiveDefinite`] naming `"S"` when S has no Cholesky
/// factor, and `"P"` when the posterior has a non-finite entry.
// Inlined so that a fixed-size caller keeps the result where it computed it: returned
// through memory, the five matrices cost the catalog's 4-state EKF about 13% of an update.
#[inline]
pub fn joseph_update<N: Dim, M: Dim>(
    Pp: &OMatrix<f64, N, N>,
    H: &OMatrix<f64, M, N>,
    R: &OMatrix<f64, M, M>,
    step: usize,
) -> Result<CovarianceUpdate<N, M>, FilterError>
where
    DefaultAllocator: Allocator<N, N> + Allocator<M, N> + Allocator<N, M> + Allocator<M, M>,
{
    let HP = H * Pp;
    let mut S = &HP * H.transpose() + R;
    symmetrize(&mut S);
    let chol = cholesky(&S).ok_or(FilterError::NotPositiveDefinite { which: "S", step })?;
    let K = chol.solve(&HP).transpose();
    let (n, _) = Pp.shape_generic();
    let IKH = OMatrix::identity_generic(n, n) - &K * H;
    let mut P = &IKH * Pp * IKH.transpose() + &K * R * K.transpose();
    symmetrize(&mut P);
    if P.iter().any(|v| !v.is_finite()) {
        return Err(FilterError::NotPositiveDefinite { which: "P", step });
    }
    Ok(CovarianceUpdate { K, S, chol, P, IKH })
}

/// A dynamic-size update's storage for [`joseph_update_sparse`]: the update, K and
/// `I − K H` as product operands, and the intermediate products. Kept from step to step,
/// a recursion allocates nothing after its first steps.
pub(crate) struct SparseUpdate {
    /// The update (its storage written over at each step).
    pub(crate) cu: CovarianceUpdate,
    /// K and `I − K H` as product operands.
    pub(crate) k_op: Sparse,
    pub(crate) ikh_op: Sparse,
    hp: DMatrix<f64>,
    scratch: DMatrix<f64>,
    scratch_r: DMatrix<f64>,
    krk: DMatrix<f64>,
    /// The factor of S of the step before the last, whose storage the next factor takes.
    spare_chol: Option<Cholesky<f64, Dyn>>,
}

impl Default for SparseUpdate {
    fn default() -> Self {
        let empty = || DMatrix::zeros(0, 0);
        SparseUpdate {
            cu: CovarianceUpdate {
                K: empty(),
                S: empty(),
                chol: Cholesky::new(DMatrix::identity(1, 1)).expect("the identity's factor"),
                P: empty(),
                IKH: empty(),
            },
            k_op: Sparse::new(&empty()),
            ikh_op: Sparse::new(&empty()),
            hp: empty(),
            scratch: empty(),
            scratch_r: empty(),
            krk: empty(),
            spare_chol: None,
        }
    }
}

/// [`joseph_update`] for a dynamic-size filter whose `H` is held by its nonzeros (`h`,
/// m × n), every product over the operands' nonzeros instead of a general multiplication
/// (which packs its operands first: at a dozen states that costs as much as the
/// arithmetic), into `out`'s storage. The same formulas and failures; the sums run in
/// another order, so the result agrees with [`joseph_update`]'s to rounding, not to the
/// bit. K and `I − K H` are also left as operands, for callers that multiply by them
/// again. `out` is left partly written when the update fails.
pub(crate) fn joseph_update_sparse(
    Pp: &DMatrix<f64>,
    h: &Sparse,
    R: &DMatrix<f64>,
    step: usize,
    out: &mut SparseUpdate,
) -> Result<(), FilterError> {
    let (n, m) = (Pp.nrows(), R.nrows());
    let cu = &mut out.cu;
    h.left_into(Pp.as_slice(), n, &mut out.hp);
    h.right_tr_into(&out.hp, &mut cu.S);
    cu.S += R;
    symmetrize(&mut cu.S);
    let chol = cholesky_reusing(&cu.S, out.spare_chol.take())
        .ok_or(FilterError::NotPositiveDefinite { which: "S", step })?;
    out.spare_chol = Some(std::mem::replace(&mut cu.chol, chol));
    // K = (S⁻¹ H P⁻)', solved in a copy of H P⁻ as Cholesky::solve does.
    shaped(&mut out.scratch, m, n);
    out.scratch.copy_from(&out.hp);
    cu.chol.solve_mut(&mut out.scratch);
    shaped(&mut cu.K, n, m);
    out.scratch.transpose_to(&mut cu.K);
    // I − K H: the negated product with 1 added on the diagonal, the same bits.
    h.right_into(&cu.K, &mut cu.IKH);
    cu.IKH.neg_mut();
    for j in 0..cu.IKH.nrows() {
        cu.IKH[(j, j)] += 1.0;
    }
    out.k_op.reset(&cu.K);
    out.ikh_op.reset(&cu.IKH);
    out.ikh_op
        .sandwich_into(Pp, &out.ikh_op, &mut out.scratch, &mut cu.P);
    out.k_op
        .sandwich_into(R, &out.k_op, &mut out.scratch_r, &mut out.krk);
    cu.P += &out.krk;
    symmetrize(&mut cu.P);
    if cu.P.iter().any(|v| !v.is_finite()) {
        return Err(FilterError::NotPositiveDefinite { which: "P", step });
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_relative_eq;
    use nalgebra::{DMatrix, Matrix2, Matrix2x4, Matrix4};

    fn problem() -> (Matrix4<f64>, Matrix2x4<f64>, Matrix2<f64>) {
        let A = Matrix4::from_fn(|i, j| ((i * 4 + j) as f64 * 0.37).sin());
        let P = A * A.transpose() + Matrix4::identity();
        let H = Matrix2x4::new(1.0, 0.5, 0.0, -0.2, 0.0, 1.0, 0.3, 0.0);
        (P, H, Matrix2::new(0.4, 0.1, 0.1, 0.3))
    }

    #[test]
    fn fixed_and_dynamic_sizes_give_the_same_bits() {
        // Small products sum in index order whatever the storage, so the catalog's
        // fixed-size filters and the dynamic KF compute the same numbers.
        let (P, H, R) = problem();
        let fixed = joseph_update(&P, &H, &R, 1).unwrap();
        let dynamic = joseph_update(
            &DMatrix::from_column_slice(4, 4, P.as_slice()),
            &DMatrix::from_column_slice(2, 4, H.as_slice()),
            &DMatrix::from_column_slice(2, 2, R.as_slice()),
            1,
        )
        .unwrap();
        assert_eq!(fixed.P.as_slice(), dynamic.P.as_slice());
        assert_eq!(fixed.K.as_slice(), dynamic.K.as_slice());
        assert_eq!(fixed.S.as_slice(), dynamic.S.as_slice());
    }

    #[test]
    fn posterior_is_the_optimal_gain_form_and_symmetric() {
        let (P, H, R) = problem();
        let cu = joseph_update(&P, &H, &R, 1).unwrap();
        assert_relative_eq!(
            cu.P,
            (Matrix4::identity() - cu.K * H) * P,
            max_relative = 1e-12
        );
        assert_eq!(cu.P, cu.P.transpose());
    }

    #[test]
    fn indefinite_s_is_an_error_naming_s() {
        let (P, H, _) = problem();
        let bad_r = Matrix2::new(-1e6, 0.0, 0.0, 1.0);
        assert_eq!(
            joseph_update(&P, &H, &bad_r, 3).unwrap_err(),
            FilterError::NotPositiveDefinite {
                which: "S",
                step: 3
            }
        );
        let dynamic = |m: &[f64], r: usize, c: usize| DMatrix::from_column_slice(r, c, m);
        let h = Sparse::new(&dynamic(H.as_slice(), 2, 4));
        assert_eq!(
            joseph_update_sparse(
                &dynamic(P.as_slice(), 4, 4),
                &h,
                &dynamic(bad_r.as_slice(), 2, 2),
                3,
                &mut SparseUpdate::default(),
            )
            .err(),
            Some(FilterError::NotPositiveDefinite {
                which: "S",
                step: 3
            })
        );
    }

    /// A matrix of pseudo-random entries in [−1, 1), about a third of them exactly zero (a
    /// fixed pattern from `seed`).
    fn entries(r: usize, c: usize, seed: u64) -> DMatrix<f64> {
        let mut state = seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1;
        DMatrix::from_fn(r, c, |_, _| {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            let u = (state >> 11) as f64 / (1u64 << 53) as f64;
            if u < 0.33 { 0.0 } else { 2.0 * u - 1.0 }
        })
    }

    #[test]
    fn over_nonzeros_it_is_the_dense_update_to_rounding() {
        // Sizes on both sides of nalgebra's switch to a packed multiplication (above 5),
        // magnitudes over six decades. Every entry within 1e-15 of the matrix's largest:
        // the two differ only in the order of sums of up to a dozen terms (measured: at
        // most 1.3e-16, at 12 states).
        let mut reused = SparseUpdate::default();
        for (i, &(n, m)) in [(1, 1), (2, 1), (4, 2), (6, 3), (9, 3), (12, 4), (12, 1)]
            .iter()
            .enumerate()
        {
            let seed = 10 * i as u64;
            let a = entries(n, n, seed);
            let scale = DMatrix::from_fn(n, n, |r, c| {
                if r == c {
                    10f64.powi(r as i32 % 7 - 3)
                } else {
                    0.0
                }
            });
            let Pp = &scale * (&a * a.transpose() + DMatrix::identity(n, n)) * &scale;
            let mut H = entries(m, n, seed + 1);
            H[(0, 0)] = 1.0;
            let b = entries(m, m, seed + 2);
            let R = &b * b.transpose() + DMatrix::identity(m, m) * 0.5;
            let dense = joseph_update(&Pp, &H, &R, 1).unwrap();
            // Into storage of another shape's update (reshaped), as a recursion reuses it.
            let mut out = SparseUpdate::default();
            joseph_update_sparse(&Pp, &Sparse::new(&H), &R, 1, &mut reused).unwrap();
            joseph_update_sparse(&Pp, &Sparse::new(&H), &R, 1, &mut out).unwrap();
            assert_eq!(
                reused.cu.P, out.cu.P,
                "the same bits in reused storage {n}×{m}"
            );
            assert_eq!(reused.cu.K, out.cu.K);
            let SparseUpdate {
                cu: sparse,
                k_op,
                ikh_op,
                ..
            } = out;
            let close = |x: &DMatrix<f64>, y: &DMatrix<f64>, what: &str| {
                let top = y.iter().fold(0.0f64, |t, v| t.max(v.abs()));
                let worst = (x - y).iter().fold(0.0f64, |t, v| t.max(v.abs()));
                assert!(
                    worst <= 1e-15 * top,
                    "{what} {n}×{m}: off by {worst:e} of {top:e}"
                );
            };
            close(&sparse.P, &dense.P, "P");
            close(&sparse.K, &dense.K, "K");
            close(&sparse.S, &dense.S, "S");
            close(&sparse.IKH, &dense.IKH, "I − K H");
            assert_eq!(sparse.P, sparse.P.transpose(), "P symmetric {n}×{m}");
            // The operands are the matrices returned beside them.
            assert_eq!(k_op.left(&DMatrix::identity(m, m)), sparse.K);
            assert_eq!(ikh_op.left(&DMatrix::identity(n, n)), sparse.IKH);
        }
    }
}
