//! The EKF and UKF reduce to the Kalman filter on a linear model, and the finite-difference
//! Jacobian matches analytic ones.

use crate::common;
use autotune::Structure;

use autotune::internals::experiment::Experiment;
use autotune::internals::filter::{
    Ekf, Filter, KalmanFilter, LinearSystem, SystemModel, Ukf, numerical_jacobian,
};
use autotune::internals::measurement::Measurement;
use autotune::internals::model::TruthModel;
use autotune::internals::montecarlo::{run_generic, run_rng};
use common::{load, truth_values};
use nalgebra::{DMatrix, DVector};

fn rel(a: f64, b: f64) -> f64 {
    (a - b).abs() / a.abs().max(b.abs()).max(1e-300)
}

fn max_rel_m(a: &DMatrix<f64>, b: &DMatrix<f64>) -> f64 {
    let scale = a.abs().max().max(b.abs().max()).max(1e-300);
    (a - b).abs().max() / scale
}

/// A linear model wrapped so that the EKF must differentiate it numerically.
struct NoJacobians(LinearSystem);

impl SystemModel for NoJacobians {
    fn n_x(&self) -> usize {
        self.0.n_x()
    }
    fn sensor_dims(&self) -> Vec<usize> {
        self.0.sensor_dims()
    }
    fn transition(&self, k: usize, x: &DVector<f64>) -> DVector<f64> {
        self.0.transition(k, x)
    }
    fn measurement(&self, k: usize, s: usize, x: &DVector<f64>) -> DVector<f64> {
        self.0.measurement(k, s, x)
    }
}

fn filters(kf: &KalmanFilter) -> (Ekf<LinearSystem>, Ukf<LinearSystem>, Ekf<NoJacobians>) {
    let sys = LinearSystem {
        F: kf.F.clone(),
        H: kf.H.clone(),
    };
    let ekf = Ekf {
        model: sys.clone(),
        Q: kf.Q.clone(),
        R: vec![kf.R.clone()],
        x0: kf.x0.clone(),
        P0: kf.P0.clone(),
    };
    let ukf = Ukf::new(
        sys.clone(),
        kf.Q.clone(),
        vec![kf.R.clone()],
        kf.x0.clone(),
        kf.P0.clone(),
    );
    let fd = Ekf {
        model: NoJacobians(sys),
        Q: kf.Q.clone(),
        R: vec![kf.R.clone()],
        x0: kf.x0.clone(),
        P0: kf.P0.clone(),
    };
    (ekf, ukf, fd)
}

#[test]
fn ekf_and_ukf_agree_with_the_kf_on_a_linear_model() {
    for name in ["cv2d", "dcmotor"] {
        let p = load(name);
        // A mis-tuned filter, so that the comparison is not only at the optimum.
        let theta: Vec<f64> = truth_values(&p).iter().map(|v| v * 3.0).collect();
        let kf = p.linear().unwrap().filter_at(&theta);
        let (ekf, ukf, fd) = filters(&kf);
        let mut rng = run_rng(5, 0);
        let mut x = p.linear().unwrap().truth.initial_state(&mut rng);
        let mut e_kf = kf.initial();
        let mut e_ekf = ekf.initial();
        let mut e_ukf = ukf.initial();
        let mut e_fd = fd.initial();
        let mut meas = Vec::new();
        for k in 1..=100 {
            x = p.linear().unwrap().truth.propagate(k, &x, &mut rng);
            meas.clear();
            p.linear()
                .unwrap()
                .truth
                .measure(k, &x, &mut rng, &mut meas);
            let z: &Measurement = &meas[0];
            kf.predict(k, &mut e_kf).unwrap();
            ekf.predict(k, &mut e_ekf).unwrap();
            ukf.predict(k, &mut e_ukf).unwrap();
            fd.predict(k, &mut e_fd).unwrap();
            let i_kf = kf.update(k, &mut e_kf, z).unwrap();
            let i_ekf = ekf.update(k, &mut e_ekf, z).unwrap();
            let i_ukf = ukf.update(k, &mut e_ukf, z).unwrap();
            let i_fd = fd.update(k, &mut e_fd, z).unwrap();
            for (label, est, inn, tol) in [
                ("EKF", &e_ekf, &i_ekf, 1e-9),
                ("UKF", &e_ukf, &i_ukf, 1e-9),
                ("EKF (finite differences)", &e_fd, &i_fd, 1e-6),
            ] {
                let dx = (&est.x - &e_kf.x).abs().max() / e_kf.x.abs().max().max(1e-300);
                assert!(dx < tol, "{name} {label} step {k}: x differs by {dx:e}");
                let dp = max_rel_m(&est.P, &e_kf.P);
                assert!(dp < tol, "{name} {label} step {k}: P differs by {dp:e}");
                assert!(
                    rel(inn.nis, i_kf.nis) < tol,
                    "{name} {label} step {k}: NIS {} vs {}",
                    inn.nis,
                    i_kf.nis
                );
                let (map, map_kf) = (est.error_map.as_ref(), e_kf.error_map.as_ref());
                let dm = max_rel_m(map.expect("set"), map_kf.expect("set"));
                assert!(
                    dm < tol.max(1e-7),
                    "{name} {label} step {k}: error map differs by {dm:e}"
                );
            }
        }
        // And through the Monte Carlo engine: the same statistics.
        let mut mc = *p.mc();
        mc = mc.with_runs(40).unwrap();
        mc = mc.with_steps(60).unwrap();
        let a = run_generic(&p.linear().unwrap().truth, &kf, &mc);
        for (label, b) in [
            ("EKF", run_generic(&p.linear().unwrap().truth, &ekf, &mc)),
            ("UKF", run_generic(&p.linear().unwrap().truth, &ukf, &mc)),
        ] {
            for i in 0..mc.steps() {
                assert!(
                    rel(a.nees_sum()[i], b.nees_sum()[i]) < 1e-9,
                    "{name} {label} NEES step {}",
                    i + 1
                );
                assert!(
                    rel(a.nis_sum()[i], b.nis_sum()[i]) < 1e-9,
                    "{name} {label} NIS step {}",
                    i + 1
                );
            }
        }
    }
}

