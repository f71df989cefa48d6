//! The catalog's EKF for `orbit2d`, on fixed-size matrices: the two-body flow and its
//! transition matrix from [`OrbitSystem::flow`], process noise in the rotating
//! radial/along-track frame, and the shared Joseph update ([`joseph_update`]) per station.

#![allow(non_snake_case)]

use nalgebra::{DVector, Matrix3, Matrix4, U3, U4, Vector3, Vector4};

use super::system::{OrbitSystem, frame};
use crate::filter::{
    CovarianceUpdate, Estimate, Filter, FilterError, Innovation, PredictResult, UpdateResult,
    check_measurement, joseph_update, update_by_into,
};
use crate::linalg::{symmetrize, wrap_angle};
use crate::measurement::Measurement;

/// A prediction: mean (km, km/s), covariance (4 × 4) and the transition F (4 × 4).
pub type Predicted = (Vector4<f64>, Matrix4<f64>, Matrix4<f64>);

/// A station's update: the posterior mean, the Joseph update (posterior covariance, gain,
/// S, `I − K H`), the innovation (3) and its NIS.
pub type Updated = (Vector4<f64>, CovarianceUpdate<U4, U3>, Vector3<f64>, f64);

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

    /// The prediction from step k − 1 to k on fixed-size state: the predicted mean (km,
    /// km/s), its covariance (4 × 4) and the transition F (4 × 4), or a covariance that
    /// stopped being finite. [`Filter::predict`] is this on the estimate.
    pub fn predict_fixed(
        &self,
        k: usize,
        x: &Vector4<f64>,
        P: &Matrix4<f64>,
    ) -> Result<Predicted, FilterError> {
        self.predict_inline(k, x, P)
    }

    /// [`Self::predict_fixed`]'s body, inlined into the [`Filter`] wrapper so that its
    /// result is built in place there rather than returned through memory (5% of an
    /// evaluation); the public function stays one compiled call, which its callers' own
    /// loops run faster than an inlined copy (the speed-of-light bench's, by 9%).
    #[inline(always)]
    fn predict_inline(
        &self,
        k: usize,
        x: &Vector4<f64>,
        P: &Matrix4<f64>,
    ) -> Result<Predicted, FilterError> {
        let (x1, F) = self.system.flow(x);
        let mut P1 = F * P * F.transpose() + self.process_noise(x, &x1);
        symmetrize(&mut P1);
        if !P1.iter().all(|v| v.is_finite()) {
            return Err(FilterError::NotPositiveDefinite {
                which: "P",
                step: k,
            });
        }
        Ok((x1, P1, F))
    }

    /// Station `station`'s update at step `k` with its measurement `z` (range km, range
    /// rate km/s, bearing rad) on fixed-size state: the posterior mean, the Joseph update
    /// (posterior covariance, gain, S, `I − K H`), the innovation (bearing wrapped to
    /// (−π, π]) and its NIS. [`Filter::update`] is this on the estimate.
    pub fn update_fixed(
        &self,
        k: usize,
        station: usize,
        x: &Vector4<f64>,
        P: &Matrix4<f64>,
        z: &Vector3<f64>,
    ) -> Result<Updated, FilterError> {
        self.update_inline(k, station, x, P, z)
    }

    /// [`Self::update_fixed`]'s body, inlined into the [`Filter`] wrapper (see
    /// [`Self::predict_inline`]).
    #[inline(always)]
    fn update_inline(
        &self,
        k: usize,
        station: usize,
        x: &Vector4<f64>,
        P: &Matrix4<f64>,
        z: &Vector3<f64>,
    ) -> Result<Updated, FilterError> {
        let (z_hat, H) = self.system.stations.measure(k, station, x);
        let mut nu = z - z_hat;
        nu[2] = wrap_angle(nu[2]);
        let cu = joseph_update(P, &H, &self.R, k)?;
        let nis = nu.dot(&cu.chol.solve(&nu));
        Ok((x + cu.K * nu, cu, nu, nis))
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
        let (x1, P1, F) = self.predict_inline(k, &x, &P)?;
        est.set_fixed(&x1, &P1);
        est.set_error_map(&F);
        Ok(())
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
        let count = self.system.stations.count;
        check_measurement((meas.sensor < count).then_some(3), meas)?;
        let (x, P) = est.fixed::<4>()?;
        let z = Vector3::new(meas.z[0], meas.z[1], meas.z[2]);
        let (x1, cu, nu, nis) = self.update_inline(k, meas.sensor, &x, &P, &z)?;
        est.set_fixed(&x1, &cu.P);
        est.compose_error_map_fixed(&cu.IKH);
        out.set_fixed(&nu, &cu.S, nis);
        Ok(())
    }

    fn state_error_into(
        &self,
        truth: &DVector<f64>,
        estimate: &DVector<f64>,
        out: &mut DVector<f64>,
    ) {
        if out.len() == truth.len() && truth.len() == estimate.len() {
            out.zip_zip_apply(truth, estimate, |e, t, x| *e = t - x);
        } else {
            *out = self.state_error(truth, estimate);
        }
    }
}
