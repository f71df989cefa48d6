//! `ctrv_radar_lidar`: a constant-turn-rate-and-velocity (CTRV) target tracked by a UKF
//! from a lidar and a radar that take turns.
//!
//! State `x = [px, py, v, yaw, yaw_rate]` (m, m, m/s, rad, rad/s); yaw is not wrapped in
//! the state (the truth and the filter both carry it continuously), and the estimation
//! error of yaw is wrapped to (−π, π].
//!
//! **Truth.** `px' = v cos yaw`, `py' = v sin yaw`, `v' = a`, `yaw' = yaw_rate`,
//! `yaw_rate' = yaw_acc`, integrated by RK4 with `substeps` steps per filter step. The
//! longitudinal acceleration `a ~ N(0, q_accel)` and the yaw acceleration
//! `yaw_acc ~ N(0, q_yaw_accel)` are drawn once per filter step and held over it: the
//! noise model the CTRV filter assumes, so the filter's noise structure is the truth's.
//!
//! **Filter.** The closed-form CTRV transition over `T = dt` with the noise
//! `w = [ν_a, ν_yawdd]` entering as in the usual discretization (Thrun, Burgard and Fox,
//! *Probabilistic Robotics*, 2005, §5.3; Schubert, Richter and Wanielik, "Comparison and
//! evaluation of advanced motion models for vehicle tracking", FUSION 2008):
//!
//! ```text
//! px  += v/ω (sin(yaw + ωT) − sin yaw)  + ½T² cos(yaw) ν_a
//! py  += v/ω (cos yaw − cos(yaw + ωT))  + ½T² sin(yaw) ν_a
//! v   += T ν_a
//! yaw += ωT + ½T² ν_yawdd
//! ω   += T ν_yawdd
//! ```
//!
//! with a Taylor branch for `|ωT| < 1e-3` (the difference quotient loses digits there).
//! The noise enters through `yaw`, so the UKF uses augmented sigma points over
//! `[x; w]` with `w ~ N(0, diag(q_accel, q_yaw_accel))`. The unscented transform uses
//! α = 1, β = 2, κ = 0: λ = 0 makes every mean weight non-negative (the common
//! `λ = 3 − n` gives a weight of −4/3 to the centre point for the 7-dimensional augmented
//! state, which can make the predicted covariance indefinite), and β = 2 is the Gaussian
//! choice.
//!
//! **Sensors.** Both at the origin, taking turns: the lidar (px, py) at odd steps, the
//! radar (range, bearing, range rate) at even steps when the target's range is within
//! `[radar.min_range, radar.max_range]` (no detection otherwise), so the measurement
//! dimension alternates 2 / 3 (or 2 / 0). Bearings are wrapped to (−π, π] in the
//! measurement, in the innovation, and in the UKF's predicted-measurement mean.

#![allow(non_snake_case)]

use nalgebra::{
    Cholesky, DMatrix, DVector, Matrix2, Matrix3, Matrix5, SMatrix, SVector, U5, Vector2, Vector3,
    Vector5,
};
use rand::RngExt;
use rand_distr::StandardNormal;
use serde::Deserialize;

use super::{
    CatalogEntry, CatalogModel, ModelContext, ModelError, ParamInfo, parse_table, positive,
};
use crate::SimRng;
use crate::filter::{
    Estimate, Filter, FilterError, Innovation, SystemModel, Ukf, check_measurement,
};
use crate::measurement::Measurement;
use crate::model::TruthModel;
use crate::params::NoiseKind;

/// Index of the lidar in the filter's sensor list.
pub const LIDAR: usize = 0;
/// Index of the radar in the filter's sensor list.
pub const RADAR: usize = 1;

/// Below this `|ω T|` (rad) the transition uses its Taylor expansion in `ωT`.
const SMALL_TURN: f64 = 1e-3;

/// Ranges below this (m) are clamped in the radar's bearing and range-rate formulas, so a
/// sigma point at the sensor gives finite numbers.
const MIN_RANGE_GUARD: f64 = 1e-6;

