//! Q and R from measurements: maximum likelihood on simulated cv2d records.

use crate::common;
use autotune::Structure;

use autotune::internals::estimate::{EstimateError, ml, simulate};
use autotune::internals::experiment::{Experiment, LinearExperiment};
use autotune::internals::problem::Problem;

fn cv2d() -> (Problem, LinearExperiment) {
    let p = common::load("cv2d");
    let lin = p.linear().expect("cv2d is linear").clone();
    (p, lin)
}

fn builder(
    lin: &LinearExperiment,
) -> impl Fn(&[f64]) -> autotune::internals::filter::KalmanFilter + '_ {
    move |theta: &[f64]| lin.filter_at(theta)
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

/// 20 000 steps: every parameter within 10% of the truth on each of five records (measured
/// worst 4.3% over ten; the standard errors are 2–3% of each value, so 10% is about four of
/// them).
#[test]
fn ml_on_20000_steps_lands_within_ten_percent() {
    let (p, lin) = cv2d();
    let truth = common::truth_values(&p);
    let build = builder(&lin);
    for seed in 31..36 {
        let sim = simulate(&lin.truth, 2, 1, 20_000, seed);
        let est = ml::estimate(
            &build,
            &sim.measurements,
            &vec![1.0; truth.len()],
            &vec![false; truth.len()],
            200,
        )
        .expect("the search runs");
        for (i, (e, t)) in est.theta.iter().zip(&truth).enumerate() {
            assert!(
                (e / t - 1.0).abs() < 0.10,
                "seed {seed}, parameter {i}: {e} vs {t}"
            );
        }
    }
}

/// The likelihood against an independent implementation: pykalman 0.11.2's
/// `loglikelihood` on the record `simulate --steps 5000 --seed 7` writes, at the ML
/// estimate, as recorded in examples/python/em/results.json. The two agree to 1e-12
/// relative (measured 2e-15): same model, same prediction-error decomposition, written
/// twice.
#[test]
fn log_likelihood_matches_pykalman() {
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
    let results: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(root.join("examples/python/em/results.json")).unwrap(),
    )
    .unwrap();
    let seven = &results["runs"][0]["seeds"]["7"];
    let reference = seven["loglik_check"]["pykalman_loglik_at_autotune_theta"]
        .as_f64()
        .unwrap();
    let (p, lin) = cv2d();
    let theta: Vec<f64> = p
        .params()
        .names()
        .iter()
        .map(|n| seven["autotune"]["theta"][*n].as_f64().unwrap())
        .collect();
    let dir = tempfile::tempdir().unwrap();
    let rec = dir.path().join("z.csv");
    let problem = common::problem_path("cv2d");
    let (code, _, err) = common::autotune(&[
        "simulate",
        problem.to_str().unwrap(),
        "--out",
        rec.to_str().unwrap(),
        "--steps",
        "5000",
        "--seed",
        "7",
    ]);
    assert_eq!(code, Some(0), "{err}");
    let data = autotune::internals::estimate::read_measurements(&rec).unwrap();
    let nll = builder(&lin)(&theta).neg_log_likelihood(&data).unwrap();
    assert!(
        ((-nll) / reference - 1.0).abs() < 1e-12,
        "{} vs pykalman {reference}",
        -nll
    );
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
    ]);
    assert_eq!(code, Some(0), "{stdout}{err}");
    // One record is one draw: confirmed once on it, not on "fresh seeds" that would all
    // give the same numbers.
    assert!(
        stdout.contains("the recorded measurements pass the gate")
            && !stdout.contains("fresh seeds pass"),
        "{stdout}"
    );
    let tuned: toml::Table = std::fs::read_to_string(&out).unwrap().parse().unwrap();
    let c = &tuned["provenance"]["confirmation"];
    assert_eq!(c["recorded"].as_bool(), Some(true));
    assert_eq!(c["seeds"].as_integer(), Some(1));
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

fn als_model(lin: &LinearExperiment) -> autotune::internals::estimate::als::AlsModel<'_> {
    autotune::internals::estimate::als::AlsModel::of(lin)
}

