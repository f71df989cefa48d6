//! The linear Kalman filter with a Joseph-form update.

#![allow(non_snake_case)]

use nalgebra::{Cholesky, DMatrix, DVector, Dyn};

use super::conditioning::check_conditioned;
use super::joseph::{CovarianceUpdate, SparseUpdate, joseph_update, joseph_update_sparse};
use super::{Estimate, Filter, FilterError, Innovation, PredictResult, UpdateResult};
use crate::linalg::products::Sparse;
use crate::linalg::{cholesky, cholesky_reusing, mahalanobis_sq, symmetrize};
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

    /// [`KalmanFilter::update_covariance`] with `H` held by its nonzeros (`h`), into the
    /// storage of `out` (and P⁻'s factor into `prior`'s): the same checks and failures
    /// around [`joseph_update_sparse`], whose K and `I − K H` operands it leaves beside the
    /// update. For the exact scoring, which runs it at every step of every filter a search
    /// scores.
    pub(crate) fn update_covariance_sparse(
        &self,
        Pp: &DMatrix<f64>,
        h: &Sparse,
        step: usize,
        out: &mut SparseUpdate,
        prior: &mut Option<Cholesky<f64, Dyn>>,
    ) -> Result<(), FilterError> {
        // `checked`'s conditioning checks of P⁻ (before) and S (after).
        *prior = cholesky_reusing(Pp, prior.take());
        match prior {
            Some(chol) => check_conditioned("P⁻", Pp, chol, step)?,
            None => {
                return Err(FilterError::IllConditioned {
                    which: "P⁻",
                    step,
                    condition: f64::INFINITY,
                });
            }
        }
        joseph_update_sparse(Pp, h, &self.R, step, out)?;
        check_conditioned("S", &out.cu.S, &out.cu.chol, step)
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
        super::recursion_memo::predict(self.memo_key(), k, &mut est.P, |P| {
            self.predict_covariance(P)
        });
        // The map's storage is reused from step to step where it has F's shape.
        match &mut est.error_map {
            Some(a) if a.shape() == self.F.shape() => a.copy_from(&self.F),
            a => *a = Some(self.F.clone()),
        }
        Ok(())
    }

    fn update(&self, k: usize, est: &mut Estimate, meas: &Measurement) -> UpdateResult {
        self.update_mean(k, est, meas, |nu, S, nis| Innovation {
            nu,
            S: S.clone(),
            nis,
        })
    }

    fn update_into(
        &self,
        k: usize,
        est: &mut Estimate,
        meas: &Measurement,
        out: &mut Innovation,
    ) -> Result<(), FilterError> {
        self.update_mean(k, est, meas, |nu, S, nis| {
            out.nu = nu;
            // S into the innovation's own storage where it has S's shape.
            if out.S.shape() == S.shape() {
                out.S.copy_from(S);
            } else {
                out.S = S.clone();
            }
            out.nis = nis;
        })
    }

    fn state_error_into(
        &self,
        truth: &DVector<f64>,
        estimate: &DVector<f64>,
        out: &mut DVector<f64>,
    ) {
        // `truth − estimate` (the default's), into `out`'s storage.
        assert_eq!(
            truth.len(),
            estimate.len(),
            "Matrix addition/subtraction dimensions mismatch."
        );
        if out.len() != truth.len() {
            *out = DVector::zeros(truth.len());
        }
        out.zip_zip_apply(truth, estimate, |o, t, e| *o = t - e);
    }
}

