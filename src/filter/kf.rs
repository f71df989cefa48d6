//! The linear Kalman filter with a Joseph-form update.

#![allow(non_snake_case)]

use nalgebra::DMatrix;

use super::conditioning::check_conditioned;
use super::joseph::{CovarianceUpdate, joseph_update, joseph_update_sparse};
use super::{Estimate, Filter, FilterError, Innovation, PredictResult, UpdateResult};
use crate::linalg::products::Sparse;
use crate::linalg::{cholesky, mahalanobis_sq, symmetrize};
use crate::measurement::Measurement;
use crate::statespace::LinearGaussian;

/// Linear Kalman filter for `x_k = F x_{k−1} + w`, `z_k = H x_k + v`: the linear-Gaussian
/// model it believes, with its own Q and R (which may differ from the truth's: that is
/// what is being tested), its initial estimate x0 and covariance P0 (positive definite).
pub type KalmanFilter = LinearGaussian;

impl KalmanFilter {
    /// Covariance prediction `P⁻ = F P F' + Q`, symmetrized.
    pub fn predict_covariance(&self, P: &DMatrix<f64>) -> DMatrix<f64> {
        let mut Pp = &self.F * P * self.F.transpose() + &self.Q;
        symmetrize(&mut Pp);
        Pp
    }

    /// The covariance half of an update from the prior `P⁻`: returns the gain K (n × m),
    /// `S = H P⁻ H' + R`, its Cholesky factor, and the Joseph-form posterior
    /// `P = (I − K H) P⁻ (I − K H)' + K R K'`, symmetrized. K solves `S K' = H P⁻` by
    /// Cholesky; no inverse is formed.
    ///
    /// Fails, besides [`joseph_update`]'s errors, when `P⁻` or `S` is too ill-conditioned for
    /// the update to keep its digits ([`super::conditioning`]): the posterior is `P⁻` minus a
    /// nearly equal matrix when `P⁻` is nearly singular (a process noise far above what the
    /// measurements pin down), and the gain solves with `S`.
    pub fn update_covariance(
        &self,
        Pp: &DMatrix<f64>,
        step: usize,
    ) -> Result<CovarianceUpdate, FilterError> {
        self.checked(Pp, step, || {
            joseph_update(Pp, &self.H, &self.R, step).map(|cu| (cu, ()))
        })
        .map(|(cu, ())| cu)
    }

    /// [`KalmanFilter::update_covariance`] with `H` held by its nonzeros (`h`): the same
    /// checks and failures around [`joseph_update_sparse`], whose K and `I − K H` operands
    /// come back with it. For the exact scoring, which runs it at every step of every
    /// filter a search scores.
    pub(crate) fn update_covariance_sparse(
        &self,
        Pp: &DMatrix<f64>,
        h: &Sparse,
        step: usize,
    ) -> Result<(CovarianceUpdate, (Sparse, Sparse)), FilterError> {
        self.checked(Pp, step, || {
            joseph_update_sparse(Pp, h, &self.R, step).map(|(cu, k, ikh)| (cu, (k, ikh)))
        })
    }

    /// `update`'s result between the conditioning checks of `P⁻` (before) and `S` (after).
    fn checked<T>(
        &self,
        Pp: &DMatrix<f64>,
        step: usize,
        update: impl FnOnce() -> Result<(CovarianceUpdate, T), FilterError>,
    ) -> Result<(CovarianceUpdate, T), FilterError> {
        // P⁻ = F P F' + Q is positive semidefinite in exact arithmetic, so a P⁻ with no
        // Cholesky factor (or with entries that overflowed) is numerically singular: the far
        // end of ill-conditioning, not a different failure.
        match cholesky(Pp) {
            Some(chol) => check_conditioned("P⁻", Pp, &chol, step)?,
            None => {
                return Err(FilterError::IllConditioned {
                    which: "P⁻",
                    step,
                    condition: f64::INFINITY,
                });
            }
        }
        let (cu, extra) = update()?;
        check_conditioned("S", &cu.S, &cu.chol, step)?;
        Ok((cu, extra))
    }
}

impl Filter for KalmanFilter {
    fn n_x(&self) -> usize {
        self.F.nrows()
    }

    fn sensor_dims(&self) -> Vec<usize> {
        vec![self.H.nrows()]
    }