#[test]
fn numerical_jacobian_matches_analytic_on_a_range_bearing_sensor() {
    // h(x) = (range, bearing, range rate) of a target at (px, py) moving with (vx, vy).
    let h = |x: &DVector<f64>| {
        let (px, py, vx, vy): (f64, f64, f64, f64) = (x[0], x[1], x[2], x[3]);
        let r = (px * px + py * py).sqrt();
        DVector::from_column_slice(&[r, py.atan2(px), (px * vx + py * vy) / r])
    };
    let x = DVector::from_column_slice(&[30.0_f64, -12.0, 4.0, 7.5]);
    let (px, py, vx, vy): (f64, f64, f64, f64) = (x[0], x[1], x[2], x[3]);
    let r2 = px * px + py * py;
    let r = r2.sqrt();
    let rr = (px * vx + py * vy) / r;
    let analytic = DMatrix::from_row_slice(
        3,
        4,
        &[
            px / r,
            py / r,
            0.0,
            0.0,
            -py / r2,
            px / r2,
            0.0,
            0.0,
            vx / r - px * rr / r2,
            vy / r - py * rr / r2,
            px / r,
            py / r,
        ],
    );
    let numeric = numerical_jacobian(h, &x);
    let err = max_rel_m(&numeric, &analytic);
    assert!(err < 1e-8, "finite-difference Jacobian off by {err:e}");
}

/// cv2d with the process noise entering as accelerations: `x_k = F x + G w`.
struct NoiseDriven(LinearSystem, DMatrix<f64>);

impl SystemModel for NoiseDriven {
    fn n_x(&self) -> usize {
        self.0.n_x()
    }
    fn sensor_dims(&self) -> Vec<usize> {
        self.0.sensor_dims()
    }
    fn transition(&self, k: usize, x: &DVector<f64>) -> DVector<f64> {
        self.0.transition(k, x)
    }
    fn transition_with_noise(
        &self,
        k: usize,
        x: &DVector<f64>,
        w: &DVector<f64>,
    ) -> Option<DVector<f64>> {
        Some(self.0.transition(k, x) + &self.1 * w)
    }
    fn measurement(&self, k: usize, s: usize, x: &DVector<f64>) -> DVector<f64> {
        self.0.measurement(k, s, x)
    }
}

#[test]
fn ukf_with_augmented_process_noise_agrees_with_the_kf() {
    let p = load("cv2d");
    let theta: Vec<f64> = truth_values(&p).iter().map(|v| v * 2.0).collect();
    let kf = p.linear().unwrap().filter_at(&theta);
    // DWNA: Q = G diag(q_x, q_y) G' with G the per-axis gain [dt²/2, dt]'.
    let g = DMatrix::from_row_slice(4, 2, &[0.5, 0.0, 1.0, 0.0, 0.0, 0.5, 0.0, 1.0]);
    let qw = DMatrix::from_diagonal(&DVector::from_column_slice(&[theta[0], theta[1]]));
    assert!(max_rel_m(&(&g * &qw * g.transpose()), &kf.Q) < 1e-15);
    let sys = LinearSystem {
        F: kf.F.clone(),
        H: kf.H.clone(),
    };
    let mut ukf = Ukf::new(
        NoiseDriven(sys, g),
        DMatrix::zeros(4, 4),
        vec![kf.R.clone()],
        kf.x0.clone(),
        kf.P0.clone(),
    );
    ukf.augmented_noise = Some(qw);
    let mut rng = run_rng(3, 0);
    let mut x = p.linear().unwrap().truth.initial_state(&mut rng);
    let (mut a, mut b) = (kf.initial(), ukf.initial());
    let mut meas = Vec::new();
    for k in 1..=80 {
        x = p.linear().unwrap().truth.propagate(k, &x, &mut rng);
        meas.clear();
        p.linear()
            .unwrap()
            .truth
            .measure(k, &x, &mut rng, &mut meas);
        kf.predict(k, &mut a).unwrap();
        ukf.predict(k, &mut b).unwrap();
        let ia = kf.update(k, &mut a, &meas[0]).unwrap();
        let ib = ukf.update(k, &mut b, &meas[0]).unwrap();
        assert!(max_rel_m(&a.P, &b.P) < 1e-9, "step {k}: P");
        assert!(
            (&a.x - &b.x).abs().max() / a.x.abs().max() < 1e-9,
            "step {k}: x"
        );
        assert!(rel(ia.nis, ib.nis) < 1e-9, "step {k}: NIS");
    }
    // A model without the noise-driven form is an error, not a silent additive fallback.
    let mut plain = Ukf::new(
        LinearSystem {
            F: kf.F.clone(),
            H: kf.H.clone(),
        },
        kf.Q.clone(),
        vec![kf.R.clone()],
        kf.x0.clone(),
        kf.P0.clone(),
    );
    plain.augmented_noise = Some(DMatrix::identity(2, 2));
    let mut e = plain.initial();
    assert!(plain.predict(1, &mut e).is_err());
}
