//! Nonlinear filters: the extended and the unscented Kalman filter, over a [`SystemModel`].

#![allow(non_snake_case)]

use nalgebra::{DMatrix, DVector};

use super::joseph::joseph_update;
use super::unscented::{self, SigmaMeasurement, SigmaWeights};
use super::{
    Estimate, Filter, FilterError, Innovation, PredictResult, UpdateResult, check_measurement,
};
use crate::linalg::{mahalanobis_sq, symmetrize};
use crate::measurement::Measurement;

/// An analytic Jacobian, or `None` for central finite differences.
pub type Jacobian = Option<DMatrix<f64>>;

/// A system as a nonlinear filter sees it: `x_k = f_k(x_{k−1}) + w_k`,
/// `z_k = h_{k,s}(x_k) + v_k` for each sensor s.
pub trait SystemModel: Sync {
    /// State dimension n_x.
    fn n_x(&self) -> usize;

    /// Dimension of each sensor's measurement.
    fn sensor_dims(&self) -> Vec<usize>;

    /// The state transition f_k (from step k − 1 to step k).
    fn transition(&self, k: usize, x: &DVector<f64>) -> DVector<f64>;

    /// `∂f_k/∂x` at `x` (n × n); `None` (the default) means central finite differences.
    fn transition_jacobian(&self, _k: usize, _x: &DVector<f64>) -> Jacobian {
        None
    }

    /// The transition driven by process noise `w`, `x_k = f_k(x_{k−1}, w_k)`, for the UKF
    /// with augmented process noise; `None` (the default) when the model has no such form.
    fn transition_with_noise(
        &self,
        _k: usize,
        _x: &DVector<f64>,
        _w: &DVector<f64>,
    ) -> Option<DVector<f64>> {
        None
    }

    /// The measurement function of `sensor` at step k.
    fn measurement(&self, k: usize, sensor: usize, x: &DVector<f64>) -> DVector<f64>;

    /// `∂h/∂x` at `x` (m_s × n); `None` (the default) means central finite differences.
    fn measurement_jacobian(&self, _k: usize, _sensor: usize, _x: &DVector<f64>) -> Jacobian {
        None
    }

    /// The innovation `z − ẑ`; override to wrap angles (e.g. a bearing into (−π, π]).
    fn residual(&self, _sensor: usize, z: &DVector<f64>, z_hat: &DVector<f64>) -> DVector<f64> {
        z - z_hat
    }

    /// The UKF's predicted measurement: the weighted mean `Σ w_i z_i` of the sigma points'
    /// measurements `zs` (weights `wm` sum to 1, the centre one may be negative). Override
    /// for angles: the plain sum of bearings near ±π (e.g. 3.1 and −3.1) averages to 0
    /// instead of π, so an angle's mean should be taken relative to one of the points with
    /// wrapped differences.
    fn measurement_mean(&self, _sensor: usize, zs: &[DVector<f64>], wm: &[f64]) -> DVector<f64> {
        unscented::weighted_sum(zs, wm.iter().copied())
    }
}

/// Central finite-difference Jacobian of `g` at `x`, with steps `1e-6·max(1, |x_i|)`
/// (close to the cube root of machine epsilon, which balances truncation and rounding).
pub fn numerical_jacobian(
    g: impl Fn(&DVector<f64>) -> DVector<f64>,
    x: &DVector<f64>,
) -> DMatrix<f64> {
    let n = x.len();
    let m = g(x).len();
    let mut J = DMatrix::zeros(m, n);
    for i in 0..n {
        let h = 1e-6 * x[i].abs().max(1.0);
        let mut xp = x.clone();
        let mut xm = x.clone();
        xp[i] += h;
        xm[i] -= h;
        let d = (g(&xp) - g(&xm)) / (2.0 * h);
        J.set_column(i, &d);
    }
    J
}

/// The extended Kalman filter: linearizes f and h at the current estimate, with the
/// model's analytic Jacobians or finite differences, and updates in Joseph form.
#[derive(Debug, Clone)]
pub struct Ekf<M> {
    /// The filter's system model.
    pub model: M,
    /// Process noise covariance per step, n × n.
    pub Q: DMatrix<f64>,
    /// Measurement noise covariance of each sensor, m_s × m_s.
    pub R: Vec<DMatrix<f64>>,
    /// Initial estimate.
    pub x0: DVector<f64>,
    /// Initial covariance.
    pub P0: DMatrix<f64>,
}

impl<M: SystemModel> Ekf<M> {
    fn f_jacobian(&self, k: usize, x: &DVector<f64>) -> DMatrix<f64> {
        self.model
            .transition_jacobian(k, x)
            .unwrap_or_else(|| numerical_jacobian(|v| self.model.transition(k, v), x))
    }

