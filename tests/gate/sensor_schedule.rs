//! Sensors that come and go: the NIS degrees of freedom of each step are those of the
//! measurements actually used at that step.

use autotune::SimRng;
use autotune::internals::filter::{Ekf, SystemModel};
use autotune::internals::measurement::Measurement;
use autotune::internals::model::{TruthModel, sample_gaussian};
use autotune::internals::montecarlo::{McConfig, run_generic};
use autotune::internals::stats::{ConsistencyReport, Verdict, chi2_average_interval};
use nalgebra::{DMatrix, DVector};

const DT: f64 = 1.0;

/// Which sensors report at step k: position (2-D) on even steps, range (1-D) every third
/// step, nothing when neither.
fn sensors_at(k: usize) -> Vec<usize> {
    let mut s = Vec::new();
    if k.is_multiple_of(2) {
        s.push(0);
    }
    if k.is_multiple_of(3) {
        s.push(1);
    }
    s
}

struct Cv2d;

impl Cv2d {
    fn f() -> DMatrix<f64> {
        DMatrix::from_row_slice(
            4,
            4,
            &[
                1.0, DT, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, DT, 0.0, 0.0, 0.0, 1.0,
            ],
        )
    }
    fn q() -> DMatrix<f64> {
        let b = autotune::internals::params::dwna_block(DT) * 0.3;
        autotune::internals::params::embed(4, &[0, 1], &b)
            + autotune::internals::params::embed(4, &[2, 3], &b)
    }
    fn r() -> Vec<DMatrix<f64>> {
        vec![
            DMatrix::identity(2, 2) * 2.0,
            DMatrix::from_element(1, 1, 0.5),
        ]
    }
}

impl SystemModel for Cv2d {
    fn n_x(&self) -> usize {
        4
    }
    fn sensor_dims(&self) -> Vec<usize> {
        vec![2, 1]
    }
    fn transition(&self, _k: usize, x: &DVector<f64>) -> DVector<f64> {
        Self::f() * x
    }
    fn measurement(&self, _k: usize, sensor: usize, x: &DVector<f64>) -> DVector<f64> {
        match sensor {
            0 => DVector::from_column_slice(&[x[0], x[2]]),
            _ => DVector::from_column_slice(&[(x[0] * x[0] + x[2] * x[2]).sqrt()]),
        }
    }
}

struct Truth {
    lq: DMatrix<f64>,
    lr: Vec<DMatrix<f64>>,
    p0: DMatrix<f64>,
    x0: DVector<f64>,
}

impl TruthModel for Truth {
    fn n_x(&self) -> usize {
        4
    }
    fn initial_state(&self, rng: &mut SimRng) -> DVector<f64> {
        sample_gaussian(&self.x0, &self.p0, rng)
    }
    fn propagate(&self, k: usize, x: &DVector<f64>, rng: &mut SimRng) -> DVector<f64> {
        sample_gaussian(&Cv2d.transition(k, x), &self.lq, rng)
    }
    fn measure(&self, k: usize, x: &DVector<f64>, rng: &mut SimRng, out: &mut Vec<Measurement>) {
        for s in sensors_at(k) {
            out.push(Measurement {
                sensor: s,
                z: sample_gaussian(&Cv2d.measurement(k, s, x), &self.lr[s], rng),
            });
        }
    }
}

#[test]
fn nis_interval_follows_the_measurement_dimension_of_each_step() {
    let factor = |m: &DMatrix<f64>| autotune::internals::linalg::psd_factor(m).unwrap();
    let x0 = DVector::from_column_slice(&[500.0, 5.0, 300.0, -2.0]);
    let p0 = DMatrix::from_diagonal(&DVector::from_column_slice(&[4.0, 1.0, 4.0, 1.0]));
    let truth = Truth {
        lq: factor(&Cv2d::q()),
        lr: Cv2d::r().iter().map(factor).collect(),
        p0: factor(&p0),
        x0: x0.clone(),
    };
    let ekf = Ekf {
        model: Cv2d,
        Q: Cv2d::q(),
        R: Cv2d::r(),
        x0,
        P0: p0,
    };
    let settings = McConfig::new(400, 60)
        .unwrap()
        .with_seed(11)
        .with_lags(2)
        .unwrap();
    let acc = run_generic(&truth, &ekf, &settings);
    assert_eq!(acc.diverged_runs(), 0);
    let names: Vec<String> = ["x", "vx", "y", "vy"]
        .iter()
        .map(|s| s.to_string())
        .collect();
    let meas = vec!["px".to_string(), "py".to_string(), "range".to_string()];
    let r = ConsistencyReport::from_accumulator(&acc, &settings.gate_spec(true), &names, &meas);
    let n = settings.runs() as f64;
    for k in 1..=settings.steps() {
        let dim: usize = sensors_at(k).iter().map(|&s| [2, 1][s]).sum();
        assert_eq!(acc.nis_dof()[k - 1], n * dim as f64, "step {k}");
        if dim == 0 {
            assert!(
                r.nis.per_step[k - 1].is_none(),
                "step {k} has no measurement"
            );
            continue;
        }
        let iv = chi2_average_interval(0.05, n * dim as f64, n);
        assert_eq!(r.nis.per_step_target[k - 1], Some(dim as f64), "step {k}");
        assert_eq!(r.nis.per_step_upper[k - 1], Some(iv.upper), "step {k}");
        assert_eq!(r.nis.per_step_lower[k - 1], Some(iv.lower), "step {k}");
    }
    // Steps 6, 12, … have both sensors (3 dof); the time-averaged target is the mean.
    let total_dim: usize = (1..=settings.steps())
        .flat_map(sensors_at)
        .map(|s| [2, 1][s])
        .sum();
    let measured_steps = (1..=settings.steps())
        .filter(|k| !sensors_at(*k).is_empty())
        .count();
    assert!((r.nis.target - total_dim as f64 / measured_steps as f64).abs() < 1e-12);
    // The filter equals the truth up to the range linearization, so the gate passes.
    assert_eq!(
        r.verdict,
        Verdict::Consistent,
        "NEES {:?} NIS {}",
        r.nees.as_ref().map(|s| s.time_average),
        r.nis.time_average
    );
}