/// The filter parameters, in θ order.
const PARAMS: &[ParamInfo] = &[
    ParamInfo {
        name: "q_accel",
        unit: "(m/s²)²",
        about: "variance of the longitudinal acceleration, held over each filter step",
        noise: NoiseKind::Process,
        components: &[2],
    },
    ParamInfo {
        name: "q_yaw_accel",
        unit: "(rad/s²)²",
        about: "variance of the yaw acceleration, held over each filter step",
        noise: NoiseKind::Process,
        components: &[3, 4],
    },
    ParamInfo {
        name: "r_lidar",
        unit: "m²",
        about: "lidar position variance (each axis)",
        noise: NoiseKind::Measurement,
        components: &[0, 1],
    },
    ParamInfo {
        name: "r_radar_range",
        unit: "m²",
        about: "radar range variance",
        noise: NoiseKind::Measurement,
        components: &[2],
    },
    ParamInfo {
        name: "r_radar_bearing",
        unit: "rad²",
        about: "radar bearing variance",
        noise: NoiseKind::Measurement,
        components: &[3],
    },
    ParamInfo {
        name: "r_radar_rate",
        unit: "(m/s)²",
        about: "radar range-rate variance",
        noise: NoiseKind::Measurement,
        components: &[4],
    },
];

/// The catalog entry.
pub const ENTRY: CatalogEntry = CatalogEntry {
    name: "ctrv_radar_lidar",
    about: "CTRV target (px, py, v, yaw, yaw rate), UKF with augmented noise, lidar and radar \
            alternating",
    params: PARAMS,
    build,
};

pub use crate::linalg::wrap_angle;

// ---------------------------------------------------------------------------------------
// Settings

fn default_substeps() -> usize {
    10
}

/// `[model]` minus `name`.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
struct Spec {
    /// RK4 steps of the truth per filter step.
    #[serde(default = "default_substeps")]
    substeps: usize,
    truth: TruthSpec,
    #[serde(default)]
    initial: InitialSpec,
    #[serde(default)]
    radar: RadarSpec,
    #[serde(default)]
    ukf: UkfSpec,
}

fn default_r_lidar() -> f64 {
    0.0225
}
fn default_r_radar_range() -> f64 {
    0.09
}
fn default_r_radar_bearing() -> f64 {
    0.0009
}
fn default_r_radar_rate() -> f64 {
    0.09
}

/// `[model.truth]`: the truth's noise, as variances in the parameters' units.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
struct TruthSpec {
    q_accel: f64,
    q_yaw_accel: f64,
    #[serde(default = "default_r_lidar")]
    r_lidar: f64,
    #[serde(default = "default_r_radar_range")]
    r_radar_range: f64,
    #[serde(default = "default_r_radar_bearing")]
    r_radar_bearing: f64,
    #[serde(default = "default_r_radar_rate")]
    r_radar_rate: f64,
}

/// `[model.initial]`: the initial state's mean and standard deviations (the truth draws
/// from it, the filter starts at its mean with its covariance).
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
struct InitialSpec {
    mean: [f64; 5],
    std: [f64; 5],
}

impl Default for InitialSpec {
    fn default() -> Self {
        // Heading east at 5 m/s, turning left at 0.25 rad/s on a 20 m circle centred at
        // (−30, 0): the target crosses the negative x axis (radar bearing ±π) at about 6 s
        // and 19 s and completes about one lap in 25 s.
        InitialSpec {
            mean: [-30.0, -20.0, 5.0, 0.0, 0.25],
            std: [0.3, 0.3, 0.5, 0.1, 0.05],
        }
    }
}

/// `[model.radar]`: where the radar detects the target.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
struct RadarSpec {
    #[serde(default = "default_min_range")]
    min_range: f64,
    #[serde(default = "default_max_range")]
    max_range: f64,
}

fn default_min_range() -> f64 {
    1.0
}
fn default_max_range() -> f64 {
    f64::INFINITY
}

impl Default for RadarSpec {
    fn default() -> Self {
        RadarSpec {
            min_range: default_min_range(),
            max_range: default_max_range(),
        }
    }
}

/// `[model.ukf]`: sigma-point scaling.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
struct UkfSpec {
    #[serde(default = "default_alpha")]
    alpha: f64,
    #[serde(default = "default_beta")]
    beta: f64,
    #[serde(default)]
    kappa: f64,
}

fn default_alpha() -> f64 {
    1.0
}
fn default_beta() -> f64 {
    2.0
}

impl Default for UkfSpec {
    fn default() -> Self {
        UkfSpec {
            alpha: 1.0,
            beta: 2.0,
            kappa: 0.0,
        }
    }
}

fn finite(field: &str, v: f64) -> Result<f64, ModelError> {
    if v.is_finite() {
        Ok(v)
    } else {
        Err(ModelError::new(field, format!("must be finite, got {v}")))
    }
}

fn build(table: &toml::Table, ctx: &ModelContext) -> Result<Box<dyn CatalogModel>, ModelError> {
    Ok(Box::new(CtrvModel::from_table(table, ctx)?))
}

// ---------------------------------------------------------------------------------------
// Dynamics