/// ALS from all parameters = 1.0 on 20 000-step cv2d records: every per-axis Q and R
/// parameter within 10% of the truth on each of five records (the issue asks for 20%;
/// measured: at most 4% with two passes). A wrong autocovariance formula (a missing
/// `− H Ā^{j−1} F K R` term, a transposed lag) puts q_accel_y off by far more.
#[test]
fn als_recovers_every_parameter_within_ten_percent_on_20000_steps() {
    let (p, lin) = cv2d();
    let truth = common::truth_values(&p);
    let model = als_model(&lin);
    for seed in 21..26 {
        let sim = simulate(&lin.truth, 2, 1, 20_000, seed);
        let start = vec![1.0; truth.len()];
        let est = autotune::internals::estimate::als::estimate_passes(
            &model,
            &sim.measurements,
            &start,
            &vec![false; truth.len()],
            15,
            2,
        )
        .expect("ALS runs");
        for (i, (e, t)) in est.theta.iter().zip(&truth).enumerate() {
            assert!(
                (e / t - 1.0).abs() < 0.10,
                "seed {seed}, parameter {i}: {e} vs {t}"
            );
        }
    }
}

/// dcmotor's noise is tiny in absolute terms (r_angle = 4e-6 rad²; autocovariances near
/// 1e-5): the constrained solve must still land on the least-squares solution whenever that
/// is interior (it once returned q_voltage = 6.3 for an unconstrained 0.027, its objective
/// below the solver's absolute tolerance). Five 20 000-step records: constrained equal to
/// unconstrained to 1e-6 (measured: up to 9e-8 at the solver's tolerance of 1e-11, 1.5e-6 at
/// its default 1e-8); q_torque within
/// 15% and r_angle within 3% of the truth (measured: 13% and 1.5%). q_voltage is weakly determined by an angle sensor (ML's own standard error
/// is a third of it) and is held to the interior check only.
#[test]
fn als_on_small_noise_lands_on_the_least_squares_solution() {
    let p = common::load("dcmotor");
    let lin = p.linear().unwrap().clone();
    let truth = common::truth_values(&p);
    let model = als_model(&lin);
    let start = p.params().values();
    for seed in 1..=5 {
        let sim = simulate(&lin.truth, 1, 1, 20_000, seed);
        let est = autotune::internals::estimate::als::estimate_passes(
            &model,
            &sim.measurements,
            &start,
            &[false; 3],
            15,
            2,
        )
        .expect("ALS runs");
        for (i, (c, u)) in est.theta.iter().zip(&est.unconstrained).enumerate() {
            assert!(*u > 0.0, "seed {seed}: parameter {i} unconstrained {u}");
            assert!(
                (c / u - 1.0).abs() < 1e-6,
                "seed {seed}, parameter {i}: {c} vs {u}"
            );
        }
        assert!(
            (est.theta[0] / truth[0] - 1.0).abs() < 0.15,
            "seed {seed}: {:?}",
            est.theta
        );
        assert!(
            (est.theta[2] / truth[2] - 1.0).abs() < 0.03,
            "seed {seed}: {:?}",
            est.theta
        );
    }
}

/// A target that barely manoeuvres in y (truth q_accel_y = 0.001) seen for 400 steps:
/// unconstrained least squares makes q_accel_y negative on some records; ALS holds it at 0,
/// so Q and R stay positive semidefinite on every record.
#[test]
fn als_never_returns_a_negative_variance() {
    let text = std::fs::read_to_string(common::problem_path("cv2d"))
        .unwrap()
        .replace(
            "{ kind = \"dwna\", indices = [2, 3], value = 0.1 }",
            "{ kind = \"dwna\", indices = [2, 3], value = 0.001 }",
        );
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("still.toml");
    std::fs::write(&path, text).unwrap();
    let p = Problem::load(&path).unwrap();
    let lin = p.linear().unwrap().clone();
    let model = als_model(&lin);
    let start = p.params().values();
    let mut negative = 0;
    for seed in 1..=8 {
        let sim = simulate(&lin.truth, 2, 1, 400, seed);
        let est = autotune::internals::estimate::als::estimate_passes(
            &model,
            &sim.measurements,
            &start,
            &[false; 4],
            15,
            2,
        )
        .expect("ALS runs");
        if est.unconstrained.iter().any(|v| *v < 0.0) {
            negative += 1;
            assert!(!est.at_zero.is_empty(), "seed {seed}");
        }
        assert!(
            est.theta.iter().all(|v| *v >= 0.0),
            "seed {seed}: {:?}",
            est.theta
        );
        let q = lin.filter.q.build(&est.theta);
        let r = lin.filter.r.build(&est.theta);
        for m in [q, r] {
            let min = m.symmetric_eigenvalues().min();
            assert!(
                min >= -1e-12 * m.abs().max(),
                "seed {seed}: eigenvalue {min}"
            );
        }
    }
    eprintln!("{negative} of 8 records with a negative unconstrained variance");
    // Measured: 3 of these 8 records (seeds 2, 4, 6).
    assert!(
        negative >= 2,
        "{negative} records with a negative unconstrained variance"
    );
}

