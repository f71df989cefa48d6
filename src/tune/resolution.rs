//! How precisely the data pin down each parameter, from the objective's curvature at the
//! optimum.
//!
//! With Hessian H of J in log-parameters, J rises by `δ²/(2 (H⁻¹)_ii)` when parameter i
//! moves by δ and the others re-adjust; solving for a rise equal to the noise floor (J's
//! Monte Carlo noise level) gives `δ_i = √(2 floor (H⁻¹)_ii)` and the factor `e^{δ_i}`. A
//! flat direction (parameters that enter only together) has a zero eigenvalue, which makes
//! `(H⁻¹)_ii` and the factor huge.

use nalgebra::{DMatrix, SymmetricEigen};

use super::cost::Cost;
use super::result::Resolution;

/// Central-difference step of the Hessian, log units (5%).
const H: f64 = 0.05;
/// A parameter that can move by more than this factor is not identifiable.
const MAX_FACTOR: f64 = 2.0;

/// Per-parameter resolution at the optimum `y` (free parameters' log values) for a rise of
/// `floor`; `fixed` flags every parameter, in problem order. Costs `1 + 2d²` evaluations
/// of `cost`, not charged to the search's budget.
pub(super) fn resolution(
    cost: &Cost<'_>,
    y: &[f64],
    floor: f64,
    fixed: &[bool],
) -> Vec<Resolution> {
    let inv_diag = inverse_hessian_diagonal(cost, y);
    let mut out = Vec::with_capacity(fixed.len());
    let mut k = 0;
    for &fx in fixed {
        if fx {
            out.push(Resolution::FIXED);
        } else {
            let delta = (2.0 * floor * inv_diag[k]).sqrt();
            let factor = delta.exp();
            let at_bound = cost.near_bound(k, y);
            out.push(Resolution {
                factor: Some(factor),
                identifiable: factor.is_finite() && factor <= MAX_FACTOR && !at_bound,
                at_bound,
            });
            k += 1;
        }
    }
    out
}

/// The diagonal of H⁻¹ at `y`, with H's eigenvalues floored at 1e-12 of the largest so a
/// flat direction gives a huge entry instead of an infinite or negative one.
fn inverse_hessian_diagonal(cost: &Cost<'_>, y: &[f64]) -> Vec<f64> {
    let d = y.len();
    let f = |v: &[f64]| cost.objective_at(v);
    let f0 = f(y);
    let mut hess = DMatrix::zeros(d, d);
    let shift = |a: usize, sa: f64, b: Option<(usize, f64)>| {
        let mut v = y.to_vec();
        v[a] += sa;
        if let Some((bi, sb)) = b {
            v[bi] += sb;
        }
        v
    };
    for a in 0..d {
        let fp = f(&shift(a, H, None));
        let fm = f(&shift(a, -H, None));
        hess[(a, a)] = (fp - 2.0 * f0 + fm) / (H * H);
        for b in 0..a {
            let fpp = f(&shift(a, H, Some((b, H))));
            let fpm = f(&shift(a, H, Some((b, -H))));
            let fmp = f(&shift(a, -H, Some((b, H))));
            let fmm = f(&shift(a, -H, Some((b, -H))));
            let v = (fpp - fpm - fmp + fmm) / (4.0 * H * H);
            hess[(a, b)] = v;
            hess[(b, a)] = v;
        }
    }
    let eig = SymmetricEigen::new(hess);
    let lmax = eig.eigenvalues.iter().fold(0.0_f64, |a, v| a.max(v.abs()));
    let floor_l = (1e-12 * lmax).max(1e-300);
    (0..d)
        .map(|i| {
            (0..d)
                .map(|k| eig.eigenvectors[(i, k)].powi(2) / eig.eigenvalues[k].max(floor_l))
                .sum()
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::tune::tests::{Mock, cost};

    #[test]
    fn matches_the_analytic_curvature_of_a_quadratic() {
        // p0 and p2 drive one component each with exponents 1 and 2, p1 is fixed:
        // J = ((y0* − y0)² + 4 (y2* − y2)²) / 2, H = diag(1, 4), and at a floor of 0.02
        // δ0 = √(2 · 0.02 · 1) = 0.2 and δ2 = √(2 · 0.02 / 4) = 0.1. Central differences of
        // a quadratic are exact but for rounding: J ≈ 1e-3 at the steps, so the Hessian is
        // good to ~1e-12 relative; 1e-9 leaves room.
        let mock = Mock::new(&[0.5, 1.0, 4.0], &[&[1.0, 0.0, 0.0], &[0.0, 0.0, 2.0]]);
        let fixed = [false, true, false];
        let cost = cost(&mock, &fixed);
        let y = [0.5f64.ln(), 4f64.ln()];
        let res = resolution(&cost, &y, 0.02, &fixed);
        assert_eq!(res[1], Resolution::FIXED);
        for (i, delta) in [(0, 0.2f64), (2, 0.1)] {
            let f = res[i].factor.unwrap();
            assert!((f / delta.exp() - 1.0).abs() < 1e-9, "p{i}: {f}");
            assert!(
                res[i].identifiable && !res[i].at_bound,
                "p{i}: {:?}",
                res[i]
            );
        }
        // Within 5% of the lower bound (1e-4): at a bound, so not identifiable.
        let near_lower = [1e-4f64.ln() + 0.01, 4f64.ln()];
        let res = resolution(&cost, &near_lower, 0.02, &fixed);
        assert!(res[0].at_bound && !res[0].identifiable, "{:?}", res[0]);
        assert!(!res[2].at_bound, "{:?}", res[2]);
    }
}