    fn h_jacobian(&self, k: usize, s: usize, x: &DVector<f64>) -> DMatrix<f64> {
        self.model
            .measurement_jacobian(k, s, x)
            .unwrap_or_else(|| numerical_jacobian(|v| self.model.measurement(k, s, v), x))
    }
}

impl<M: SystemModel> Filter for Ekf<M> {
    fn sensor_dims(&self) -> Vec<usize> {
        self.model.sensor_dims()
    }

    fn initial(&self) -> Estimate {
        Estimate::new(&self.x0, &self.P0)
    }

    fn predict(&self, k: usize, est: &mut Estimate) -> PredictResult {
        let F = self.f_jacobian(k, &est.x);
        est.x = self.model.transition(k, &est.x);
        let mut P = &F * &est.P * F.transpose() + &self.Q;
        symmetrize(&mut P);
        est.P = P;
        est.error_map = Some(F);
        Ok(())
    }

    fn update(&self, k: usize, est: &mut Estimate, meas: &Measurement) -> UpdateResult {
        check_measurement(self.sensor_dims().get(meas.sensor).copied(), meas)?;
        let s = meas.sensor;
        let H = self.h_jacobian(k, s, &est.x);
        let cu = joseph_update(&est.P, &H, &self.R[s], k)?;
        let nu = self
            .model
            .residual(s, &meas.z, &self.model.measurement(k, s, &est.x));
        est.x += &cu.K * &nu;
        est.P = cu.P;
        est.compose_error_map(&cu.IKH);
        let (chol, S) = (cu.chol, cu.S);
        let nis = mahalanobis_sq(&chol, &nu);
        Ok(Innovation { nu, S, nis })
    }
}

/// The unscented Kalman filter with additive noise and the scaled sigma points of Julier
/// (2002) / van der Merwe: 2n + 1 points at `x ± columns of √((n + λ) P)`,
/// `λ = α² (n + κ) − n`, mean weights `λ/(n+λ)` and `1/(2(n+λ))`, and covariance weight
/// `λ/(n+λ) + 1 − α² + β` for the centre point (`unscented` holds the arithmetic).
#[derive(Debug, Clone)]
pub struct Ukf<M> {
    /// The system model, the noise covariances and the initial estimate: the five things an
    /// [`Ekf`] is made of (Q is added after propagation unless the noise is augmented).
    pub design: Ekf<M>,
    /// Spread of the sigma points around the mean (0 < α ≤ 1; default 1).
    pub alpha: f64,
    /// Prior knowledge of the distribution (2 is optimal for Gaussians).
    pub beta: f64,
    /// Secondary scaling (default 0).
    pub kappa: f64,
    /// Covariance of the process noise w for augmented sigma points (non-additive noise
    /// through [`SystemModel::transition_with_noise`]); `None` adds `Q` after propagation.
    pub augmented_noise: Option<DMatrix<f64>>,
}

impl<M: SystemModel> Ukf<M> {
    /// A UKF with α = 1, β = 2, κ = 0.
    pub fn new(
        model: M,
        Q: DMatrix<f64>,
        R: Vec<DMatrix<f64>>,
        x0: DVector<f64>,
        P0: DMatrix<f64>,
    ) -> Self {
        Ukf {
            design: Ekf {
                model,
                Q,
                R,
                x0,
                P0,
            },
            alpha: 1.0,
            beta: 2.0,
            kappa: 0.0,
            augmented_noise: None,
        }
    }

    /// The sigma points of `(x, P)` and their weights.
    fn sigma(
        &self,
        x: &DVector<f64>,
        P: &DMatrix<f64>,
        step: usize,
    ) -> Result<(Vec<DVector<f64>>, SigmaWeights), FilterError> {
        let n = x.len();
        let w = SigmaWeights::new(n, self.alpha, self.beta, self.kappa);
        let L = unscented::sigma_factor(P, w.spread)
            .ok_or(FilterError::NotPositiveDefinite { which: "P", step })?;
        let mut offsets = vec![DVector::zeros(n); 2 * n + 1];
        unscented::fill_offsets(&L, &mut offsets);
        Ok((offsets.iter().map(|d| x + d).collect(), w))
    }
}

impl<M: SystemModel> Filter for Ukf<M> {
    fn sensor_dims(&self) -> Vec<usize> {
        self.design.model.sensor_dims()
    }

    fn initial(&self) -> Estimate {
        Estimate::new(&self.design.x0, &self.design.P0)
    }

