//! Tune a model defined entirely in user code: a damped pendulum whose angle is measured,
//! tracked by an EKF, with the truth integrated by RK4 at a finer step than the filter's.
//!
//! Run with `cargo run --release --example custom_model`. It starts 10× off in both noise
//! parameters and exits non-zero unless the tuned filter passes the consistency gate on
//! fresh seeds.

use autotune::SimRng;
use autotune::filter::{Ekf, SystemModel};
use autotune::model::{Measurement, TruthModel, sample_gaussian};
use autotune::params::{ParamDef, ParamSpace, cwna_block};
use autotune::problem::McConfig;
use autotune::tune::{CustomModel, Silent, TuneSettings, TuneStatus, tune};
use nalgebra::{DMatrix, DVector};

/// Filter step, s.
const DT: f64 = 0.05;
/// RK4 substeps of the truth per filter step.
const SUBSTEPS: usize = 4;
/// g / L, 1/s² (a 1 m pendulum).
const G_OVER_L: f64 = 9.81;
/// Viscous damping, 1/s.
const DAMPING: f64 = 0.3;
/// The truth's noise: angular-acceleration spectral density, rad²/s³, and the angle
/// sensor's variance, rad².
const Q_TRUE: f64 = 0.02;
const R_TRUE: f64 = 1e-4;

/// θ'' = −(g/L) sin θ − c θ'.
fn derivative(x: &DVector<f64>) -> DVector<f64> {
    DVector::from_column_slice(&[x[1], -G_OVER_L * x[0].sin() - DAMPING * x[1]])
}

/// One filter step of the deterministic dynamics, by RK4 with `SUBSTEPS` substeps.
fn integrate(x: &DVector<f64>) -> DVector<f64> {
    let h = DT / SUBSTEPS as f64;
    let mut x = x.clone();
    for _ in 0..SUBSTEPS {
        let k1 = derivative(&x);
        let k2 = derivative(&(&x + &k1 * (h / 2.0)));
        let k3 = derivative(&(&x + &k2 * (h / 2.0)));
        let k4 = derivative(&(&x + &k3 * h));
        x += (k1 + k2 * 2.0 + k3 * 2.0 + k4) * (h / 6.0);
    }
    x
}

/// The filter's view: the same dynamics, angle measured.
struct Pendulum;

impl SystemModel for Pendulum {
    fn n_x(&self) -> usize {
        2
    }
    fn sensor_dims(&self) -> Vec<usize> {
        vec![1]
    }
    fn transition(&self, _k: usize, x: &DVector<f64>) -> DVector<f64> {
        integrate(x)
    }
    // No Jacobians: the EKF differentiates `transition` numerically.
    fn measurement(&self, _k: usize, _sensor: usize, x: &DVector<f64>) -> DVector<f64> {
        DVector::from_element(1, x[0])
    }
}

/// The simulated pendulum: integrated dynamics plus white angular-acceleration noise.
struct Truth {
    noise: DMatrix<f64>,
    sensor: DMatrix<f64>,
    p0: DMatrix<f64>,
}

impl TruthModel for Truth {
    fn n_x(&self) -> usize {
        2
    }
    fn initial_state(&self, rng: &mut SimRng) -> DVector<f64> {
        sample_gaussian(&DVector::from_column_slice(&[0.8, 0.0]), &self.p0, rng)
    }
    fn propagate(&self, _k: usize, x: &DVector<f64>, rng: &mut SimRng) -> DVector<f64> {
        sample_gaussian(&integrate(x), &self.noise, rng)
    }
    fn measure(&self, _k: usize, x: &DVector<f64>, rng: &mut SimRng, out: &mut Vec<Measurement>) {
        out.push(Measurement {
            sensor: 0,
            z: sample_gaussian(&DVector::from_element(1, x[0]), &self.sensor, rng),
        });
    }
}

fn main() {
    let factor = |m: &DMatrix<f64>| autotune::linalg::psd_factor(m).expect("PSD");
    let p0 = DMatrix::from_diagonal(&DVector::from_column_slice(&[0.01, 0.01]));
    let truth = Truth {
        noise: factor(&(cwna_block(DT) * Q_TRUE)),
        sensor: factor(&DMatrix::from_element(1, 1, R_TRUE)),
        p0: factor(&p0),
    };
    let param = |name: &str, value: f64, unit: &str, about: &str| ParamDef {
        name: name.into(),
        value,
        lower: value / 1e4,
        upper: value * 1e4,
        fixed: false,
        unit: unit.into(),
        about: about.into(),
    };
    let params = ParamSpace {
        params: vec![
            param(
                "q_accel",
                Q_TRUE * 10.0,
                "rad²/s³",
                "angular acceleration noise density",
            ),
            param("r_angle", R_TRUE / 10.0, "rad²", "angle sensor variance"),
        ],
    };
    let build = |theta: &[f64]| Ekf {
        model: Pendulum,
        Q: cwna_block(DT) * theta[0],
        R: vec![DMatrix::from_element(1, 1, theta[1])],
        x0: DVector::from_column_slice(&[0.8, 0.0]),
        P0: p0.clone(),
    };
    let model = CustomModel::new(
        truth,
        build,
        params.clone(),
        vec!["angle".into(), "rate".into()],
        vec!["angle".into()],
    );
    let mc = McConfig {
        runs: 100,
        steps: 100,
        seed: 1,
        alpha: 0.05,
        lags: 3,
    };
    // Monte Carlo scoring (an EKF has no closed form): a small global stage and two local
    // searches keep the example to seconds.
    let settings = TuneSettings {
        max_evals: 300,
        global_points_per_param: 4,
        starts: 2,
        search_runs: Some(200),
        ..TuneSettings::default()
    };
    let start = params.values();
    let result =
        tune(&model, &start, &[false, false], &mc, &settings, &Silent).expect("valid settings");
    println!(
        "pendulum: {} evaluations ({:?} scoring) in {:.1} s",
        result.evaluations, result.scoring, result.seconds
    );
    for (i, p) in params.params.iter().enumerate() {
        println!(
            "  {}: start {:.3e}, tuned {:.3e}, truth {:.3e}",
            p.name,
            start[i],
            result.tuned[i],
            [Q_TRUE, R_TRUE][i]
        );
    }
    let a = &result.after;
    println!(
        "  confirmation (seed {}): ANEES {:.3} in [{:.3}, {:.3}], ANIS {:.3} in [{:.3}, {:.3}]: {}",
        result.confirm_seed,
        a.nees.as_ref().map_or(f64::NAN, |s| s.time_average),
        a.nees.as_ref().map_or(f64::NAN, |s| s.interval.lower),
        a.nees.as_ref().map_or(f64::NAN, |s| s.interval.upper),
        a.nis.time_average,
        a.nis.interval.lower,
        a.nis.interval.upper,
        a.verdict.describe()
    );
    if result.status != TuneStatus::Consistent {
        eprintln!(
            "the tuned pendulum filter did not pass the gate: {:?}",
            result.status
        );
        std::process::exit(1);
    }
}