/// ALS refuses what it cannot use: records with gaps, too short a record, an unstable filter.
#[test]
fn als_refuses_gaps_short_records_and_unstable_filters() {
    let (_, lin) = cv2d();
    let model = als_model(&lin);
    let start = vec![1.0; 4];
    let mut sim = simulate(&lin.truth, 2, 1, 60, 1);
    let e = autotune::internals::estimate::als::estimate(
        &model,
        &sim.measurements,
        &start,
        &[false; 4],
        15,
    )
    .unwrap_err();
    assert!(matches!(e, EstimateError::TooShort { .. }), "{e}");
    assert!(e.to_string().contains("too short"), "{e}");
    sim.measurements.sequences[0].z[7] = f64::NAN;
    let e = autotune::internals::estimate::als::estimate(
        &model,
        &sim.measurements,
        &start,
        &[false; 4],
        15,
    )
    .unwrap_err();
    assert_eq!(e, EstimateError::Gaps);
    assert!(e.to_string().contains("every component"), "{e}");
    // A filter that does not see y (H's second row zero) and believes y still (its F has no
    // y velocity coupling, its q_accel_y is 0): its covariance settles, but its error in y
    // never decays (Ā has an eigenvalue 1), so its innovations are not stationary.
    let mut blind = lin.clone();
    blind.filter.F[(2, 3)] = 0.0;
    blind.filter.H[(1, 2)] = 0.0;
    let bm = als_model(&blind);
    let sim = simulate(&lin.truth, 2, 1, 2000, 1);
    let e = autotune::internals::estimate::als::estimate(
        &bm,
        &sim.measurements,
        &[1.0, 0.0, 1.0, 1.0],
        &[false; 4],
        15,
    )
    .unwrap_err();
    assert!(matches!(e, EstimateError::Unstable(_)), "{e}");
    let e = e.to_string();
    assert!(
        e.contains("unstable") && e.contains("spectral radius"),
        "{e}"
    );
}

/// `tune --init ml` (and `als`) start from the estimate on a record simulated from the
/// truth: the search skips its global stage and needs fewer than half the evaluations from
/// the file's start to reach the same tuned config (to 1e-4 relative). Measured on cv2d:
/// exact scoring 572 (ml) and 565 (als) against 1 391. Under Monte Carlo scoring the
/// default search is Gauss–Newton, which itself skips the global stage once the moment
/// equations solved from the file's start score as consistent (issue 25): 21 (ml) against
/// 30, so there the estimate saves evaluations but not half; the two tuned configs within
/// 4e-5 of each other (common random numbers: the same optimum of the same noisy
/// objective).
#[test]
fn tune_from_an_estimate_needs_fewer_evaluations() {
    let dir = tempfile::tempdir().unwrap();
    let problem = common::problem_path("cv2d");
    let p = problem.to_str().unwrap();
    let run = |extra: &[&str]| -> serde_json::Value {
        let out = dir.path().join("t.toml");
        let mut args = vec!["tune", p, "--json", "--out", out.to_str().unwrap()];
        args.extend_from_slice(extra);
        let (code, stdout, err) = common::autotune(&args);
        assert_eq!(code, Some(0), "{err}");
        let v: serde_json::Value = serde_json::from_str(&stdout).unwrap();
        v.get("result").cloned().unwrap_or(v)
    };
    let default = run(&[]);
    let mc_default = run(&["--scoring", "monte_carlo"]);
    for (method, default, scoring) in [
        ("ml", &default, "exact"),
        ("als", &default, "exact"),
        ("ml", &mc_default, "monte_carlo"),
    ] {
        let init = run(&["--init", method, "--scoring", scoring]);
        let (e0, e1) = (
            default["evaluations"].as_u64().unwrap(),
            init["evaluations"].as_u64().unwrap(),
        );
        let fewer = match scoring {
            "exact" => e1 * 2 < e0,
            _ => e1 < e0,
        };
        assert!(fewer, "{method}, {scoring}: {e1} evaluations against {e0}");
        for (a, b) in default["tuned"]
            .as_array()
            .unwrap()
            .iter()
            .zip(init["tuned"].as_array().unwrap())
        {
            let (a, b) = (a.as_f64().unwrap(), b.as_f64().unwrap());
            // Exact scoring converges to rounding from either start. Under Monte Carlo
            // scoring the search stops at its noise floor and the refinement skips moves
            // below a quarter of the gate's standard deviation, so two starts agree to that
            // resolution: 3e-4 measured, against a Monte Carlo spread of the tuned value of
            // several percent.
            let tol = if scoring == "exact" { 1e-4 } else { 1e-3 };
            assert!((a / b - 1.0).abs() < tol, "{method}, {scoring}: {a} vs {b}");
        }
    }
}