/// Continuous CTRV dynamics driven by held accelerations `a` (m/s²) and `yy` (rad/s²).
fn derivative(x: &Vector5<f64>, a: f64, yy: f64) -> Vector5<f64> {
    let (s, c) = x[3].sin_cos();
    Vector5::new(x[2] * c, x[2] * s, a, x[4], yy)
}

/// One filter step of the truth: RK4 with `n` substeps of `dt / n`.
fn rk4(x: &Vector5<f64>, a: f64, yy: f64, dt: f64, n: usize) -> Vector5<f64> {
    let h = dt / n as f64;
    let mut x = *x;
    for _ in 0..n {
        let k1 = derivative(&x, a, yy);
        let k2 = derivative(&(x + k1 * (h / 2.0)), a, yy);
        let k3 = derivative(&(x + k2 * (h / 2.0)), a, yy);
        let k4 = derivative(&(x + k3 * h), a, yy);
        x += (k1 + k2 * 2.0 + k3 * 2.0 + k4) * (h / 6.0);
    }
    x
}

/// Position increments of the noise-free CTRV step over `T` and their partial derivatives
/// with respect to (v, yaw, ω): `(dx, dy, [∂dx/∂v, ∂dx/∂yaw, ∂dx/∂ω], [∂dy/∂v, …])`.
fn ctrv_increment(v: f64, yaw: f64, w: f64, T: f64) -> (f64, f64, [f64; 3], [f64; 3]) {
    let (s, c) = yaw.sin_cos();
    let e = w * T;
    if e.abs() < SMALL_TURN {
        // (sin(yaw + ε) − sin yaw)/ω = T (c (1 − ε²/6) − s ε/2) + O(T ε³), likewise for cos.
        let a = 1.0 - e * e / 6.0;
        let gx = T * (c * a - s * e / 2.0);
        let gy = T * (s * a + c * e / 2.0);
        let dx = [
            gx,
            v * T * (-s * a - c * e / 2.0),
            v * T * T * (-c * e / 3.0 - s / 2.0),
        ];
        let dy = [
            gy,
            v * T * (c * a - s * e / 2.0),
            v * T * T * (-s * e / 3.0 + c / 2.0),
        ];
        (v * gx, v * gy, dx, dy)
    } else {
        let (s1, c1) = (yaw + e).sin_cos();
        let gx = (s1 - s) / w;
        let gy = (c - c1) / w;
        let dx = [gx, v * (c1 - c) / w, v * (T * c1 - gx) / w];
        let dy = [gy, v * (s1 - s) / w, v * (T * s1 - gy) / w];
        (v * gx, v * gy, dx, dy)
    }
}

/// The radar's noise-free measurement `[range, bearing, range_rate]` of state `x`.
fn radar_of(x: &[f64]) -> [f64; 3] {
    let (px, py, v, yaw) = (x[0], x[1], x[2], x[3]);
    let r = px.hypot(py);
    let rs = r.max(MIN_RANGE_GUARD);
    let (s, c) = yaw.sin_cos();
    [r, py.atan2(px), v * (px * c + py * s) / rs]
}

// ---------------------------------------------------------------------------------------
// The filter's system model

/// The CTRV system as the UKF sees it: closed-form transition over one filter step `dt`
/// (s), lidar `[px, py]` (m) and radar `[range (m), bearing (rad), range_rate (m/s)]`.
#[derive(Debug, Clone, Copy)]
pub struct CtrvSystem {
    /// Filter step T, s.
    pub dt: f64,
}

impl CtrvSystem {
    /// The transition of `x` (5 components) with process noise `[ν_a (m/s²), ν_yawdd
    /// (rad/s²)]` held over the step.
    pub fn step(&self, x: &[f64], nu_a: f64, nu_yy: f64) -> [f64; 5] {
        let T = self.dt;
        let (px, py, v, yaw, w) = (x[0], x[1], x[2], x[3], x[4]);
        let (dx, dy, _, _) = ctrv_increment(v, yaw, w, T);
        let (s, c) = yaw.sin_cos();
        let h = 0.5 * T * T;
        [
            px + dx + h * c * nu_a,
            py + dy + h * s * nu_a,
            v + T * nu_a,
            yaw + w * T + h * nu_yy,
            w + T * nu_yy,
        ]
    }
}

impl SystemModel for CtrvSystem {
    fn n_x(&self) -> usize {
        5
    }

    fn sensor_dims(&self) -> Vec<usize> {
        vec![2, 3]
    }

    fn transition(&self, _k: usize, x: &DVector<f64>) -> DVector<f64> {
        DVector::from_row_slice(&self.step(x.as_slice(), 0.0, 0.0))
    }

