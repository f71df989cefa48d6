//! The catalog's EKF for `orbit2d`, on fixed-size matrices: the two-body flow and its
//! transition matrix from [`OrbitSystem::flow`], process noise in the rotating
//! radial/along-track frame, and the shared Joseph update ([`joseph_update`]) per station.

#![allow(non_snake_case)]

use nalgebra::{DVector, Matrix3, Matrix4, Vector3, Vector4};

use super::system::{OrbitSystem, frame};
use crate::filter::{
    Estimate, Filter, FilterError, Innovation, PredictResult, UpdateResult, check_measurement,
    joseph_update,
};
use crate::linalg::{symmetrize, to_dynamic, wrap_angle};
use crate::measurement::Measurement;

/// The catalog's EKF for `orbit2d`, with fixed-size matrices inside and process noise
/// in the rotating radial/along-track frame (which a constant-Q [`crate::filter::Ekf`]
/// cannot express).
#[derive(Debug, Clone)]
pub struct OrbitEkf {
    /// Dynamics and sensors.
    pub system: OrbitSystem,
    /// PSDs of the radial and along-track acceleration noise, km²/s³.
    pub q: (f64, f64),
    /// Measurement noise covariance of every station (3 × 3, diagonal: km², (km/s)², rad²).
    pub R: Matrix3<f64>,
    /// Initial estimate, [km, km, km/s, km/s].
    pub x0: Vector4<f64>,
    /// Initial covariance, 4 × 4.
    pub P0: Matrix4<f64>,
}

impl OrbitEkf {
    /// Process noise over one step for a move from `x` to `x1`, with the radial/along-track
    /// frame taken at the middle of the step.
    pub fn process_noise(&self, x: &Vector4<f64>, x1: &Vector4<f64>) -> Matrix4<f64> {
        let mid = (x + x1) * 0.5;
        let (ur, ut) = frame(
            &mid.fixed_rows::<2>(0).into(),
            &mid.fixed_rows::<2>(2).into(),
        );
        let qa = ur * ur.transpose() * self.q.0 + ut * ut.transpose() * self.q.1;
        let dt = self.system.dt;
        let mut Q = Matrix4::zeros();
        Q.fixed_view_mut::<2, 2>(0, 0)
            .copy_from(&(qa * (dt * dt * dt / 3.0)));
        Q.fixed_view_mut::<2, 2>(0, 2)
            .copy_from(&(qa * (dt * dt / 2.0)));
        Q.fixed_view_mut::<2, 2>(2, 0)
            .copy_from(&(qa * (dt * dt / 2.0)));
        Q.fixed_view_mut::<2, 2>(2, 2).copy_from(&(qa * dt));
        Q
    }
}

impl Filter for OrbitEkf {
    fn n_x(&self) -> usize {
        4
    }

    fn sensor_dims(&self) -> Vec<usize> {
        vec![3; self.system.stations.count]
    }

    fn initial(&self) -> Estimate {
        Estimate::from_fixed(&self.x0, &self.P0)
    }

    fn predict(&self, k: usize, est: &mut Estimate) -> PredictResult {
        let (x, P) = est.fixed::<4>()?;
        let (x1, F) = self.system.flow(&x);
        let mut P1 = F * P * F.transpose() + self.process_noise(&x, &x1);
        symmetrize(&mut P1);
        if !P1.iter().all(|v| v.is_finite()) {
            return Err(FilterError::NotPositiveDefinite {
                which: "P",
                step: k,
            });
        }
        est.set_fixed(&x1, &P1);
        est.set_error_map(&F);
        Ok(())
    }

    fn update(&self, k: usize, est: &mut Estimate, meas: &Measurement) -> UpdateResult {
        let count = self.system.stations.count;
        check_measurement((meas.sensor < count).then_some(3), meas)?;
        let (x, P) = est.fixed::<4>()?;
        let (z_hat, H) = self.system.stations.measure(k, meas.sensor, &x);
        let mut nu = Vector3::new(meas.z[0], meas.z[1], meas.z[2]) - z_hat;
        nu[2] = wrap_angle(nu[2]);
        let cu = joseph_update(&P, &H, &self.R, k)?;
        let nis = nu.dot(&cu.chol.solve(&nu));
        est.set_fixed(&(x + cu.K * nu), &cu.P);
        est.compose_error_map_fixed(&cu.IKH);
        Ok(Innovation {
            nu: DVector::from_column_slice(nu.as_slice()),
            S: to_dynamic(&cu.S),
            nis,
        })
    }
}
