//! The catalog's UKF for `ctrv_radar_lidar`, on fixed-size matrices.
//!
//! The unscented arithmetic is [`crate::filter::unscented`]'s; what is this filter's own is
//! which points it propagates. The augmented state `[x; w]` has a block-diagonal covariance
//! `blkdiag(P, diag(q))`, so its Cholesky factor is block diagonal too: the four noise points
//! are `x` with `±√(spread q_i)` in `w_i`, and since they start at `x` and the noise enters
//! additively given yaw, their images are the centre's noise-free image plus a fixed
//! increment. Eleven transitions are evaluated instead of fifteen.

#![allow(non_snake_case)]

use nalgebra::{
    Const, DVector, Matrix2, Matrix3, Matrix5, SMatrix, SVector, U2, U3, U5, Vector2, Vector3,
    Vector5,
};

use super::system::{BEARING, CtrvSystem, radar_of};
use super::{LIDAR, RADAR};
use crate::filter::unscented::{self, SigmaMeasurement, SigmaUpdate, SigmaWeights};
use crate::filter::{
    Estimate, Filter, FilterError, Innovation, PredictResult, UpdateResult, check_measurement,
    update_by_into,
};
use crate::linalg::wrap_angle;
use crate::measurement::Measurement;

/// The UKF over [`CtrvSystem`] on fixed-size matrices, with the yaw error wrapped to
/// (−π, π].
///
/// It computes what [`crate::filter::Ukf`] with augmented process noise computes on the
/// same [`CtrvSystem`] (the tests check agreement to 1e-9;
/// [`super::CtrvModel::reference_ukf`] builds that one), without the generic filter's heap
/// allocations, which made up about half of a Monte Carlo evaluation's time.
#[derive(Debug, Clone)]
pub struct CtrvFilter {
    /// The system model.
    pub system: CtrvSystem,
    /// Process-noise variances `[q_accel ((m/s²)²), q_yaw_accel ((rad/s²)²)]`.
    pub q: [f64; 2],
    /// Lidar noise covariance, 2 × 2, m².
    pub R_lidar: Matrix2<f64>,
    /// Radar noise covariance, 3 × 3, in (m, rad, m/s)².
    pub R_radar: Matrix3<f64>,
    /// Initial estimate.
    pub x0: Vector5<f64>,
    /// Initial covariance.
    pub P0: Matrix5<f64>,
    /// Sigma-point scaling `(α, β, κ)`.
    pub scaling: (f64, f64, f64),
}

/// A prediction: mean (5), covariance (5 × 5), and the statistically linearized
/// transition `F` (5 × 5).
pub type Predicted = (Vector5<f64>, Matrix5<f64>, Matrix5<f64>);

impl CtrvFilter {
    fn weights(&self, n: usize) -> SigmaWeights {
        let (alpha, beta, kappa) = self.scaling;
        SigmaWeights::new(n, alpha, beta, kappa)
    }

    /// The prediction from step k − 1 to k on fixed-size state (eleven transitions of the
    /// augmented sigma points); [`Filter::predict`] is this on the estimate.
    pub fn predict_fixed(
        &self,
        k: usize,
        x: &Vector5<f64>,
        P: &Matrix5<f64>,
    ) -> Result<Predicted, FilterError> {
        let not_pd = FilterError::NotPositiveDefinite {
            which: "P",
            step: k,
        };
        // Sigma points of the augmented [x; w] (n = 7): offsets of x at 1..=5 and 8..=12,
        // the noise points at 6, 7, 13, 14 with zero offset in x.
        let w = self.weights(7);
        let L = unscented::sigma_factor(P, w.spread).ok_or(not_pd.clone())?;
        let qa = (self.q[0] * w.spread).sqrt();
        let qy = (self.q[1] * w.spread).sqrt();
        if !(qa.is_finite() && qa > 0.0 && qy.is_finite() && qy > 0.0) {
            return Err(not_pd);
        }
        let mut dx = [Vector5::zeros(); 15];
        unscented::fill_offsets(&L, &mut dx);
        let centre = Vector5::from(self.system.step(x.as_slice(), 0.0, 0.0));
        let mut prop = [centre; 15];
        for i in (1..=5).chain(8..=12) {
            prop[i] = Vector5::from(self.system.step((x + dx[i]).as_slice(), 0.0, 0.0));
        }
        // The same numbers `step(x, ±qa, ±qy)` gives, without evaluating the turn again.
        let T = self.system.dt;
        let (s, c) = x[3].sin_cos();
        let h = 0.5 * T * T;
        let na = Vector5::new(h * c * qa, h * s * qa, T * qa, 0.0, 0.0);
        let ny = Vector5::new(0.0, 0.0, 0.0, h * qy, T * qy);
        prop[6] = centre + na;
        prop[7] = centre + ny;
        prop[13] = centre - na;
        prop[14] = centre - ny;
        let m = unscented::moments(&prop, &dx, &w, Matrix5::zeros());
        // Statistical linearization F = C P⁻¹ for the NEES correlation model.
        let F = unscented::linearize(P, &m.cross.transpose()).ok_or(not_pd)?;
        Ok((m.mean, m.cov, F))
    }

    /// Lidar's update at step `k` with its position fix `z` (m, 2) on fixed-size state:
    /// the posterior, the innovation and its NIS ([`unscented::update`]).
    pub fn update_lidar(
        &self,
        k: usize,
        x: &Vector5<f64>,
        P: &Matrix5<f64>,
        z: &Vector2<f64>,
    ) -> Result<SigmaUpdate<U5, U2>, FilterError> {
        let h = |x: &Vector5<f64>| Vector2::new(x[0], x[1]);
        self.sigma_update(k, x, P, z, &self.R_lidar, h, None)
    }

