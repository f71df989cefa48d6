//! The simulated satellite and stations: two-body gravity plus random radial and
//! along-track accelerations held over each RK4 step, measured by every station that sees
//! it.

use nalgebra::{DVector, Vector3, Vector4};
use rand::RngExt;
use rand_distr::StandardNormal;

use super::system::{Stations, frame, rk4, to4};
use crate::measurement::Measurement;
use crate::model::TruthModel;
use crate::rng::SimRng;

/// The simulated satellite and stations.
#[derive(Debug, Clone)]
pub struct OrbitTruth {
    /// Mean of the initial state [x, y, vx, vy] (km, km/s): a circular orbit at the
    /// configured radius, on the +x axis moving towards +y.
    pub x0: Vector4<f64>,
    /// Initial position and velocity standard deviations per axis (km, km/s).
    pub initial_std: (f64, f64),
    /// RK4 steps per filter step.
    pub substeps: usize,
    /// RK4 step, s (dt / substeps).
    pub h: f64,
    /// Standard deviation of the piecewise-constant radial and along-track accelerations,
    /// km/s² (√(q/h)).
    pub accel_std: (f64, f64),
    /// Sensor noise standard deviations [range (km), range rate (km/s), angle (rad)].
    pub sensor_std: Vector3<f64>,
    /// The stations.
    pub stations: Stations,
}

impl TruthModel for OrbitTruth {
    fn n_x(&self) -> usize {
        4
    }

    fn initial_state(&self, rng: &mut SimRng) -> DVector<f64> {
        let (sp, sv) = self.initial_std;
        let s = [sp, sp, sv, sv];
        DVector::from_fn(4, |i, _| {
            self.x0[i] + s[i] * rng.sample::<f64, _>(StandardNormal)
        })
    }

    fn propagate(&self, _k: usize, x: &DVector<f64>, rng: &mut SimRng) -> DVector<f64> {
        let mut s = to4(x);
        for _ in 0..self.substeps {
            let (ur, ut) = frame(&s.fixed_rows::<2>(0).into(), &s.fixed_rows::<2>(2).into());
            let a_r: f64 = rng.sample(StandardNormal);
            let a_t: f64 = rng.sample(StandardNormal);
            let a = ur * (self.accel_std.0 * a_r) + ut * (self.accel_std.1 * a_t);
            s = rk4(&s, &a, self.h);
        }
        DVector::from_column_slice(s.as_slice())
    }

    fn measure(&self, k: usize, x: &DVector<f64>, rng: &mut SimRng, out: &mut Vec<Measurement>) {
        let s = to4(x);
        let earth = self.stations.earth(k);
        for i in 0..self.stations.count {
            let site = self.stations.site_at(&earth, i);
            if !self.stations.sees(&site, &s) {
                continue;
            }
            let (z, _) = Stations::measure_from(&site, &s);
            let z = DVector::from_fn(3, |j, _| {
                z[j] + self.sensor_std[j] * rng.sample::<f64, _>(StandardNormal)
            });
            out.push(Measurement { sensor: i, z });
        }
    }
}
