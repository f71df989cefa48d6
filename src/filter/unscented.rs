//! The scaled unscented transform, written once for the generic [`super::Ukf`] (dynamic
//! matrices) and the catalog's fixed-size UKF: weights, sigma points, the moments of
//! propagated points, and the measurement update from the points' predicted measurements.
//!
//! With n dimensions and `λ = α² (n + κ) − n` (Julier 2002; van der Merwe 2004), the
//! 2n + 1 sigma points sit at `x` and `x ± L_i`, `L_i` the columns of the Cholesky factor
//! of `(n + λ) P`. Point 0 has mean weight `λ/(n+λ)` and covariance weight
//! `λ/(n+λ) + 1 − α² + β`; every other point has `1/(2(n+λ))` for both.
//!
//! Everything is generic over nalgebra dimensions, so the same arithmetic, in the same
//! order, serves `Dyn` and `Const<N>`. Callers keep what is their own: which points they
//! propagate (a filter may reuse one point's image for others), the predicted measurement
//! (a model may average angles on the circle), and the residual (a model may wrap angles).

#![allow(non_snake_case)]

use nalgebra::allocator::Allocator;
use nalgebra::{Cholesky, DefaultAllocator, Dim, OMatrix, OVector, U1};

use super::FilterError;
use crate::linalg::{cholesky, mahalanobis_sq, symmetrize, wrap_angle};

/// Weights of the scaled unscented transform in n dimensions.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SigmaWeights {
    /// Mean weight of point 0, `λ/(n+λ)`.
    pub mean0: f64,
    /// Covariance weight of point 0, `λ/(n+λ) + 1 − α² + β`.
    pub cov0: f64,
    /// Mean and covariance weight of every other point, `1/(2(n+λ))`.
    pub other: f64,
    /// `n + λ = α² (n + κ)`, the factor P is scaled by before its Cholesky factor gives the
    /// points' offsets.
    pub spread: f64,
}

impl SigmaWeights {
    /// The weights for n dimensions with spread α (0 < α ≤ 1), prior-knowledge β (2 for
    /// Gaussians) and secondary scaling κ.
    pub fn new(n: usize, alpha: f64, beta: f64, kappa: f64) -> Self {
        let n = n as f64;
        let lambda = alpha * alpha * (n + kappa) - n;
        let mean0 = lambda / (n + lambda);
        SigmaWeights {
            mean0,
            cov0: mean0 + 1.0 - alpha * alpha + beta,
            other: 1.0 / (2.0 * (n + lambda)),
            spread: n + lambda,
        }
    }

    /// Mean weight of point `i`.
    pub fn mean(&self, i: usize) -> f64 {
        if i == 0 { self.mean0 } else { self.other }
    }

    /// Covariance weight of point `i`.
    pub fn cov(&self, i: usize) -> f64 {
        if i == 0 { self.cov0 } else { self.other }
    }

    /// The mean weights of points 0, 1, 2, … (an endless sequence: zip it with the points).
    pub fn means(&self) -> impl Iterator<Item = f64> + use<> {
        let (first, other) = (self.mean0, self.other);
        std::iter::once(first).chain(std::iter::repeat(other))
    }
}

/// The factor `L` (n × n, lower triangular) with `L L' = spread · P`, whose columns are the
/// sigma points' offsets; `None` when `P` is not positive definite or not finite.
pub fn sigma_factor<D: Dim>(P: &OMatrix<f64, D, D>, spread: f64) -> Option<OMatrix<f64, D, D>>
where
    DefaultAllocator: Allocator<D, D>,
{
    cholesky(&(P * spread)).map(|c| c.l())
}

/// Write the sigma points' offsets from the mean into `offsets` (2h + 1 of them): column i of
/// `L` at `1 + i` and its negative at `1 + h + i`. The entry of point 0 and those of any
/// dimensions beyond `L`'s columns (the noise dimensions of an augmented state, which a
/// caller treats on its own) are left as they are.
pub fn fill_offsets<D: Dim>(L: &OMatrix<f64, D, D>, offsets: &mut [OVector<f64, D>])
where
    DefaultAllocator: Allocator<D, D> + Allocator<D>,
{
    let h = offsets.len().saturating_sub(1) / 2;
    for i in 0..L.ncols().min(h) {
        let c = L.column(i).into_owned();
        offsets[1 + h + i] = -&c;
        offsets[1 + i] = c;
    }
}

/// `Σ w_i p_i`, summed in index order from zero (weights beyond the points are ignored).
/// Empty `points` give a zero-length vector, which only a dynamic dimension has.
pub fn weighted_sum<D: Dim>(
    points: &[OVector<f64, D>],
    weights: impl IntoIterator<Item = f64>,
) -> OVector<f64, D>
where
    DefaultAllocator: Allocator<D>,
{
    let rows = points
        .first()
        .map_or_else(|| D::from_usize(0), |p| p.shape_generic().0);
    let mut sum = OVector::zeros_generic(rows, U1);
    for (p, w) in points.iter().zip(weights) {
        sum += p * w;
    }
    sum
}

