//! The loosely coupled INS/GNSS error-state EKF of `ins_gnss`.
//!
//! Prediction mechanizes each 100 Hz IMU sample of the step ([`super::nav::mechanize`])
//! and propagates the covariance once per filter step with the product of the samples'
//! exact transitions, `P ← Φ P Φ' + Q_k`, `Φ = Φ_n ⋯ Φ_1`. Once per step rather than per
//! sample because the 15 × 15 products dominate the cost and Φ's block structure lets the
//! ten sample transitions be multiplied with 3 × 3 blocks; Q_k is integrated to third
//! order in the step ([`super::nav::process_noise`]), so nothing is lost at 0.1 s.
//!
//! A GNSS fix updates the error state in Joseph form ([`joseph_update`], `H = [I₃ 0]`, no
//! lever arm), the error is injected into the nominal state and reset to zero. The
//! covariance is reused as is: the exact reset Jacobian `I − ½[ψ]×` on the attitude block
//! differs from I by the size of the correction (a few mrad), well below what the Monte
//! Carlo test resolves.

#![allow(non_snake_case)]

use nalgebra::{DVector, Matrix3, SMatrix, U3, U15, Vector3};

use super::nav::{
    ImuSample, Mat15, N_ERR, N_NOM, NoiseDensities, Nominal, Transition, Vec15, mechanize,
    process_noise,
};
use crate::filter::{
    CovarianceUpdate, Estimate, Filter, FilterError, Innovation, PredictResult, UpdateResult,
    check_measurement, joseph_update, update_by_into,
};
use crate::linalg::{store, symmetrize, to_dynamic, to_fixed};
use crate::measurement::Measurement;

/// A GNSS update: the nominal state with the error injected, the Joseph update (posterior
/// covariance, gain, S, `I − K H`), the innovation (m) and its NIS.
pub type GnssUpdate = (Nominal, CovarianceUpdate<U15, U3>, Vector3<f64>, f64);

/// The ESKF: noise densities, GNSS noise, initial state and covariance.
#[derive(Debug, Clone)]
pub struct Eskf {
    /// IMU samples per filter step.
    pub n_imu: usize,
    /// Filter step, s.
    pub dt: f64,
    /// Process noise densities.
    pub noise: NoiseDensities,
    /// GNSS position noise covariance, m², NED.
    pub R: Matrix3<f64>,
    /// Initial nominal state.
    pub x0: Nominal,
    /// Initial error covariance, 15 × 15.
    pub P0: Mat15,
}

impl Eskf {
    /// One step of prediction on fixed-size state: the nominal state and covariance are
    /// advanced in place; returns Φ.
    pub fn propagate(&self, nom: &mut Nominal, P: &mut Mat15, u: &[f64]) -> Mat15 {
        let dt_imu = self.dt / self.n_imu as f64;
        let mut phi = Transition::identity();
        let mut qv = Matrix3::zeros();
        let mut r_sum = Matrix3::zeros();
        let mut y_sum = Vector3::zeros();
        let D = Matrix3::from_diagonal(&self.noise.accel);
        for j in 0..self.n_imu {
            let s = mechanize(nom, &ImuSample::from_input(u, j), dt_imu);
            phi = phi.then(&s.phi);
            qv += s.r_mid * D * s.r_mid.transpose();
            r_sum += s.r_mid;
            y_sum += s.f_nav;
        }
        let n = self.n_imu as f64;
        let Q = process_noise(&(qv / n), &(r_sum / n), &(y_sum / n), &self.noise, self.dt);
        let F = phi.matrix();
        *P = sandwich(&F, P) + Q;
        symmetrize(P);
        F
    }

    /// A GNSS fix `z` (m, NED) at step `k` on fixed-size state: the nominal state with the
    /// error injected, the Joseph update (posterior covariance, gain, S, `I − K H`), the
    /// innovation (m) and its NIS. [`Filter::update`] is this on the estimate.
    pub fn update_fixed(
        &self,
        k: usize,
        nom: &Nominal,
        P: &Mat15,
        z: &Vector3<f64>,
    ) -> Result<GnssUpdate, FilterError> {
        // H = [I₃ 0]: the products with its zeros and ones are exact, so this gives the
        // numbers the block-sparse form (S = P_pp + R, K from P's first rows) gives.
        let H = SMatrix::<f64, 3, N_ERR>::identity();
        let cu = joseph_update(P, &H, &self.R, k)?;
        let nu = z - nom.p;
        let dx: Vec15 = cu.K * nu;
        let nis = nu.dot(&cu.chol.solve(&nu));
        Ok((nom.inject(&dx), cu, nu, nis))
    }
}

