//! Q and R from measurements: maximum likelihood on simulated cv2d records.

mod common;

use autotune::estimate::{LinearFilterModel, ml, simulate};
use autotune::experiment::{Experiment, LinearExperiment};
use autotune::problem::Problem;

fn cv2d() -> (Problem, LinearExperiment) {
    let p = common::load("cv2d");
    let lin = p.linear().expect("cv2d is linear").clone();
    (p, lin)
}

fn builder(lin: &LinearExperiment) -> impl Fn(&[f64]) -> LinearFilterModel + '_ {
    move |theta: &[f64]| {
        let kf = lin.filter_at(theta);
        LinearFilterModel {
            F: kf.F,
            H: kf.H,
            Q: kf.Q,
            R: kf.R,
            x0: kf.x0,
            P0: kf.P0,
        }
    }
}

/// 5 000 steps: every parameter within 3 of its own standard errors of the truth, and the
/// likelihood at the estimate not below the truth's. Over 10 seeds (each a fresh record): if
/// the standard errors are right, all four |z| ≤ 3 holds with probability ≈ 0.989 per seed,
/// so at least 9 of 10 seeds with probability 0.995 (measured: 10 of 10; an estimator off
/// by a few percent, or standard errors too small by half, fails most seeds).
#[test]
fn ml_on_5000_steps_lands_within_three_standard_errors() {
    let (p, lin) = cv2d();
    let truth = common::truth_values(&p);
    let build = builder(&lin);
    let mut within = 0;
    let seeds = 10;
    for seed in 0..seeds {
        let sim = simulate(&lin.truth, 2, 1, 5000, 100 + seed);
        let start = vec![1.0; truth.len()];
        let t0 = std::time::Instant::now();
        let est = ml::estimate(
            &build,
            &sim.measurements,
            &start,
            &vec![false; truth.len()],
            200,
        )
        .expect("the search runs");
        let took = t0.elapsed();
        let at_truth = build(&truth).neg_log_likelihood(&sim.measurements).unwrap();
        assert!(
            est.neg_log_likelihood <= at_truth + 1e-6,
            "seed {seed}: {} > {at_truth}",
            est.neg_log_likelihood
        );
        let z: Vec<f64> = est
            .theta
            .iter()
            .zip(&truth)
            .zip(&est.std_errors)
            .map(|((e, t), se)| (e - t) / se.expect("identified"))
            .collect();
        eprintln!(
            "seed {seed}: {:?} z {:?} ({} its, {} evals, {:?})",
            est.theta, z, est.iterations, est.evaluations, took
        );
        if z.iter().all(|v| v.abs() <= 3.0) {
            within += 1;
        }
    }
    assert!(within >= 9, "{within} of {seeds}");
}

/// NIS-only tuning against a recorded cv2d record (20 sequences × 500 steps, no truth):
/// the search lands within 10% of the parameters the record was drawn with.
#[test]
fn tune_against_recorded_measurements_recovers_the_truth() {
    let dir = tempfile::tempdir().unwrap();
    let rec = dir.path().join("rec.csv");
    let out = dir.path().join("tuned.toml");
    let problem = common::problem_path("cv2d");
    let p = problem.to_str().unwrap();
    let (code, _, err) = common::autotune(&[
        "simulate",
        p,
        "--out",
        rec.to_str().unwrap(),
        "--runs",
        "20",
        "--steps",
        "500",
        "--seed",
        "11",
    ]);
    assert_eq!(code, Some(0), "{err}");
    let (code, stdout, err) = common::autotune(&[
        "tune",
        p,
        "--measurements",
        rec.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--quiet",
    ]);
    assert_eq!(code, Some(0), "{stdout}{err}");
    let tuned: toml::Table = std::fs::read_to_string(&out).unwrap().parse().unwrap();
    let (prob, _) = cv2d();
    for (name, truth) in prob
        .params()
        .names()
        .iter()
        .zip(common::truth_values(&prob))
    {
        let v = tuned["params"][*name].as_float().unwrap();
        assert!((v / truth - 1.0).abs() < 0.10, "{name}: {v} vs {truth}");
    }
}