    fn transition_jacobian(&self, _k: usize, x: &DVector<f64>) -> Option<DMatrix<f64>> {
        let T = self.dt;
        let (_, _, gx, gy) = ctrv_increment(x[2], x[3], x[4], T);
        let mut F = DMatrix::identity(5, 5);
        for j in 0..3 {
            F[(0, 2 + j)] = gx[j];
            F[(1, 2 + j)] = gy[j];
        }
        F[(3, 4)] = T;
        Some(F)
    }

    fn transition_with_noise(
        &self,
        _k: usize,
        x: &DVector<f64>,
        w: &DVector<f64>,
    ) -> Option<DVector<f64>> {
        if w.len() != 2 {
            return None;
        }
        Some(DVector::from_row_slice(&self.step(
            x.as_slice(),
            w[0],
            w[1],
        )))
    }

    fn measurement(&self, _k: usize, sensor: usize, x: &DVector<f64>) -> DVector<f64> {
        if sensor == LIDAR {
            DVector::from_row_slice(&[x[0], x[1]])
        } else {
            DVector::from_row_slice(&radar_of(x.as_slice()))
        }
    }

    fn measurement_jacobian(
        &self,
        _k: usize,
        sensor: usize,
        x: &DVector<f64>,
    ) -> Option<DMatrix<f64>> {
        if sensor == LIDAR {
            let mut H = DMatrix::zeros(2, 5);
            H[(0, 0)] = 1.0;
            H[(1, 1)] = 1.0;
            return Some(H);
        }
        let (px, py, v, yaw) = (x[0], x[1], x[2], x[3]);
        let r = px.hypot(py).max(MIN_RANGE_GUARD);
        let (r2, r3) = (r * r, r * r * r);
        let (s, c) = yaw.sin_cos();
        let u = px * c + py * s;
        let mut H = DMatrix::zeros(3, 5);
        H[(0, 0)] = px / r;
        H[(0, 1)] = py / r;
        H[(1, 0)] = -py / r2;
        H[(1, 1)] = px / r2;
        H[(2, 0)] = v * c / r - v * u * px / r3;
        H[(2, 1)] = v * s / r - v * u * py / r3;
        H[(2, 2)] = u / r;
        H[(2, 3)] = v * (py * c - px * s) / r;
        Some(H)
    }

    fn residual(&self, sensor: usize, z: &DVector<f64>, z_hat: &DVector<f64>) -> DVector<f64> {
        let mut d = z - z_hat;
        if sensor == RADAR && d.len() == 3 {
            d[1] = wrap_angle(d[1]);
        }
        d
    }

    fn measurement_mean(&self, sensor: usize, zs: &[DVector<f64>], wm: &[f64]) -> DVector<f64> {
        let mut z_hat = DVector::zeros(zs.first().map_or(0, |z| z.len()));
        for (z, w) in zs.iter().zip(wm) {
            z_hat += z * *w;
        }
        if sensor == RADAR && z_hat.len() == 3 {
            // Bearings averaged as wrapped offsets from the first point's: the same as the
            // weighted sum when no point crosses ±π, and correct when some do.
            let b0 = zs[0][1];
            let mut off = 0.0;
            for (z, w) in zs.iter().zip(wm) {
                off += w * wrap_angle(z[1] - b0);
            }
            z_hat[1] = wrap_angle(b0 + off);
        }
        z_hat
    }
}

/// The UKF over [`CtrvSystem`] on fixed-size matrices, with the yaw error wrapped to
/// (−π, π].
///
/// It computes exactly what [`crate::filter::Ukf`] with augmented process noise computes
/// on the same [`CtrvSystem`] (the tests check agreement to 1e-9; [`CtrvModel::reference_ukf`]
/// builds that one), without the generic filter's heap allocations, which made up about
/// half of a Monte Carlo evaluation's time.
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

/// Mean and covariance weights `(w_centre_mean, w_centre_cov, w_other)` of the scaled
/// unscented transform in `n` dimensions, and the spread factor `n + λ`.
fn weights(n: f64, (alpha, beta, kappa): (f64, f64, f64)) -> (f64, f64, f64, f64) {
    let lambda = alpha * alpha * (n + kappa) - n;
    let wm0 = lambda / (n + lambda);
    let wc0 = wm0 + 1.0 - alpha * alpha + beta;
    (wm0, wc0, 1.0 / (2.0 * (n + lambda)), n + lambda)
}

/// A prediction: mean, covariance, and the statistically linearized transition `F`.
type Predicted = (Vector5<f64>, Matrix5<f64>, Matrix5<f64>);

fn chol5(m: &Matrix5<f64>) -> Option<Cholesky<f64, U5>> {
    if m.iter().any(|v| !v.is_finite()) {
        return None;
    }
    Cholesky::new(*m)
}