/// The weighted mean of component `j` of `points` taken as angles, rad: the offsets from
/// point 0's angle, wrapped to (−π, π], averaged, added back and wrapped. The same as the
/// plain weighted mean when no point crosses ±π, and right when some do (the plain mean of
/// 3.1 and −3.1 is 0, not π).
pub fn circular_mean<D: Dim>(
    points: &[OVector<f64, D>],
    weights: impl IntoIterator<Item = f64>,
    j: usize,
) -> f64
where
    DefaultAllocator: Allocator<D>,
{
    let b0 = points[0][j];
    let mut off = 0.0;
    for (p, w) in points.iter().zip(weights) {
        off += w * wrap_angle(p[j] - b0);
    }
    wrap_angle(b0 + off)
}

/// The first two moments of propagated sigma points.
#[derive(Debug, Clone)]
pub struct Moments<D: Dim, E: Dim>
where
    DefaultAllocator: Allocator<D> + Allocator<D, D> + Allocator<D, E>,
{
    /// Mean `x̄ = Σ w_i p_i`, n.
    pub mean: OVector<f64, D>,
    /// Covariance `cov0 + Σ wc_i (p_i − x̄)(p_i − x̄)'`, symmetrized, n × n.
    pub cov: OMatrix<f64, D, D>,
    /// Cross-covariance `C = Σ wc_i (p_i − x̄) d_i'` of the output with the input offsets,
    /// n × e.
    pub cross: OMatrix<f64, D, E>,
}

/// The [`Moments`] of propagated sigma points `points` (the images `p_i` under the
/// transition) whose inputs were offset by `offsets[i]` (`d_i`) from the prior mean;
/// `cov0` is additive process noise, or zero.
#[inline]
pub fn moments<D: Dim, E: Dim>(
    points: &[OVector<f64, D>],
    offsets: &[OVector<f64, E>],
    w: &SigmaWeights,
    cov0: OMatrix<f64, D, D>,
) -> Moments<D, E>
where
    DefaultAllocator: Allocator<D>
        + Allocator<E>
        + Allocator<D, D>
        + Allocator<D, E>
        + Allocator<U1, D>
        + Allocator<U1, E>,
{
    let mean = weighted_sum(points, w.means());
    let mut P = cov0;
    let mut C = OMatrix::zeros_generic(mean.shape_generic().0, offsets[0].shape_generic().0);
    for (i, (p, d)) in points.iter().zip(offsets).enumerate() {
        let wc = w.cov(i);
        let e = p - &mean;
        P += &e * e.transpose() * wc;
        C += &e * d.transpose() * wc;
    }
    symmetrize(&mut P);
    Moments {
        mean,
        cov: P,
        cross: C,
    }
}

/// Statistical linearization: the matrix `Pxy' P⁻¹` (E × D) with which a linear map would
/// produce the cross-covariance `Pxy` (D × E) from the prior covariance `P`, by one Cholesky
/// solve; `None` when `P` is not positive definite. For a prediction, `Pxy = C'` gives the
/// transition `F = C P⁻¹`; for an update, `Pxy = Pxz` gives the measurement matrix H.
pub fn linearize<D: Dim, E: Dim>(
    P: &OMatrix<f64, D, D>,
    Pxy: &OMatrix<f64, D, E>,
) -> Option<OMatrix<f64, E, D>>
where
    DefaultAllocator: Allocator<D, D> + Allocator<D, E> + Allocator<E, D>,
{
    cholesky(P).map(|c| c.solve(Pxy).transpose())
}

/// One measurement as the sigma points of the prior predict it.
#[derive(Debug, Clone, Copy)]
pub struct SigmaMeasurement<'a, D: Dim, M: Dim>
where
    DefaultAllocator: Allocator<D> + Allocator<M>,
{
    /// The weights the points were drawn with.
    pub weights: SigmaWeights,
    /// Each point's offset from the prior mean, n.
    pub offsets: &'a [OVector<f64, D>],
    /// Each point's predicted measurement, m.
    pub zs: &'a [OVector<f64, M>],
    /// The predicted measurement ẑ (the model's mean of `zs`), m.
    pub z_hat: &'a OVector<f64, M>,
}

/// The result of an unscented measurement update.
#[derive(Debug, Clone)]
pub struct SigmaUpdate<D: Dim, M: Dim>
where
    DefaultAllocator: Allocator<D> + Allocator<M> + Allocator<D, D> + Allocator<M, M>,
{
    /// Posterior mean, n.
    pub x: OVector<f64, D>,
    /// Posterior covariance `P − K S K'`, symmetrized, n × n.
    pub P: OMatrix<f64, D, D>,
    /// Innovation ν = residual(z, ẑ), m.
    pub nu: OVector<f64, M>,
    /// Innovation covariance, m × m.
    pub S: OMatrix<f64, M, M>,
    /// Cholesky factor of S.
    pub chol: Cholesky<f64, M>,
    /// ν' S⁻¹ ν.
    pub nis: f64,
    /// `I − K H` with the statistically linearized `H = Pxz' P⁻¹`, n × n (for the error
    /// map).
    pub IKH: OMatrix<f64, D, D>,
}