    /// The radar's update at step `k` with its measurement `z` (range m, bearing rad,
    /// range rate m/s) on fixed-size state, the bearing's mean and residual taken on the
    /// circle.
    pub fn update_radar(
        &self,
        k: usize,
        x: &Vector5<f64>,
        P: &Matrix5<f64>,
        z: &Vector3<f64>,
    ) -> Result<SigmaUpdate<U5, U3>, FilterError> {
        let h = |x: &Vector5<f64>| Vector3::from(radar_of(x.as_slice()));
        self.sigma_update(k, x, P, z, &self.R_radar, h, Some(BEARING))
    }

    /// The unscented update through `h`, with component `angle` (if any) an angle.
    #[allow(clippy::too_many_arguments)]
    fn sigma_update<const M: usize>(
        &self,
        k: usize,
        x: &Vector5<f64>,
        P: &Matrix5<f64>,
        z: &SVector<f64, M>,
        R: &SMatrix<f64, M, M>,
        h: impl Fn(&Vector5<f64>) -> SVector<f64, M>,
        angle: Option<usize>,
    ) -> Result<SigmaUpdate<U5, Const<M>>, FilterError> {
        let w = self.weights(5);
        let L = unscented::sigma_factor(P, w.spread).ok_or(FilterError::NotPositiveDefinite {
            which: "P",
            step: k,
        })?;
        let mut dx = [Vector5::zeros(); 11];
        unscented::fill_offsets(&L, &mut dx);
        let zs: [SVector<f64, M>; 11] = std::array::from_fn(|i| h(&(x + dx[i])));
        let mut z_hat = unscented::weighted_sum(&zs, w.means());
        if let Some(j) = angle {
            z_hat[j] = unscented::circular_mean(&zs, w.means(), j);
        }
        let sm = SigmaMeasurement {
            weights: w,
            offsets: &dx,
            zs: &zs,
            z_hat: &z_hat,
        };
        let residual = |a: &SVector<f64, M>, b: &SVector<f64, M>| {
            let mut d = a - b;
            if let Some(j) = angle {
                d[j] = wrap_angle(d[j]);
            }
            d
        };
        unscented::update(x, P, &sm, z, R, residual, k)
    }
}

impl Filter for CtrvFilter {
    fn n_x(&self) -> usize {
        5
    }

    fn sensor_dims(&self) -> Vec<usize> {
        vec![2, 3]
    }

    fn initial(&self) -> Estimate {
        Estimate::from_fixed(&self.x0, &self.P0)
    }

    fn predict(&self, k: usize, est: &mut Estimate) -> PredictResult {
        let (x, P) = est.fixed::<5>()?;
        let (x, P, F) = self.predict_fixed(k, &x, &P)?;
        est.set_fixed(&x, &P);
        est.set_error_map(&F);
        Ok(())
    }

    fn step_length(&self) -> Option<f64> {
        Some(self.system.dt)
    }

    /// The same CTRV transition and noise held over `dt` instead of the filter's step: the
    /// model is closed-form in its step length.
    fn predict_over(&self, k: usize, est: &mut Estimate, dt: f64) -> PredictResult {
        let mut over = self.clone();
        over.system.dt = dt;
        over.predict(k, est)
    }

    fn update(&self, k: usize, est: &mut Estimate, meas: &Measurement) -> UpdateResult {
        update_by_into(self, k, est, meas)
    }

    fn update_into(
        &self,
        k: usize,
        est: &mut Estimate,
        meas: &Measurement,
        out: &mut Innovation,
    ) -> Result<(), FilterError> {
        let dim = match meas.sensor {
            LIDAR => Some(2),
            RADAR => Some(3),
            _ => None,
        };
        check_measurement(dim, meas)?;
        if est.error_map.as_ref().is_some_and(|a| a.shape() != (5, 5)) {
            return Err(FilterError::Unsupported {
                what: "an error map of the filter's dimension",
            });
        }
        let (x, P) = est.fixed::<5>()?;
        match meas.sensor {
            LIDAR => {
                let z = Vector2::from_column_slice(meas.z.as_slice());
                into_estimate(est, self.update_lidar(k, &x, &P, &z)?, out);
            }
            _ => {
                let z = Vector3::from_column_slice(meas.z.as_slice());
                into_estimate(est, self.update_radar(k, &x, &P, &z)?, out);
            }
        }
        Ok(())
    }

    fn state_error(&self, truth: &DVector<f64>, estimate: &DVector<f64>) -> DVector<f64> {
        let mut e = truth - estimate;
        if e.len() == 5 {
            e[3] = wrap_angle(e[3]);
        }
        e
    }

    fn state_error_into(
        &self,
        truth: &DVector<f64>,
        estimate: &DVector<f64>,
        out: &mut DVector<f64>,
    ) {
        if out.len() == 5 && truth.len() == 5 && estimate.len() == 5 {
            out.zip_zip_apply(truth, estimate, |e, t, x| *e = t - x);
            out[3] = wrap_angle(out[3]);
        } else {
            *out = self.state_error(truth, estimate);
        }
    }
}

/// Write an update's posterior into the estimate (and compose its error map), and its
/// innovation into `out`.
fn into_estimate<const M: usize>(
    est: &mut Estimate,
    u: SigmaUpdate<U5, Const<M>>,
    out: &mut Innovation,
) {
    est.set_fixed(&u.x, &u.P);
    est.compose_error_map_fixed(&u.IKH);
    out.set_fixed(&u.nu, &u.S, u.nis);
}