fn to_dmatrix<const R: usize, const C: usize>(m: &SMatrix<f64, R, C>) -> DMatrix<f64> {
    DMatrix::from_column_slice(R, C, m.as_slice())
}

fn symmetrized<const N: usize>(m: &SMatrix<f64, N, N>) -> SMatrix<f64, N, N> {
    (m + m.transpose()) * 0.5
}

impl CtrvFilter {
    fn predict_fixed(
        &self,
        k: usize,
        x: &Vector5<f64>,
        P: &Matrix5<f64>,
    ) -> Result<Predicted, FilterError> {
        let not_pd = FilterError::NotPositiveDefinite {
            which: "P",
            step: k,
        };
        let (wm0, wc0, w, spread) = weights(7.0, self.scaling);
        // Sigma points of [x; w] with covariance blkdiag(P, diag(q)): the Cholesky factor
        // is block diagonal, so the noise points are x with ±√(spread q_i) in w_i.
        let cP = chol5(&(P * spread)).ok_or(not_pd.clone())?;
        let L = cP.l();
        let qa = (self.q[0] * spread).sqrt();
        let qy = (self.q[1] * spread).sqrt();
        if !(qa.is_finite() && qa > 0.0 && qy.is_finite() && qy > 0.0) {
            return Err(not_pd);
        }
        let xs = x.as_slice();
        let centre = Vector5::from(self.system.step(xs, 0.0, 0.0));
        // Propagated points and the state offsets they came from (zero for noise points).
        let mut prop = [Vector5::zeros(); 15];
        let mut dx = [Vector5::zeros(); 15];
        prop[0] = centre;
        for i in 0..5 {
            let c = L.column(i).into_owned();
            let p = x + c;
            let m = x - c;
            prop[1 + i] = Vector5::from(self.system.step(p.as_slice(), 0.0, 0.0));
            prop[8 + i] = Vector5::from(self.system.step(m.as_slice(), 0.0, 0.0));
            dx[1 + i] = c;
            dx[8 + i] = -c;
        }
        // The noise points start at x: the noise-free step is the centre's, and the noise
        // enters additively given yaw (the same numbers `step(x, ±qa, ±qy)` gives).
        let T = self.system.dt;
        let (s, c) = x[3].sin_cos();
        let h = 0.5 * T * T;
        let na = Vector5::new(h * c * qa, h * s * qa, T * qa, 0.0, 0.0);
        let ny = Vector5::new(0.0, 0.0, 0.0, h * qy, T * qy);
        prop[6] = centre + na;
        prop[7] = centre + ny;
        prop[13] = centre - na;
        prop[14] = centre - ny;
        let mut mean = prop[0] * wm0;
        for p in &prop[1..] {
            mean += p * w;
        }
        let mut Pn = Matrix5::zeros();
        let mut C = Matrix5::zeros();
        for (i, (p, d)) in prop.iter().zip(&dx).enumerate() {
            let wc = if i == 0 { wc0 } else { w };
            let e = p - mean;
            Pn += e * e.transpose() * wc;
            C += e * d.transpose() * wc;
        }
        let Pn = symmetrized(&Pn);
        // Statistical linearization F = C P⁻¹ for the NEES correlation model.
        let cP0 = chol5(P).ok_or(not_pd)?;
        let F = cP0.solve(&C.transpose()).transpose();
        Ok((mean, Pn, F))
    }