    fn predict(&self, k: usize, est: &mut Estimate) -> PredictResult {
        let n = est.x.len();
        // Additive noise: sigma points of x, Q added after. Augmented: sigma points of
        // [x; w] with covariance blkdiag(P, Q_w), each propagated through f(x, w).
        let (pts, w, prop, cov0) = match &self.augmented_noise {
            None => {
                let (pts, w) = self.sigma(&est.x, &est.P, k)?;
                let prop: Vec<DVector<f64>> = pts
                    .iter()
                    .map(|p| self.design.model.transition(k, p))
                    .collect();
                (pts, w, prop, self.design.Q.clone())
            }
            Some(qw) => {
                let q = qw.nrows();
                let mut xa = DVector::zeros(n + q);
                xa.rows_mut(0, n).copy_from(&est.x);
                let mut pa = DMatrix::zeros(n + q, n + q);
                pa.view_mut((0, 0), (n, n)).copy_from(&est.P);
                pa.view_mut((n, n), (q, q)).copy_from(qw);
                let (apts, w) = self.sigma(&xa, &pa, k)?;
                let mut prop = Vec::with_capacity(apts.len());
                for a in &apts {
                    let x = a.rows(0, n).clone_owned();
                    let w = a.rows(n, q).clone_owned();
                    prop.push(self.design.model.transition_with_noise(k, &x, &w).ok_or(
                        FilterError::Unsupported {
                            what: "transition_with_noise (needed for augmented process noise)",
                        },
                    )?);
                }
                let pts = apts.iter().map(|a| a.rows(0, n).clone_owned()).collect();
                (pts, w, prop, DMatrix::zeros(n, n))
            }
        };
        let offsets: Vec<DVector<f64>> = pts.iter().map(|p| p - &est.x).collect();
        let m = unscented::moments(&prop, &offsets, &w, cov0);
        // Statistical linearization of f: the F with which a linear filter would produce the
        // same cross covariance, F = C P⁻¹ (used for the NEES correlation model).
        let F = unscented::linearize(&est.P, &m.cross.transpose()).ok_or(
            FilterError::NotPositiveDefinite {
                which: "P",
                step: k,
            },
        )?;
        est.x = m.mean;
        est.P = m.cov;
        est.error_map = Some(F);
        Ok(())
    }

    fn update(&self, k: usize, est: &mut Estimate, meas: &Measurement) -> UpdateResult {
        check_measurement(self.sensor_dims().get(meas.sensor).copied(), meas)?;
        let s = meas.sensor;
        let (pts, weights) = self.sigma(&est.x, &est.P, k)?;
        let zs: Vec<DVector<f64>> = pts
            .iter()
            .map(|p| self.design.model.measurement(k, s, p))
            .collect();
        let wm: Vec<f64> = weights.means().take(zs.len()).collect();
        let z_hat = self.design.model.measurement_mean(s, &zs, &wm);
        let offsets: Vec<DVector<f64>> = pts.iter().map(|p| p - &est.x).collect();
        let sm = SigmaMeasurement {
            weights,
            offsets: &offsets,
            zs: &zs,
            z_hat: &z_hat,
        };
        let u = unscented::update(
            &est.x,
            &est.P,
            &sm,
            &meas.z,
            &self.design.R[s],
            |a, b| self.design.model.residual(s, a, b),
            k,
        )?;
        est.x = u.x;
        est.P = u.P;
        est.compose_error_map(&u.IKH);
        Ok(Innovation {
            nu: u.nu,
            S: u.S,
            nis: u.nis,
        })
    }
}

/// A linear system `f(x) = F x`, `h(x) = H x` as a [`SystemModel`] (one sensor), for running
/// the nonlinear filters on linear problems (and checking them against the KF).
#[derive(Debug, Clone)]
pub struct LinearSystem {
    /// State transition, n × n.
    pub F: DMatrix<f64>,
    /// Measurement matrix, m × n.
    pub H: DMatrix<f64>,
}

impl SystemModel for LinearSystem {
    fn n_x(&self) -> usize {
        self.F.nrows()
    }

    fn sensor_dims(&self) -> Vec<usize> {
        vec![self.H.nrows()]
    }

    fn transition(&self, _k: usize, x: &DVector<f64>) -> DVector<f64> {
        &self.F * x
    }

    fn transition_jacobian(&self, _k: usize, _x: &DVector<f64>) -> Jacobian {
        Some(self.F.clone())
    }

    fn measurement(&self, _k: usize, _sensor: usize, x: &DVector<f64>) -> DVector<f64> {
        &self.H * x
    }

    fn measurement_jacobian(&self, _k: usize, _sensor: usize, _x: &DVector<f64>) -> Jacobian {
        Some(self.H.clone())
    }
}