/// `Φ P Φ'` for a transition whose bias rows are the identity and whose first three
/// columns are the identity (`Φ = I + N`, N nonzero only in rows 0–8 and columns 3–14):
/// `A = Φ P` changes only rows 0–8, `A Φ'` only columns 0–8, so two 9×12 by 12×15 products
/// replace two dense 15×15 ones.
fn sandwich(F: &Mat15, P: &Mat15) -> Mat15 {
    let mut N: SMatrix<f64, 9, 12> = F.fixed_view::<9, 12>(0, 3).into_owned();
    for r in 3..9 {
        N[(r, r - 3)] -= 1.0;
    }
    let mut A = *P;
    let top = P.fixed_view::<9, 15>(0, 0) + N * P.fixed_view::<12, 15>(3, 0);
    A.fixed_view_mut::<9, 15>(0, 0).copy_from(&top);
    let mut B = A;
    let left = A.fixed_view::<15, 9>(0, 0) + A.fixed_view::<15, 12>(0, 3) * N.transpose();
    B.fixed_view_mut::<15, 9>(0, 0).copy_from(&left);
    B
}

impl Filter for Eskf {
    fn n_x(&self) -> usize {
        N_ERR
    }

    fn sensor_dims(&self) -> Vec<usize> {
        vec![3]
    }

    fn initial(&self) -> Estimate {
        let mut x = DVector::zeros(N_NOM);
        self.x0.write(x.as_mut_slice());
        Estimate::new(&x, &to_dynamic(&self.P0))
    }

    fn predict(&self, _k: usize, _est: &mut Estimate) -> PredictResult {
        Err(FilterError::Unsupported {
            what: "a prediction without IMU samples",
        })
    }

    fn predict_with_input(&self, k: usize, est: &mut Estimate, u: &DVector<f64>) -> PredictResult {
        if u.len() != 6 * self.n_imu {
            return Err(FilterError::Unsupported {
                what: "an IMU input of 6 values per sample",
            });
        }
        let bad = FilterError::NotPositiveDefinite {
            which: "P",
            step: k,
        };
        let mut nom = Nominal::from_slice(est.x.as_slice()).ok_or(bad.clone())?;
        let mut P: Mat15 = to_fixed(&est.P).ok_or(bad.clone())?;
        let F = self.propagate(&mut nom, &mut P, u.as_slice());
        if !P.iter().all(|v| v.is_finite()) {
            return Err(bad);
        }
        nom.write(est.x.as_mut_slice());
        est.P.copy_from_slice(P.as_slice());
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
        check_measurement((meas.sensor == 0).then_some(3), meas)?;
        let badp = FilterError::NotPositiveDefinite {
            which: "P",
            step: k,
        };
        let nom = Nominal::from_slice(est.x.as_slice()).ok_or(badp.clone())?;
        let P: Mat15 = to_fixed(&est.P).ok_or(badp)?;
        let z = Vector3::new(meas.z[0], meas.z[1], meas.z[2]);
        let (nom, cu, nu, nis) = self.update_fixed(k, &nom, &P, &z)?;
        nom.write(est.x.as_mut_slice());
        est.P.copy_from_slice(cu.P.as_slice());
        est.compose_error_map_fixed(&cu.IKH);
        out.set_fixed(&nu, &cu.S, nis);
        Ok(())
    }

    /// The 15-vector error of the truth's navigation state (its first 16 entries, see
    /// [`super::truth::layout`]) relative to the estimate, attitude as `Log(R_t R̂')`.
    fn state_error(&self, truth: &DVector<f64>, estimate: &DVector<f64>) -> DVector<f64> {
        match (
            Nominal::from_slice(truth.as_slice()),
            Nominal::from_slice(estimate.as_slice()),
        ) {
            (Some(t), Some(e)) => DVector::from_column_slice(e.error_to(&t).as_slice()),
            _ => DVector::from_element(N_ERR, f64::NAN),
        }
    }

    fn state_error_into(
        &self,
        truth: &DVector<f64>,
        estimate: &DVector<f64>,
        out: &mut DVector<f64>,
    ) {
        match (
            Nominal::from_slice(truth.as_slice()),
            Nominal::from_slice(estimate.as_slice()),
        ) {
            (Some(t), Some(e)) => store(out, &e.error_to(&t)),
            _ => *out = DVector::from_element(N_ERR, f64::NAN),
        }
    }
}