    #[allow(clippy::too_many_arguments)]
    fn update_fixed<const M: usize>(
        &self,
        k: usize,
        est: &mut Estimate,
        z: &SVector<f64, M>,
        R: &SMatrix<f64, M, M>,
        h: impl Fn(&Vector5<f64>) -> SVector<f64, M>,
        angle: Option<usize>,
    ) -> Result<Innovation, FilterError> {
        let not_pd = FilterError::NotPositiveDefinite {
            which: "P",
            step: k,
        };
        let x = Vector5::from_column_slice(est.x.as_slice());
        let P = Matrix5::from_column_slice(est.P.as_slice());
        let (wm0, wc0, w, spread) = weights(5.0, self.scaling);
        let cP = chol5(&(P * spread)).ok_or(not_pd.clone())?;
        let L = cP.l();
        let mut dx = [Vector5::zeros(); 11];
        for i in 0..5 {
            let c = L.column(i).into_owned();
            dx[1 + i] = c;
            dx[6 + i] = -c;
        }
        let zs: [SVector<f64, M>; 11] = std::array::from_fn(|i| h(&(x + dx[i])));
        let wm = |i: usize| if i == 0 { wm0 } else { w };
        let mut z_hat = SVector::<f64, M>::zeros();
        for (i, zi) in zs.iter().enumerate() {
            z_hat += zi * wm(i);
        }
        let resid = |a: &SVector<f64, M>, b: &SVector<f64, M>| {
            let mut d = a - b;
            if let Some(j) = angle {
                d[j] = wrap_angle(d[j]);
            }
            d
        };
        if let Some(j) = angle {
            // Circular mean, as CtrvSystem::measurement_mean.
            let b0 = zs[0][j];
            let mut off = 0.0;
            for (i, zi) in zs.iter().enumerate() {
                off += wm(i) * wrap_angle(zi[j] - b0);
            }
            z_hat[j] = wrap_angle(b0 + off);
        }
        let mut S = *R;
        let mut Pxz = SMatrix::<f64, 5, M>::zeros();
        for (i, (zi, d)) in zs.iter().zip(&dx).enumerate() {
            let wc = if i == 0 { wc0 } else { w };
            let dz = resid(zi, &z_hat);
            S += dz * dz.transpose() * wc;
            Pxz += d * dz.transpose() * wc;
        }
        let S = symmetrized(&S);
        let cS = if S.iter().all(|v| v.is_finite()) {
            Cholesky::new(S)
        } else {
            None
        }
        .ok_or(FilterError::NotPositiveDefinite {
            which: "S",
            step: k,
        })?;
        let K = cS.solve(&Pxz.transpose()).transpose();
        let nu = resid(z, &z_hat);
        let cP0 = chol5(&P).ok_or(not_pd)?;
        let H = cP0.solve(&Pxz).transpose();
        let xn = x + K * nu;
        let Pn = symmetrized(&(P - K * S * K.transpose()));
        let IKH = Matrix5::identity() - K * H;
        let A = est
            .error_map
            .as_ref()
            .map(|a| IKH * Matrix5::from_column_slice(a.as_slice()));
        let v = cS
            .l()
            .solve_lower_triangular(&nu)
            .ok_or(FilterError::NotPositiveDefinite {
                which: "S",
                step: k,
            })?;
        est.x = DVector::from_column_slice(xn.as_slice());
        est.P = to_dmatrix(&Pn);
        est.error_map = A.as_ref().map(to_dmatrix);
        Ok(Innovation {
            nu: DVector::from_column_slice(nu.as_slice()),
            S: to_dmatrix(&S),
            nis: v.norm_squared(),
        })
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
        Estimate::new(
            &DVector::from_column_slice(self.x0.as_slice()),
            &to_dmatrix(&self.P0),
        )
    }

    fn predict(&self, k: usize, est: &mut Estimate) -> Result<(), FilterError> {
        if est.x.len() != 5 || est.P.shape() != (5, 5) {
            return Err(FilterError::Unsupported {
                what: "an estimate of dimension 5",
            });
        }
        let x = Vector5::from_column_slice(est.x.as_slice());
        let P = Matrix5::from_column_slice(est.P.as_slice());
        let (x, P, F) = self.predict_fixed(k, &x, &P)?;
        est.x = DVector::from_column_slice(x.as_slice());
        est.P = to_dmatrix(&P);
        est.error_map = Some(to_dmatrix(&F));
        Ok(())
    }

    fn update(
        &self,
        k: usize,
        est: &mut Estimate,
        meas: &Measurement,
    ) -> Result<Innovation, FilterError> {
        let dim = match meas.sensor {
            LIDAR => Some(2),
            RADAR => Some(3),
            _ => None,
        };
        check_measurement(dim, meas)?;
        let map_ok = est.error_map.as_ref().is_none_or(|a| a.shape() == (5, 5));
        if est.x.len() != 5 || est.P.shape() != (5, 5) || !map_ok {
            return Err(FilterError::Unsupported {
                what: "an estimate of dimension 5",
            });
        }
        match meas.sensor {
            LIDAR => {
                let z = Vector2::from_column_slice(meas.z.as_slice());
                self.update_fixed(
                    k,
                    est,
                    &z,
                    &self.R_lidar,
                    |x| Vector2::new(x[0], x[1]),
                    None,
                )
            }
            _ => {
                let z = Vector3::from_column_slice(meas.z.as_slice());
                self.update_fixed(
                    k,
                    est,
                    &z,
                    &self.R_radar,
                    |x| Vector3::from(radar_of(x.as_slice())),
                    Some(1),
                )
            }
        }
    }

    fn state_error(&self, truth: &DVector<f64>, estimate: &DVector<f64>) -> DVector<f64> {
        let mut e = truth - estimate;
        if e.len() == 5 {
            e[3] = wrap_angle(e[3]);
        }
        e
    }
}