/// The unscented update of the prior `(x, P)` by the measurement `z` with noise `R`:
/// `S = R + Σ wc_i δz_i δz_i'`, `Pxz = Σ wc_i d_i δz_i'` with `δz_i = residual(z_i, ẑ)`,
/// `K = Pxz S⁻¹` by Cholesky, `x + K ν`, `P − K S K'`.
///
/// `residual(a, b)` is the model's `a − b` (wrapping angles where it has them). Fails with
/// [`FilterError::NotPositiveDefinite`] naming `"S"` or `"P"` at `step`.
// Inlined for the reason joseph_update is: a fixed-size caller's result stays in place.
#[inline]
pub fn update<D: Dim, M: Dim>(
    x: &OVector<f64, D>,
    P: &OMatrix<f64, D, D>,
    sm: &SigmaMeasurement<'_, D, M>,
    z: &OVector<f64, M>,
    R: &OMatrix<f64, M, M>,
    residual: impl Fn(&OVector<f64, M>, &OVector<f64, M>) -> OVector<f64, M>,
    step: usize,
) -> Result<SigmaUpdate<D, M>, FilterError>
where
    DefaultAllocator: Allocator<D>
        + Allocator<M>
        + Allocator<D, D>
        + Allocator<M, M>
        + Allocator<D, M>
        + Allocator<M, D>
        + Allocator<U1, M>,
{
    let mut S = R.clone();
    let mut Pxz = OMatrix::zeros_generic(x.shape_generic().0, z.shape_generic().0);
    for (i, (zi, d)) in sm.zs.iter().zip(sm.offsets).enumerate() {
        let wc = sm.weights.cov(i);
        let dz = residual(zi, sm.z_hat);
        S += &dz * dz.transpose() * wc;
        Pxz += d * dz.transpose() * wc;
    }
    symmetrize(&mut S);
    let chol = cholesky(&S).ok_or(FilterError::NotPositiveDefinite { which: "S", step })?;
    let K = chol.solve(&Pxz.transpose()).transpose();
    let nu = residual(z, sm.z_hat);
    let H = linearize(P, &Pxz).ok_or(FilterError::NotPositiveDefinite { which: "P", step })?;
    let x = x + &K * &nu;
    let mut P = P - &K * &S * K.transpose();
    symmetrize(&mut P);
    let (n, _) = P.shape_generic();
    let IKH = OMatrix::identity_generic(n, n) - &K * &H;
    let nis = mahalanobis_sq(&chol, &nu);
    Ok(SigmaUpdate {
        x,
        P,
        nu,
        S,
        chol,
        nis,
        IKH,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_relative_eq;
    use nalgebra::{Matrix2, Vector2};

    #[test]
    fn weights_sum_to_one_and_match_the_formulas() {
        let w = SigmaWeights::new(4, 0.5, 2.0, 1.0);
        let lambda = 0.25 * 5.0 - 4.0;
        assert_relative_eq!(w.spread, 4.0 + lambda);
        assert_relative_eq!(w.mean0 + 8.0 * w.other, 1.0, epsilon = 1e-12);
        assert_relative_eq!(w.cov0, w.mean0 + 1.0 - 0.25 + 2.0);
    }

    #[test]
    fn sigma_points_reproduce_mean_and_covariance_through_the_identity() {
        let x = Vector2::new(1.0, -2.0);
        let P = Matrix2::new(2.0, 0.3, 0.3, 0.5);
        let w = SigmaWeights::new(2, 1.0, 2.0, 0.0);
        let L = sigma_factor(&P, w.spread).unwrap();
        let mut d = [Vector2::zeros(); 5];
        fill_offsets(&L, &mut d);
        let pts: Vec<_> = d.iter().map(|d| x + d).collect();
        let m = moments(&pts, &d, &w, Matrix2::zeros());
        assert_relative_eq!(m.mean, x, epsilon = 1e-12);
        assert_relative_eq!(m.cov, P, epsilon = 1e-12);
        assert_relative_eq!(m.cross, P, epsilon = 1e-12);
        let F = linearize(&P, &m.cross.transpose()).unwrap();
        assert_relative_eq!(F, Matrix2::identity(), epsilon = 1e-12);
    }

    #[test]
    fn circular_mean_of_bearings_across_pi() {
        let pts = [Vector2::new(0.0, 3.1), Vector2::new(0.0, -3.1)];
        let m = circular_mean(&pts, [0.5, 0.5], 1);
        assert_relative_eq!(m.abs(), std::f64::consts::PI, epsilon = 1e-12);
        assert_relative_eq!(weighted_sum(&pts, [0.5, 0.5])[1], 0.0);
    }
}