    fn initial(&self) -> Estimate {
        Estimate::new(&self.x0, &self.P0)
    }

    fn predict(&self, k: usize, est: &mut Estimate) -> PredictResult {
        est.x = &self.F * &est.x;
        est.P = super::recursion_memo::predict(self, k, &est.P);
        // The map's storage is reused from step to step where it has F's shape.
        match &mut est.error_map {
            Some(a) if a.shape() == self.F.shape() => a.copy_from(&self.F),
            a => *a = Some(self.F.clone()),
        }
        Ok(())
    }

    fn update(&self, k: usize, est: &mut Estimate, meas: &Measurement) -> UpdateResult {
        let m = self.H.nrows();
        super::check_measurement((meas.sensor == 0).then_some(m), meas)?;
        let cu = super::recursion_memo::update(self, k, &est.P)?;
        let nu = &meas.z - &self.H * &est.x;
        est.x += &cu.K * &nu;
        est.P = cu.P;
        est.compose_error_map(&cu.IKH);
        let nis = mahalanobis_sq(&cu.chol, &nu);
        Ok(Innovation { nu, S: cu.S, nis })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_relative_eq;
    use nalgebra::DVector;

    fn cv1d() -> KalmanFilter {
        KalmanFilter {
            F: DMatrix::from_row_slice(2, 2, &[1.0, 1.0, 0.0, 1.0]),
            H: DMatrix::from_row_slice(1, 2, &[1.0, 0.0]),
            Q: crate::params::dwna_block(1.0) * 0.3,
            R: DMatrix::from_element(1, 1, 2.0),
            x0: DVector::from_column_slice(&[0.0, 1.0]),
            P0: DMatrix::from_diagonal(&DVector::from_column_slice(&[10.0, 4.0])),
        }
    }

    #[test]
    fn joseph_update_matches_textbook_form() {
        // For the optimal gain, (I − KH)P⁻ equals the Joseph form; both must agree.
        let kf = cv1d();
        let Pp = kf.predict_covariance(&kf.P0);
        let cu = kf.update_covariance(&Pp, 1).unwrap();
        let simple = (DMatrix::identity(2, 2) - &cu.K * &kf.H) * &Pp;
        assert_relative_eq!(cu.P, simple, max_relative = 1e-12);
        // K = P⁻ H' S⁻¹ computed with an explicit inverse for the check only.
        let k_ref = &Pp * kf.H.transpose() * cu.S.clone().try_inverse().unwrap();
        assert_relative_eq!(cu.K, k_ref, max_relative = 1e-12);
    }

    #[test]
    fn update_keeps_covariance_symmetric_and_reports_nis() {
        let kf = cv1d();
        let mut est = kf.initial();
        kf.predict(1, &mut est).unwrap();
        let z = Measurement {
            sensor: 0,
            z: DVector::from_column_slice(&[3.0]),
        };
        let prior_x = est.x.clone();
        let inn = kf.update(1, &mut est, &z).unwrap();
        assert!(crate::linalg::asymmetry(&est.P).is_none());
        assert_relative_eq!(inn.nu[0], 3.0 - prior_x[0]);
        assert_relative_eq!(
            inn.nis,
            inn.nu[0] * inn.nu[0] / inn.S[(0, 0)],
            max_relative = 1e-14
        );
    }

    #[test]
    fn indefinite_innovation_covariance_is_an_error_not_nan() {
        let mut kf = cv1d();
        kf.R[(0, 0)] = -1e6;
        let mut est = kf.initial();
        kf.predict(1, &mut est).unwrap();
        let z = Measurement {
            sensor: 0,
            z: DVector::from_column_slice(&[0.0]),
        };
        assert_eq!(
            kf.update(1, &mut est, &z).unwrap_err(),
            FilterError::NotPositiveDefinite {
                which: "S",
                step: 1
            }
        );
    }

    #[test]
    fn wrong_measurement_dimension_is_rejected() {
        let kf = cv1d();
        let mut est = kf.initial();
        let z = Measurement {
            sensor: 0,
            z: DVector::from_column_slice(&[0.0, 1.0]),
        };
        assert!(matches!(
            kf.update(1, &mut est, &z),
            Err(FilterError::BadMeasurement { .. })
        ));
    }
}