impl KalmanFilter {
    /// What the recursion memo knows this filter by: F, Q, H, R.
    fn memo_key(&self) -> super::recursion_memo::Model<'_> {
        [&self.F, &self.Q, &self.H, &self.R]
    }

    /// The update of the estimate's mean, covariance and error map at step `k` (after
    /// checking the measurement against the filter's one sensor) with the remembered
    /// covariance update (`update_covariance` of the prior), the innovation,
    /// its covariance S and NIS handed to `out`: one body for `update` and `update_into`.
    fn update_mean<R>(
        &self,
        k: usize,
        est: &mut Estimate,
        meas: &Measurement,
        out: impl FnOnce(DVector<f64>, &DMatrix<f64>, f64) -> R,
    ) -> Result<R, FilterError> {
        let m = self.H.nrows();
        super::check_measurement((meas.sensor == 0).then_some(m), meas)?;
        let covariance = |P: &DMatrix<f64>| self.update_covariance(P, k);
        super::recursion_memo::update(self.memo_key(), k, est, covariance, |u, est| {
            let cu = &u.cu;
            let nu = &meas.z - &self.H * &est.x;
            est.x += &cu.K * &nu;
            if est.P.shape() == cu.P.shape() {
                est.P.copy_from(&cu.P);
            } else {
                est.P = cu.P.clone();
            }
            // After this filter's prediction the map is F, whose composition with I − K H
            // the memo holds: the same product, computed once for every run.
            match &mut est.error_map {
                Some(a) if crate::linalg::same_bits(a, &self.F) => a.copy_from(&u.map),
                _ => est.compose_error_map(&cu.IKH),
            }
            let nis = mahalanobis_sq(&cu.chol, &nu);
            out(nu, &cu.S, nis)
        })
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

    /// The bits of an estimate: mean, covariance and error map.
    fn bits(est: &Estimate) -> Vec<u64> {
        est.x
            .iter()
            .chain(est.P.iter())
            .chain(est.error_map.iter().flatten())
            .map(|v| v.to_bits())
            .collect()
    }

    #[test]
    fn update_into_and_a_remembered_update_give_the_bits_of_the_textbook_step() {
        // Several runs of one filter through `update` and `update_into`, the later ones
        // served by the memo: each step's estimate, innovation, S and NIS are the bits of
        // the step computed from its definitions (x⁻ = F x, P⁻ = F P F' + Q, the Joseph
        // update, the map (I − K H) F), whichever path gave them.
        let kf = cv1d();
        for run in 0..3 {
            let (mut a, mut b) = (kf.initial(), kf.initial());
            let mut reference = kf.initial();
            let mut out = Innovation::empty();
            for k in 1..=6 {
                let z = Measurement {
                    sensor: 0,
                    z: DVector::from_column_slice(&[0.7 * k as f64 - 0.3 * run as f64]),
                };
                kf.predict(k, &mut a).unwrap();
                kf.predict(k, &mut b).unwrap();
                let inn = kf.update(k, &mut a, &z).unwrap();
                kf.update_into(k, &mut b, &z, &mut out).unwrap();

                reference.x = &kf.F * &reference.x;
                reference.P = kf.predict_covariance(&reference.P);
                let cu = kf.update_covariance(&reference.P, k).unwrap();
                let nu = &z.z - &kf.H * &reference.x;
                reference.x += &cu.K * &nu;
                reference.P = cu.P.clone();
                reference.error_map = Some(&cu.IKH * &kf.F);
                let nis = mahalanobis_sq(&cu.chol, &nu);

                assert_eq!(bits(&a), bits(&reference), "run {run} step {k}");
                assert_eq!(bits(&b), bits(&reference), "run {run} step {k}");
                for i in [&inn, &out] {
                    assert_eq!(i.nu, nu);
                    assert_eq!(i.S, cu.S);
                    assert_eq!(i.nis.to_bits(), nis.to_bits());
                }
            }
        }
    }

    #[test]
    fn a_second_update_in_a_step_composes_the_map_it_finds() {
        // After one update the map is (I − K H) F, not F: a second update of the same step
        // composes its own I − K H with it instead of taking the remembered (I − K H) F.
        let kf = cv1d();
        let mut est = kf.initial();
        kf.predict(1, &mut est).unwrap();
        let z = Measurement {
            sensor: 0,
            z: DVector::from_column_slice(&[1.0]),
        };
        kf.update(1, &mut est, &z).unwrap();
        let first = est.error_map.clone().unwrap();
        let prior = est.P.clone();
        kf.update(1, &mut est, &z).unwrap();
        let cu = kf.update_covariance(&prior, 1).unwrap();
        assert_eq!(est.error_map.unwrap(), &cu.IKH * &first);
    }

    #[test]
    fn state_error_into_is_the_difference_in_the_buffer_given() {
        let kf = cv1d();
        let (t, e) = (
            DVector::from_column_slice(&[1.5, -0.0]),
            DVector::from_column_slice(&[0.25, 0.0]),
        );
        let mut out = DVector::zeros(7);
        kf.state_error_into(&t, &e, &mut out);
        let want = kf.state_error(&t, &e);
        assert_eq!(out.len(), 2);
        assert!(
            out.iter()
                .zip(&want)
                .all(|(a, b)| a.to_bits() == b.to_bits())
        );
    }
}