// ---------------------------------------------------------------------------------------
// The truth

/// The simulated target and sensors.
#[derive(Debug, Clone)]
pub struct CtrvTruth {
    /// Filter step, s.
    pub dt: f64,
    /// RK4 substeps per filter step.
    pub substeps: usize,
    /// Standard deviations of the held accelerations: `[√q_accel (m/s²), √q_yaw_accel
    /// (rad/s²)]`.
    pub accel_std: [f64; 2],
    /// Lidar standard deviation per axis, m.
    pub lidar_std: f64,
    /// Radar standard deviations `[range (m), bearing (rad), range rate (m/s)]`.
    pub radar_std: [f64; 3],
    /// Radar detection range interval `[min, max]`, m.
    pub radar_range: [f64; 2],
    /// Initial state mean, 5.
    pub x0: [f64; 5],
    /// Initial state standard deviations, 5.
    pub x0_std: [f64; 5],
}

impl CtrvTruth {
    /// Which sensor measures at step `k` (1-based) if the target is visible to it: the
    /// lidar at odd steps, the radar at even ones.
    pub fn scheduled(k: usize) -> usize {
        if k % 2 == 1 { LIDAR } else { RADAR }
    }

    /// Whether the radar detects a target at range `r` (m).
    pub fn radar_sees(&self, r: f64) -> bool {
        r >= self.radar_range[0] && r <= self.radar_range[1]
    }
}

fn normal(rng: &mut SimRng) -> f64 {
    rng.sample::<f64, _>(StandardNormal)
}

impl TruthModel for CtrvTruth {
    fn n_x(&self) -> usize {
        5
    }

    fn initial_state(&self, rng: &mut SimRng) -> DVector<f64> {
        DVector::from_fn(5, |i, _| self.x0[i] + self.x0_std[i] * normal(rng))
    }

    fn propagate(&self, _k: usize, x: &DVector<f64>, rng: &mut SimRng) -> DVector<f64> {
        let a = self.accel_std[0] * normal(rng);
        let yy = self.accel_std[1] * normal(rng);
        let x = Vector5::from_column_slice(x.as_slice());
        let y = rk4(&x, a, yy, self.dt, self.substeps);
        DVector::from_column_slice(y.as_slice())
    }

    fn measure(&self, k: usize, x: &DVector<f64>, rng: &mut SimRng, out: &mut Vec<Measurement>) {
        if Self::scheduled(k) == LIDAR {
            let z = DVector::from_fn(2, |i, _| x[i] + self.lidar_std * normal(rng));
            out.push(Measurement { sensor: LIDAR, z });
            return;
        }
        let h = radar_of(x.as_slice());
        if !self.radar_sees(h[0]) {
            return;
        }
        let mut z = DVector::from_fn(3, |i, _| h[i] + self.radar_std[i] * normal(rng));
        z[1] = wrap_angle(z[1]);
        out.push(Measurement { sensor: RADAR, z });
    }
}

// ---------------------------------------------------------------------------------------
// The catalog model

/// The built model: truth, and the UKF at any parameter values.
#[derive(Debug, Clone)]
pub struct CtrvModel {
    /// The truth.
    pub truth: CtrvTruth,
    /// The filter's system model.
    pub system: CtrvSystem,
    /// Sigma-point scaling `(α, β, κ)`.
    pub ukf_scaling: (f64, f64, f64),
    truth_values: [f64; 6],
}

impl CtrvModel {
    /// Build from a `[model]` table without its `name` key (what [`ENTRY`]'s `build` does,
    /// returning the concrete type).
    pub fn from_table(table: &toml::Table, ctx: &ModelContext) -> Result<Self, ModelError> {
        let spec: Spec = parse_table(table)?;
        Self::from_spec(&spec, ctx)
    }

