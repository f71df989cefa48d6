//! The simulated CTRV target and its sensors: continuous dynamics driven by accelerations
//! held over each filter step, integrated by RK4; lidar at odd steps, radar at even steps
//! when the target is in range.

use nalgebra::{DVector, Vector5};
use rand::RngExt;
use rand_distr::StandardNormal;

use super::system::radar_of;
use super::{LIDAR, RADAR};
use crate::linalg::wrap_angle;
use crate::measurement::Measurement;
use crate::model::TruthModel;
use crate::rng::SimRng;

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
