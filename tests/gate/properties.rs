//! Invariants that are cheap to state, checked on random inputs (proptest): every parameter
//! vector gives symmetric PSD Q and R; Kalman, extended and unscented updates keep P
//! symmetric and positive semidefinite. (That Monte Carlo sums merge associatively is a
//! property test of `stats::sums`, beside the sums.)

use crate::common;
use autotune::Structure;

use autotune::internals::experiment::Experiment;
use autotune::internals::filter::{Ekf, Filter, KalmanFilter, LinearSystem, Ukf};
use autotune::internals::linalg::{asymmetry, max_abs, min_eigenvalue};
use autotune::internals::measurement::Measurement;
use nalgebra::{DMatrix, DVector};
use proptest::prelude::*;

/// Smallest eigenvalue allowed for a PSD matrix: rounding of order 1e-12 of its scale.
fn psd_floor(m: &DMatrix<f64>) -> f64 {
    -1e-12 * max_abs(m).max(f64::MIN_POSITIVE)
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(200))]

    /// Q(θ) = Σ θ_i B_i with PSD bases: symmetric and PSD for every θ > 0, over twelve
    /// decades per parameter, on each shipped linear problem's own terms.
    #[test]
    fn every_theta_gives_symmetric_psd_q_and_r(
        which in 0usize..3,
        decades in proptest::collection::vec(-6.0f64..6.0, 4),
    ) {
        let p = common::load(["cv1d", "cv2d", "dcmotor"][which]);
        let theta: Vec<f64> = p
            .params()
            .values()
            .iter()
            .zip(&decades)
            .map(|(v, d)| v * 10f64.powf(*d))
            .collect();
        let c = p.covariances(&theta).unwrap();
        for m in [&c.Q, &c.R] {
            prop_assert!(asymmetry(m).is_none());
            prop_assert!(min_eigenvalue(m) >= psd_floor(m), "{m}");
        }
    }

    /// One predict and one update of the KF, and of the EKF and UKF on the same linear
    /// system, from a random PSD covariance whose scales span eight decades: P stays
    /// symmetric (to the symmetry check's 1e-9 relative) and PSD.
    #[test]
    fn updates_keep_p_symmetric_and_psd(
        a in proptest::collection::vec(-1.0f64..1.0, 9),
        f in proptest::collection::vec(-0.3f64..0.3, 9),
        h in proptest::collection::vec(-2.0f64..2.0, 6),
        scales in proptest::collection::vec(-4.0f64..4.0, 3),
        r in proptest::collection::vec(-3.0f64..1.0, 2),
        z in proptest::collection::vec(-10.0f64..10.0, 2),
    ) {
        let s = DMatrix::from_diagonal(&DVector::from_iterator(3, scales.iter().map(|d| 10f64.powf(*d))));
        let a = DMatrix::from_row_slice(3, 3, &a);
        let p0 = &s * (&a * a.transpose() + DMatrix::identity(3, 3) * 1e-3) * &s;
        let fm = DMatrix::identity(3, 3) + DMatrix::from_row_slice(3, 3, &f);
        let hm = DMatrix::from_row_slice(2, 3, &h);
        let rm = DMatrix::from_diagonal(&DVector::from_iterator(2, r.iter().map(|d| 10f64.powf(*d))));
        let q = DMatrix::identity(3, 3) * 1e-2;
        let x0 = DVector::zeros(3);
        let kf = KalmanFilter { F: fm.clone(), H: hm.clone(), Q: q.clone(), R: rm.clone(), x0: x0.clone(), P0: p0.clone() };
        let sys = LinearSystem { F: fm, H: hm };
        let ekf = Ekf { model: sys.clone(), Q: q.clone(), R: vec![rm.clone()], x0: x0.clone(), P0: p0.clone() };
        let ukf = Ukf::new(sys, q, vec![rm], x0, p0);
        let meas = Measurement { sensor: 0, z: DVector::from_column_slice(&z) };
        let filters: [&dyn Filter; 3] = [&kf, &ekf, &ukf];
        for (name, filter) in ["KF", "EKF", "UKF"].iter().zip(filters) {
            let mut est = filter.initial();
            filter.predict(1, &mut est).unwrap();
            prop_assert!(asymmetry(&est.P).is_none(), "{name} predict");
            filter.update(1, &mut est, &meas).unwrap();
            prop_assert!(asymmetry(&est.P).is_none(), "{name} update: {}", est.P);
            prop_assert!(min_eigenvalue(&est.P) >= -1e-9 * max_abs(&est.P), "{name}: {}", est.P);
        }
    }
}