/// Bad measurement records: one line naming the file and the row or field, exit 2.
#[test]
fn bad_records_are_one_line_errors() {
    let dir = tempfile::tempdir().unwrap();
    let problem = common::problem_path("cv2d");
    let p = problem.to_str().unwrap();
    let cases: &[(&str, &str, &[&str], &str)] = &[
        (
            "cells.csv",
            "run,step,z_1,z_2\n0,1,1.0,2.0\n0,2,1.0\n",
            &[],
            "cells.csv:3: 3 cells where the header has 4",
        ),
        (
            "inf.csv",
            "run,step,z_1,z_2\n0,1,1.0,inf\n",
            &[],
            "inf.csv:2: z_2: not finite",
        ),
        (
            "word.csv",
            "run,step,z_1,z_2\n0,1,1.0,abc\n",
            &[],
            "word.csv:2: z_2: 'abc' is not a number",
        ),
        (
            "gap.csv",
            "run,step,z_1,z_2\n0,1,1.0,2.0\n0,3,1.0,2.0\n",
            &[],
            "gap.csv:3: step",
        ),
        (
            "dim.csv",
            "run,step,z_1\n0,1,1.0\n",
            &[],
            "dim.csv: z: 1 components per step, but cv2d measures 2",
        ),
        (
            "null.jsonl",
            "{\"run\": 0, \"step\": 1, \"z\": [1.0, \"x\"]}\n",
            &[],
            "null.jsonl:1: z: not a number or null",
        ),
        (
            "short.csv",
            "run,step,z_1,z_2\n0,1,1.0,2.0\n0,2,1.5,2.5\n",
            &["--method", "als"],
            "short.csv: the record is too short",
        ),
        (
            "gaps_als.csv",
            "run,step,z_1,z_2\n0,1,1.0,\n0,2,1.5,2.5\n",
            &["--method", "als"],
            "every component measured",
        ),
        (
            "empty.csv",
            "run,step,z_1,z_2\n",
            &[],
            "empty.csv: no measurements",
        ),
    ];
    for (name, text, extra, want) in cases {
        let f = dir.path().join(name);
        std::fs::write(&f, text).unwrap();
        let mut args = vec!["estimate", p, "--measurements", f.to_str().unwrap()];
        args.extend_from_slice(extra);
        let (code, out, err) = common::autotune(&args);
        assert_eq!(code, Some(2), "{name}: {out}{err}");
        assert_eq!(err.lines().count(), 1, "{name}: {err}");
        assert!(err.contains(want), "{name}: {err}");
    }
}

/// Without the `sdp` feature, `--full` says what the build lacks and how to get it.
#[cfg(not(feature = "sdp"))]
#[test]
fn full_matrices_need_the_sdp_feature() {
    let dir = tempfile::tempdir().unwrap();
    let rec = dir.path().join("rec.csv");
    let problem = common::problem_path("cv2d");
    let problem = problem.to_str().unwrap();
    let (code, _, err) = common::autotune(&[
        "simulate",
        problem,
        "--out",
        rec.to_str().unwrap(),
        "--steps",
        "500",
    ]);
    assert_eq!(code, Some(0), "{err}");
    let (code, _, err) = common::autotune(&[
        "estimate",
        problem,
        "--measurements",
        rec.to_str().unwrap(),
        "--method",
        "als",
        "--full",
        "qr",
    ]);
    assert_eq!(code, Some(2), "{err}");
    assert!(
        err.contains("--full") && err.contains("--features sdp"),
        "{err}"
    );
    assert_eq!(err.trim().lines().count(), 1, "{err}");
}