    fn from_spec(spec: &Spec, ctx: &ModelContext) -> Result<Self, ModelError> {
        let dt = positive("dt", ctx.dt)?;
        if spec.substeps == 0 || spec.substeps > 10_000 {
            return Err(ModelError::new(
                "substeps",
                format!("must be in 1..=10000, got {}", spec.substeps),
            ));
        }
        let t = &spec.truth;
        let tv = [
            positive("truth.q_accel", t.q_accel)?,
            positive("truth.q_yaw_accel", t.q_yaw_accel)?,
            positive("truth.r_lidar", t.r_lidar)?,
            positive("truth.r_radar_range", t.r_radar_range)?,
            positive("truth.r_radar_bearing", t.r_radar_bearing)?,
            positive("truth.r_radar_rate", t.r_radar_rate)?,
        ];
        for i in 0..5 {
            finite(&format!("initial.mean[{i}]"), spec.initial.mean[i])?;
            positive(&format!("initial.std[{i}]"), spec.initial.std[i])?;
        }
        let rmin = spec.radar.min_range;
        if !(rmin.is_finite() && rmin >= 0.0) {
            return Err(ModelError::new(
                "radar.min_range",
                format!("must be finite and >= 0, got {rmin}"),
            ));
        }
        let rmax = spec.radar.max_range;
        if rmax.is_nan() || rmax <= rmin {
            return Err(ModelError::new(
                "radar.max_range",
                format!("must be > radar.min_range ({rmin}), got {rmax}"),
            ));
        }
        let u = &spec.ukf;
        if !(u.alpha.is_finite() && u.alpha > 0.0 && u.alpha <= 1.0) {
            return Err(ModelError::new(
                "ukf.alpha",
                format!("must be in (0, 1], got {}", u.alpha),
            ));
        }
        finite("ukf.beta", u.beta)?;
        // n + λ = α² (n + κ) must be positive for the update (n = 5) and the augmented
        // prediction (n = 7).
        if !(u.kappa.is_finite() && u.kappa > -5.0) {
            return Err(ModelError::new(
                "ukf.kappa",
                format!("must be finite and > -5 (n + κ > 0), got {}", u.kappa),
            ));
        }
        Ok(CtrvModel {
            truth: CtrvTruth {
                dt,
                substeps: spec.substeps,
                accel_std: [tv[0].sqrt(), tv[1].sqrt()],
                lidar_std: tv[2].sqrt(),
                radar_std: [tv[3].sqrt(), tv[4].sqrt(), tv[5].sqrt()],
                radar_range: [rmin, rmax],
                x0: spec.initial.mean,
                x0_std: spec.initial.std,
            },
            system: CtrvSystem { dt },
            ukf_scaling: (u.alpha, u.beta, u.kappa),
            truth_values: tv,
        })
    }

    /// The UKF with parameter values `theta` (θ order: q_accel, q_yaw_accel, r_lidar,
    /// r_radar_range, r_radar_bearing, r_radar_rate). Missing or invalid values make the
    /// filter fail with a non-positive-definite covariance rather than panic.
    pub fn ukf(&self, theta: &[f64]) -> CtrvFilter {
        let th = |i: usize| theta.get(i).copied().unwrap_or(f64::NAN);
        CtrvFilter {
            system: self.system,
            q: [th(0), th(1)],
            R_lidar: Matrix2::from_diagonal(&Vector2::new(th(2), th(2))),
            R_radar: Matrix3::from_diagonal(&Vector3::new(th(3), th(4), th(5))),
            x0: Vector5::from(self.truth.x0),
            P0: Matrix5::from_diagonal(&Vector5::from_fn(|i, _| {
                self.truth.x0_std[i] * self.truth.x0_std[i]
            })),
            scaling: self.ukf_scaling,
        }
    }

    /// The same filter as [`CtrvModel::ukf`], as the generic [`Ukf`] with augmented process
    /// noise (slower; the reference the fixed-size filter is tested against). Its state
    /// error is not wrapped.
    pub fn reference_ukf(&self, theta: &[f64]) -> Ukf<CtrvSystem> {
        let f = self.ukf(theta);
        let mut ukf = Ukf::new(
            self.system,
            DMatrix::zeros(5, 5),
            vec![to_dmatrix(&f.R_lidar), to_dmatrix(&f.R_radar)],
            DVector::from_column_slice(f.x0.as_slice()),
            to_dmatrix(&f.P0),
        );
        ukf.alpha = self.ukf_scaling.0;
        ukf.beta = self.ukf_scaling.1;
        ukf.kappa = self.ukf_scaling.2;
        ukf.augmented_noise = Some(DMatrix::from_diagonal(&DVector::from_row_slice(&f.q)));
        ukf
    }
}

impl CatalogModel for CtrvModel {
    fn state_names(&self) -> Vec<String> {
        ["px", "py", "v", "yaw", "yaw_rate"]
            .iter()
            .map(|s| s.to_string())
            .collect()
    }

    fn measurement_names(&self) -> Vec<String> {
        [
            "lidar_px",
            "lidar_py",
            "radar_range",
            "radar_bearing",
            "radar_rate",
        ]
        .iter()
        .map(|s| s.to_string())
        .collect()
    }

    fn truth(&self) -> &dyn TruthModel {
        &self.truth
    }

    fn filter(&self, theta: &[f64]) -> Box<dyn Filter> {
        Box::new(self.ukf(theta))
    }

    fn truth_values(&self) -> Vec<f64> {
        self.truth_values.to_vec()
    }
}
