//! Whether a covariance can be inverted meaningfully.
//!
//! The NEES `e' P⁻¹ e`, the NIS `ν' S⁻¹ ν` and the gain `P⁻ H' S⁻¹` all solve with a
//! covariance, and a Kalman update forms `P` from `P⁻` by cancellation. Rounding perturbs
//! each entry of such a matrix by about `u = 1.1e-16` relative to itself, so what matters is
//! the condition number of the matrix scaled to a unit diagonal (Jacobi scaling,
//! `C = D^{-1/2} M D^{-1/2}`, `D = diag(M)`): it does not depend on units, and a solve with
//! `M` has relative error about `κ(C) u` (van der Sluis 1969; Higham, *Accuracy and Stability
//! of Numerical Algorithms*, 2002, §7.3 and §10.1).
//!
//! The bound is [`MAX_CONDITION`] = 1e12: there the NEES and NIS keep about 4 significant
//! digits (relative error 1.1e-4), a hundred times finer than the narrowest gate interval the
//! tool builds (about ±1.4% at N·T·n = 40 000 degrees of freedom), so no verdict moves. Above
//! it the rounding reaches the interval's width within two decades, and at `κ ≈ 1/u ≈ 9e15`
//! no digit is left: a 1-D tracker with `q_accel = 1e18` reported an ANEES of 1e17 from such a
//! matrix. A covariance beyond the bound is a [`FilterError::IllConditioned`], recorded as a
//! divergence with its reason, never a number.
//!
//! The check is cheap where the matrix is fine. With `M = L L'`, the scaled matrix's Cholesky
//! pivots are `d_i = L_ii² / M_ii`, the variance of state i given the states before it
//! relative to its own; each is at least `λ_min(C)`, and `λ_max(C) ≥ 1` (the mean of its
//! eigenvalues is 1), so `1 / min d_i ≤ 1/λ_min ≤ κ(C)`. Only when that lower bound exceeds
//! [`SCREEN`] (1e-4 of the bound) are the eigenvalues computed; for two collinear states the
//! pivot bound is within a factor 4 of κ.

#![allow(non_snake_case)]

use nalgebra::{Cholesky, DMatrix, Dyn, SymmetricEigen};

use super::error::FilterError;
pub use super::error::{MAX_CONDITION, describe};
use crate::linalg::jacobi_scaled;

/// Pivot bound below which the eigenvalues are not computed: 1e-4 of [`MAX_CONDITION`].
pub const SCREEN: f64 = MAX_CONDITION * 1e-4;

/// The condition number `λ_max / λ_min` of `m` scaled to a unit diagonal (symmetric, with a
/// positive diagonal); infinite when the scaled matrix is singular or indefinite.
pub fn scaled_condition(m: &DMatrix<f64>) -> f64 {
    let eig = SymmetricEigen::new(jacobi_scaled(m).0).eigenvalues;
    let max = eig.iter().fold(f64::NEG_INFINITY, |a, &v| a.max(v));
    let min = eig.iter().fold(f64::INFINITY, |a, &v| a.min(v));
    if min > 0.0 { max / min } else { f64::INFINITY }
}

/// `Err(IllConditioned)` when the covariance `m`, with Cholesky factor `chol`, has a
/// Jacobi-scaled condition number above [`MAX_CONDITION`]; `which` names it and `step` is
/// the time step.
pub fn check_conditioned(
    which: &'static str,
    m: &DMatrix<f64>,
    chol: &Cholesky<f64, Dyn>,
    step: usize,
) -> Result<(), FilterError> {
    check_conditioned_factor(which, m, chol.l_dirty(), step)
}

/// [`check_conditioned`] from the lower Cholesky factor `l` of `m` in a plain matrix (its
/// lower triangle is read; [`crate::linalg::cholesky_in_place`] gives it).
pub fn check_conditioned_factor(
    which: &'static str,
    m: &DMatrix<f64>,
    l: &DMatrix<f64>,
    step: usize,
) -> Result<(), FilterError> {
    let bound = (0..m.nrows()).fold(0.0_f64, |a, i| a.max(m[(i, i)] / (l[(i, i)] * l[(i, i)])));
    if bound <= SCREEN {
        return Ok(());
    }
    let condition = scaled_condition(m);
    if condition > MAX_CONDITION {
        return Err(FilterError::IllConditioned {
            which,
            step,
            condition,
        });
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::linalg::cholesky;

    /// A 2 × 2 covariance with unit variances and correlation `rho`, its entries scaled by
    /// `s1` and `s2` (units must not matter).
    fn pair(rho: f64, s1: f64, s2: f64) -> DMatrix<f64> {
        DMatrix::from_row_slice(2, 2, &[s1 * s1, rho * s1 * s2, rho * s1 * s2, s2 * s2])
    }

    #[test]
    fn condition_is_unit_free() {
        // κ of [[1, ρ], [ρ, 1]] is (1 + ρ) / (1 − ρ).
        for (s1, s2) in [(1.0, 1.0), (1e-6, 1e6), (1e8, 3.0)] {
            let k = scaled_condition(&pair(0.5, s1, s2));
            assert!((k - 3.0).abs() < 1e-9, "{k}");
        }
    }

    #[test]
    fn a_nearly_collinear_pair_is_ill_conditioned_and_a_mildly_correlated_one_is_not() {
        let check = |m: &DMatrix<f64>| check_conditioned("P", m, &cholesky(m).unwrap(), 7);
        // κ = (1 + ρ)/(1 − ρ) ≈ 2e6: fine, and screened out without eigenvalues.
        assert!(check(&pair(1.0 - 1e-6, 1e-3, 1e4)).is_ok());
        // κ ≈ 2e13: beyond the bound, whatever the units.
        match check(&pair(1.0 - 1e-13, 1e-3, 1e4)) {
            Err(FilterError::IllConditioned {
                which: "P",
                step: 7,
                condition,
            }) => assert!((1e13..1e14).contains(&condition), "{condition}"),
            other => panic!("{other:?}"),
        }
    }

    #[test]
    fn a_three_state_dependency_is_caught_though_no_pair_is_collinear() {
        // x3 = x1 + x2 (+ tiny noise) with x1, x2 independent: pairwise correlations are
        // only 1/√2, but the matrix is singular to 1e-14.
        let m =
            DMatrix::from_row_slice(3, 3, &[1.0, 0.0, 1.0, 0.0, 1.0, 1.0, 1.0, 1.0, 2.0 + 1e-14]);
        let chol = cholesky(&m).unwrap();
        assert!(matches!(
            check_conditioned("P⁻", &m, &chol, 1),
            Err(FilterError::IllConditioned { .. })
        ));
    }
}
