//! The CTRV system as the filter sees it: the closed-form transition over one filter step
//! with the noise entering as in the usual discretization, and the two sensors'
//! measurement functions with analytic Jacobians.

#![allow(non_snake_case)]

use nalgebra::{DMatrix, DVector};

use crate::filter::unscented;
use crate::filter::{Jacobian, SystemModel};
use crate::linalg::wrap_angle;

/// Index of the lidar in the filter's sensor list.
pub const LIDAR: usize = 0;
/// Index of the radar in the filter's sensor list.
pub const RADAR: usize = 1;

/// Below this `|ω T|` (rad) the transition uses its Taylor expansion in `ωT`.
const SMALL_TURN: f64 = 1e-3;

/// Ranges below this (m) are clamped in the radar's bearing and range-rate formulas, so a
/// sigma point at the sensor gives finite numbers.
const MIN_RANGE_GUARD: f64 = 1e-6;

/// Index of the bearing (rad) in the radar's measurement.
pub(super) const BEARING: usize = 1;

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
pub(super) fn radar_of(x: &[f64]) -> [f64; 3] {
    let (px, py, v, yaw) = (x[0], x[1], x[2], x[3]);
    let r = px.hypot(py);
    let rs = r.max(MIN_RANGE_GUARD);
    let (s, c) = yaw.sin_cos();
    [r, py.atan2(px), v * (px * c + py * s) / rs]
}

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

    fn transition_jacobian(&self, _k: usize, x: &DVector<f64>) -> Jacobian {
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

    fn measurement_jacobian(&self, _k: usize, sensor: usize, x: &DVector<f64>) -> Jacobian {
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
            d[BEARING] = wrap_angle(d[BEARING]);
        }
        d
    }

    fn measurement_mean(&self, sensor: usize, zs: &[DVector<f64>], wm: &[f64]) -> DVector<f64> {
        let mut z_hat = unscented::weighted_sum(zs, wm.iter().copied());
        if sensor == RADAR && z_hat.len() == 3 {
            z_hat[BEARING] = unscented::circular_mean(zs, wm.iter().copied(), BEARING);
        }
        z_hat
    }
}
