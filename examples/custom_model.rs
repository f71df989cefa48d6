//! A model defined entirely in user code, with the whole autotune command line: a damped
//! pendulum whose angle is measured, tracked by an EKF, with the truth integrated by RK4 at
//! a finer step than the filter's. The filter is configured 10× off in both noise
//! parameters.
//!
//! ```sh
//! cargo run --release --example custom_model -- check                  # exit 1: 10× off
//! cargo run --release --example custom_model -- tune --out /tmp/pendulum.toml --report out/pendulum
//! cargo run --release --example custom_model -- check --config /tmp/pendulum.toml   # exit 0
//! ```
//!
//! `tune` writes the same tuned config, report.html/md/json and advice as `autotune tune`
//! does for a problem file; every option of `autotune check` and `tune` works (`--json`,
//! `--junit`, `--set`, `--fix`, `--runs`, …).

use std::process::ExitCode;

use autotune::{
    Covariances, Ekf, McConfig, Measurement, ParamDef, RustModel, SimRng, SystemModel, Target,
    TruthModel, TuneSettings, cwna_block, psd_factor, sample_gaussian,
};
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

fn main() -> ExitCode {
    let factor = |m: &DMatrix<f64>| psd_factor(m).expect("PSD");
    let p0 = DMatrix::from_diagonal(&DVector::from_column_slice(&[0.01, 0.01]));
    let truth = Truth {
        noise: factor(&(cwna_block(DT) * Q_TRUE)),
        sensor: factor(&DMatrix::from_element(1, 1, R_TRUE)),
        p0: factor(&p0),
    };
    let filter = move |theta: &[f64]| Ekf {
        model: Pendulum,
        Q: cwna_block(DT) * theta[0],
        R: vec![DMatrix::from_element(1, 1, theta[1])],
        x0: DVector::from_column_slice(&[0.8, 0.0]),
        P0: p0.clone(),
    };
    let model = RustModel::builder("pendulum", truth, filter)
        .description("damped pendulum, angle measured, EKF (autotune example)")
        .program("custom_model")
        .states(["angle", "rate"])
        .measurements(["angle"])
        .param(
            ParamDef::new("q_accel", Q_TRUE * 10.0)
                .unit("rad²/s³")
                .about("angular acceleration noise density"),
            Target::process(&[0, 1]),
        )
        .param(
            ParamDef::new("r_angle", R_TRUE / 10.0)
                .unit("rad²")
                .about("angle sensor variance"),
            Target::measurement(&[0]),
        )
        .covariances(|theta| Covariances {
            Q: cwna_block(DT) * theta[0],
            R: DMatrix::from_element(1, 1, theta[1]),
        })
        .truth_values(vec![Q_TRUE, R_TRUE])
        .montecarlo(
            McConfig::new(100, 100)
                .and_then(|mc| mc.with_lags(3))
                .expect("valid Monte Carlo settings")
                .with_seed(1),
        )
        .build()
        .expect("a valid model");
    // Monte Carlo scoring (an EKF has no closed form): a small global stage and two local
    // searches keep a tuning run to seconds.
    let settings = TuneSettings::default()
        .with_max_evals(300)
        .and_then(|s| s.with_global_points(4))
        .and_then(|s| s.with_starts(2))
        .and_then(|s| s.with_search_runs(200))
        .expect("valid tuning settings");
    autotune::app::main_for(&model, &settings)
}
