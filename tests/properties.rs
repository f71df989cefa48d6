//! Invariants that are cheap to state, checked on random inputs (proptest): every parameter
//! vector gives symmetric PSD Q and R; Kalman, extended and unscented updates keep P
//! symmetric and positive semidefinite; Monte Carlo sums merge associatively (the engine
//! relies on it to give the same result whatever the chunking).

mod common;

use autotune::experiment::Experiment;
use autotune::filter::{Ekf, Filter, KalmanFilter, LinearSystem, Ukf};
use autotune::linalg::{asymmetry, max_abs, min_eigenvalue};
use autotune::measurement::Measurement;
use autotune::stats::{Accumulator, Divergence};
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

    /// `(a + b) + c == a + (b + c)` exactly, on sums whose values are small integers (exact
    /// in floating point, so any field merged wrongly, twice or not at all shows).
    #[test]
    fn sums_merge_associatively(
        va in proptest::collection::vec(0u32..100, 64),
        vb in proptest::collection::vec(0u32..100, 64),
        vc in proptest::collection::vec(0u32..100, 64),
    ) {
        let a = accumulator(&va);
        let b = accumulator(&vb);
        let c = accumulator(&vc);
        let mut left = a.clone();
        left.merge(&b);
        left.merge(&c);
        let mut bc = b.clone();
        bc.merge(&c);
        let mut right = a.clone();
        right.merge(&bc);
        prop_assert_eq!(&left, &right);
        // And merging adds every sum (associativity alone would not see a field that is
        // never merged).
        let (sa, sb, sc, sl) = (scalars(&a), scalars(&b), scalars(&c), scalars(&left));
        for i in 0..sl.len() {
            prop_assert_eq!(sl[i], sa[i] + sb[i] + sc[i], "scalar {}", i);
        }
        let (va, vb, vc, vl) = (vectors(&a), vectors(&b), vectors(&c), vectors(&left));
        for (k, l) in vl.iter().enumerate() {
            for j in 0..l.len() {
                prop_assert_eq!(l[j], va[k][j] + vb[k][j] + vc[k][j], "vector {} [{}]", k, j);
            }
        }
    }
}

/// Every scalar sum of `acc`, as f64.
fn scalars(acc: &Accumulator) -> Vec<f64> {
    vec![
        acc.runs as f64,
        acc.nees_null_var,
        acc.null_var_runs as f64,
        acc.error_map_missing as f64,
        acc.nees_run_total,
        acc.nees_run_total_sq,
        acc.nees_total_runs as f64,
        acc.diverged_runs as f64,
        acc.meas_comp_runs[0] as f64,
        acc.meas_comp_runs[1] as f64,
    ]
}

/// Every vector sum of `acc`.
fn vectors(acc: &Accumulator) -> Vec<Vec<f64>> {
    let mut a = acc.clone();
    fields(&mut a).into_iter().map(|v| v.clone()).collect()
}

/// The vector sums of `acc`, for filling and for checking.
fn fields(acc: &mut Accumulator) -> [&mut Vec<f64>; 26] {
    [
        &mut acc.nees_sum,
        &mut acc.nees_sq,
        &mut acc.nees_dof,
        &mut acc.nees_count,
        &mut acc.nis_sum,
        &mut acc.nis_sq,
        &mut acc.nis_dof,
        &mut acc.nis_count,
        &mut acc.state_comp_total,
        &mut acc.state_comp_samples,
        &mut acc.state_comp_run_sum,
        &mut acc.state_comp_run_sq,
        &mut acc.state_comp_null_var,
        &mut acc.state_mean_total,
        &mut acc.state_mean_samples,
        &mut acc.state_mean_run_sq,
        &mut acc.state_mean_null_var,
        &mut acc.meas_mean_total,
        &mut acc.meas_comp_total,
        &mut acc.meas_comp_samples,
        &mut acc.meas_comp_run_sum,
        &mut acc.meas_comp_run_sq,
        &mut acc.white_ab,
        &mut acc.white_a2,
        &mut acc.white_b2,
        &mut acc.white_pairs,
    ]
}

/// An accumulator of 3 steps, 2 states, 2 measurement components and 2 lags, every field
/// filled from `v` (cycled), with up to 7 divergences.
fn accumulator(v: &[u32]) -> Accumulator {
    let mut acc = Accumulator::new(3, 2, 2, 2);
    let mut it = v.iter().cycle().map(|&x| f64::from(x));
    let mut fill = |xs: &mut Vec<f64>| xs.iter_mut().for_each(|x| *x = it.next().unwrap());
    for xs in fields(&mut acc) {
        fill(xs);
    }
    acc.runs = v[0] as usize;
    acc.nees_null_var = f64::from(v[1]);
    acc.null_var_runs = v[2] as usize;
    acc.error_map_missing = v[3] as usize % 3;
    acc.nees_run_total = f64::from(v[4]);
    acc.nees_run_total_sq = f64::from(v[5]);
    acc.nees_total_runs = v[6] as usize;
    acc.meas_comp_runs = vec![v[7] as usize, v[8] as usize];
    for i in 0..(v[9] as usize % 8) {
        acc.record_divergence(i, v[10 + i] as usize, format!("reason {i}"));
    }
    acc
}

#[test]
fn divergence_details_keep_the_first_ten_in_run_order() {
    let mut a = Accumulator::new(1, 1, 1, 0);
    for run in 0..8 {
        a.record_divergence(run, 1, "S".into());
    }
    let mut b = Accumulator::new(1, 1, 1, 0);
    for run in 8..12 {
        b.record_divergence(run, 2, "P".into());
    }
    a.merge(&b);
    assert_eq!(a.diverged_runs, 12);
    let runs: Vec<usize> = a.divergences.iter().map(|d: &Divergence| d.run).collect();
    assert_eq!(runs, (0..10).collect::<Vec<_>>());
}