/// Every parameter fixed: ALS has nothing to estimate and says so (exit 2), where the
/// solver would otherwise be handed an empty problem.
#[test]
fn als_with_every_parameter_fixed_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let text = std::fs::read_to_string(common::problem_path("cv2d"))
        .unwrap()
        .replace("unit = \"m²\"", "unit = \"m²\"\nfixed = true")
        .replace("unit = \"(m/s²)²\"", "unit = \"(m/s²)²\"\nfixed = true");
    let problem = dir.path().join("fixed.toml");
    std::fs::write(&problem, text).unwrap();
    let rec = dir.path().join("rec.csv");
    let p = problem.to_str().unwrap();
    let (code, _, err) = common::autotune(&["simulate", p, "--out", rec.to_str().unwrap()]);
    assert_eq!(code, Some(0), "{err}");
    let (code, _, err) = common::autotune(&[
        "estimate",
        p,
        "--measurements",
        rec.to_str().unwrap(),
        "--method",
        "als",
    ]);
    assert_eq!(code, Some(2), "{err}");
    assert!(err.contains("every parameter is fixed"), "{err}");
    assert_eq!(err.trim().lines().count(), 1, "{err}");
}

/// `check PROBLEM --measurements FILE`: the filter judged on a record by its innovations.
/// On ten 5 000-step cv2d records the truth's values pass and the file's start fails; the
/// HTML report plots one record as blocks of 50 steps, each against its own χ²(100)/50
/// interval, and over the 1 000 blocks about 5% fall outside (binomial: 50 expected, the
/// test allows 30–72, three standard deviations; measured 57). An interval of the per-step
/// χ²(2) would put far fewer outside, one of χ²(2)/2 scaled wrongly far more.
#[test]
fn check_on_a_record_judges_by_innovations_and_plots_blocks() {
    let dir = tempfile::tempdir().unwrap();
    let problem = common::problem_path("cv2d");
    let p = problem.to_str().unwrap();
    let truth = common::problem_path("cv2d")
        .parent()
        .unwrap()
        .parent()
        .unwrap()
        .join("tuned/cv2d.toml");
    let rec = dir.path().join("rec.csv");
    let report = dir.path().join("report");
    let (mut passed, mut outside) = (0, 0);
    for seed in 1..=10 {
        let (code, _, err) = common::autotune(&[
            "simulate",
            p,
            "--out",
            rec.to_str().unwrap(),
            "--steps",
            "5000",
            "--seed",
            &seed.to_string(),
            // The record of the previous seed, replaced: a record carries no mark.
            "--force",
        ]);
        assert_eq!(code, Some(0), "{err}");
        let (code, _, err) = common::autotune(&[
            "check",
            p,
            "--measurements",
            rec.to_str().unwrap(),
            "--config",
            truth.to_str().unwrap(),
            "--report",
            report.to_str().unwrap(),
            "--quiet",
        ]);
        assert!(matches!(code, Some(0 | 1)), "{err}");
        passed += usize::from(code == Some(0));
        let html = std::fs::read_to_string(report.join("report.html")).unwrap();
        assert!(html.contains("blocks of 50 steps"), "seed {seed}");
        let n: usize = html
            .split("outside the interval (")
            .nth(1)
            .and_then(|s| s.split(')').next())
            .and_then(|s| s.parse().ok())
            .expect("the plot's legend counts the blocks outside");
        outside += n;
        let (code, _, err) = common::autotune(&[
            "check",
            p,
            "--measurements",
            rec.to_str().unwrap(),
            "--quiet",
        ]);
        assert_eq!(code, Some(1), "seed {seed}: the start should fail: {err}");
    }
    // A consistent filter passes each record with probability ≥ 0.95: at least 8 of 10
    // with probability 0.99.
    assert!(passed >= 8, "{passed} of 10 records pass at the truth");
    assert!(
        (30..=72).contains(&outside),
        "{outside} of 1000 blocks outside"
    );
}
