//! Issue 21, items 9–12: ML estimates that say "converged" only when they are,
//! identifiability per parameter, `tune --measurements` that agrees with `estimate`, and
//! records `estimate` and `simulate` refuse.

use crate::common;
use autotune::Structure;

use std::path::PathBuf;

use autotune::internals::estimate::{ml, simulate};
use autotune::internals::experiment::{Experiment, LinearExperiment};
use autotune::internals::problem::Problem;

fn data_problem(name: &str) -> (PathBuf, Problem, LinearExperiment) {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data")
        .join(name);
    let p = Problem::load(&path).expect("loads");
    let lin = p.linear().expect("linear").clone();
    (path, p, lin)
}

/// Item 9: from a start far below the truth (every parameter 0.01), L-BFGS alone stopped
/// 17–320 nats short of the maximum on 22 of 50 records and said "converged". Now every
/// one of 25 seeded records is checked converged, and a fresh search started from the
/// estimate finds nothing better than 1e-6 nats. (Fails on ec9f763: seeds 0, 4, 5, 8, 9,
/// 11, 12, 13, 14, 17, 19, 21 stop short.)
#[test]
fn issue21_ml_converged_means_a_restart_gains_nothing() {
    let (_, p, lin) = data_problem("fullq2_issue21.toml");
    let build = |t: &[f64]| lin.filter_at(t);
    let start = p.params().values();
    assert!(start.iter().all(|&v| v == 0.01));
    let fixed = vec![false; start.len()];
    let mut reached = 0;
    for seed in 0..25 {
        let sim = simulate(&lin.truth, 2, 1, 1001, seed);
        let est = ml::estimate(&build, &sim.measurements, &start, &fixed, 200).unwrap();
        let again = ml::estimate(&build, &sim.measurements, &est.theta, &fixed, 200).unwrap();
        let gap = est.neg_log_likelihood - again.neg_log_likelihood;
        eprintln!(
            "seed {seed}: gap {gap:.2e} nats, converged {}, predicted {:.1e}, {} restarts, {} Newton",
            est.converged, est.predicted_improvement, est.restarts, est.newton_steps
        );
        assert!(
            est.converged || gap > 1e-6,
            "seed {seed}: not converged but nothing left"
        );
        if est.converged && gap <= 1e-6 {
            reached += 1;
        }
    }
    assert_eq!(reached, 25, "{reached} of 25 records at the maximum");
}

/// Item 9: a search stopped by its iteration limit says so, in text and JSON, with the
/// gradient and the improvement still predicted. (Fails on ec9f763: "converged" was
/// "stopped before the limit", and the text had neither.) The Newton steps after L-BFGS may
/// still reach the maximum from where the limit stops it (from 1 or 2 iterations they do on
/// this record, and "converged" is then true); from 3 they leave r_a stuck near zero.
#[test]
fn issue21_estimate_reports_not_converged_with_gradient() {
    let (path, _, _) = data_problem("fullq2_issue21.toml");
    let dir = tempfile::tempdir().unwrap();
    let rec = dir.path().join("rec.csv");
    let p = path.to_str().unwrap();
    let r = rec.to_str().unwrap();
    let (code, _, err) = common::autotune(&["simulate", p, "--out", r, "--seed", "4"]);
    assert_eq!(code, Some(0), "{err}");
    let (code, out, err) =
        common::autotune(&["estimate", p, "--measurements", r, "--max-iterations", "3"]);
    assert_eq!(code, Some(0), "{err}");
    assert!(
        out.contains("not converged")
            && out.contains("gradient in log θ")
            && out.contains("iteration limit reached"),
        "{out}"
    );
    let (code, out, err) = common::autotune(&[
        "estimate",
        p,
        "--measurements",
        r,
        "--max-iterations",
        "3",
        "--json",
    ]);
    assert_eq!(code, Some(0), "{err}");
    let j: serde_json::Value = serde_json::from_str(&out).unwrap();
    assert_eq!(j["estimate"]["converged"], false, "{out}");
    assert_eq!(j["estimate"]["gradient"].as_array().map(Vec::len), Some(5));
    let (code, out, err) = common::autotune(&["estimate", p, "--measurements", r]);
    assert_eq!(code, Some(0), "{err}");
    assert!(out.contains("converged: the quadratic model"), "{out}");
}

/// Item 10: with q_ab truly zero, records whose maximum puts it at zero report it "at
/// bound (0)", and the other four keep standard errors from the reduced information:
/// 2 000 steps give relative errors of some 5–20%, so the band is 2–40%, and each
/// estimate is within 4 of its own standard errors of the truth (|z| ≤ 4 for 4 × the
/// at-bound records: a false failure has probability below 0.3%). (Fails on ec9f763:
/// every parameter came out "not identified".)
#[test]
fn issue21_a_parameter_at_zero_leaves_the_others_identified() {
    let (_, p, lin) = data_problem("diagq2_issue21.toml");
    let build = |t: &[f64]| lin.filter_at(t);
    let start = p.params().values();
    let fixed = vec![false; start.len()];
    let names = p.params().names();
    let ab = names.iter().position(|n| *n == "q_ab").unwrap();
    // q_a, q_b, q_ab, r_a, r_b in the file's (alphabetical) parameter order.
    let truth: Vec<f64> = names
        .iter()
        .map(|n| match *n {
            "q_a" => 2.0,
            "q_b" => 1.0,
            "q_ab" => 0.0,
            "r_a" => 3.0,
            "r_b" => 2.0,
            _ => unreachable!(),
        })
        .collect();
    let mut at_bound = 0;
    for seed in 0..6 {
        let sim = simulate(&lin.truth, 2, 1, 2000, 700 + seed);
        let est = ml::estimate(&build, &sim.measurements, &start, &fixed, 200).unwrap();
        eprintln!(
            "seed {seed}: {:?} se {:?} at bound {:?} not identified {:?} converged {}",
            est.theta, est.std_errors, est.at_bound, est.not_identified, est.converged
        );
        if est.at_bound != vec![ab] {
            continue;
        }
        at_bound += 1;
        assert!(est.not_identified.is_empty(), "seed {seed}");
        assert!(est.std_errors[ab].is_none());
        for i in (0..names.len()).filter(|&i| i != ab) {
            let se = est.std_errors[i].expect("identified");
            let rel = se / est.theta[i];
            assert!(
                (0.02..0.40).contains(&rel),
                "seed {seed} {}: {rel}",
                names[i]
            );
            let z = (est.theta[i] - truth[i]) / se;
            assert!(z.abs() <= 4.0, "seed {seed} {}: z {z}", names[i]);
        }
    }
    assert!(
        at_bound >= 2,
        "q_ab at its bound on {at_bound} of 6 records"
    );
}

/// Item 12: a record with no measured value, or a single step, is refused with exit 2 and
/// a one-line error naming the file, and --out is not written. (Fails on ec9f763: exit 0,
/// and --out held the start values.)
#[test]
fn issue21_estimate_refuses_empty_and_one_step_records() {
    let (path, _, _) = data_problem("fullq2_issue21.toml");
    let p = path.to_str().unwrap();
    let dir = tempfile::tempdir().unwrap();
    let empty = dir.path().join("empty.csv");
    std::fs::write(&empty, "step,z_1,z_2\n1,,\n2,,\n3,,\n").unwrap();
    let one = dir.path().join("one.csv");
    std::fs::write(&one, "step,z_1,z_2\n1,1.5,-0.5\n").unwrap();
    let out = dir.path().join("est.toml");
    for rec in [&empty, &one] {
        for method in ["ml", "als"] {
            let (code, stdout, err) = common::autotune(&[
                "estimate",
                p,
                "--measurements",
                rec.to_str().unwrap(),
                "--method",
                method,
                "--out",
                out.to_str().unwrap(),
            ]);
            assert_eq!(code, Some(2), "{method} {}: {stdout}{err}", rec.display());
            assert_eq!(err.trim().lines().count(), 1, "{err}");
            assert!(
                err.contains(rec.file_name().unwrap().to_str().unwrap()),
                "{err}"
            );
            assert!(!out.exists());
        }
    }
}

/// Item 12: `simulate --out X --truth X` (or ./X, or dir/../X) is refused before anything
/// is written: X keeps what it held, or stays absent. (Fails on ec9f763: exit 2, but X
/// held the states.)
#[test]
fn issue21_simulate_refuses_the_same_file_twice() {
    let (path, _, _) = data_problem("fullq2_issue21.toml");
    let p = path.to_str().unwrap();
    let dir = tempfile::tempdir().unwrap();
    std::fs::create_dir(dir.path().join("sub")).unwrap();
    let x = dir.path().join("x.csv");
    let spellings = [
        x.to_str().unwrap().to_string(),
        format!("{}/./x.csv", dir.path().display()),
        format!("{}/sub/../x.csv", dir.path().display()),
    ];
    for existing in [false, true] {
        if existing {
            std::fs::write(&x, "keep me\n").unwrap();
        }
        for other in &spellings {
            let (code, stdout, err) = common::autotune(&[
                "simulate",
                p,
                "--out",
                x.to_str().unwrap(),
                "--truth",
                other,
                "--steps",
                "10",
                // Past the refusal of an existing record without autotune's mark.
                "--force",
            ]);
            assert_eq!(code, Some(2), "{other}: {stdout}{err}");
            assert!(err.contains("--truth"), "{err}");
            if existing {
                assert_eq!(std::fs::read_to_string(&x).unwrap(), "keep me\n");
            } else {
                assert!(!x.exists(), "{other}");
            }
        }
    }
    // Relative to the working directory: x.csv and ./x.csv.
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_autotune"))
        .current_dir(dir.path())
        .args([
            "simulate", p, "--out", "y.csv", "--truth", "./y.csv", "--steps", "10",
        ])
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(2));
    assert!(!dir.path().join("y.csv").exists());
}

/// Item 11: on one record of a 3-state system (dcmotor, 2 000 steps), `tune
/// --measurements` starts at the ML estimate and keeps its start when the search ends no
/// better: wherever the ML estimate passes `check --measurements`, the tune passes too
/// and never says "no value of the free parameters"; and each tuned value stays within 4
/// standard errors of the ML estimate in log θ (the NIS objective is flat where the
/// likelihood is, so the two need not coincide; measured |z| ≤ 2.8 over seeds 1–6). (Fails
/// on ec9f763: the search from the problem's values exited 1 "no value … fits" on every
/// one of these records, with q_voltage ×370–1700 the ML estimate.)
#[test]
fn issue21_tune_on_a_record_agrees_with_estimate() {
    let problem = common::problem_path("dcmotor");
    let p = problem.to_str().unwrap();
    let dir = tempfile::tempdir().unwrap();
    let mut ml_passes = 0;
    for seed in 1..=6 {
        let rec = dir.path().join(format!("d{seed}.csv"));
        let est = dir.path().join(format!("e{seed}.toml"));
        let tuned = dir.path().join(format!("t{seed}.toml"));
        let r = rec.to_str().unwrap();
        let seed_s = seed.to_string();
        let (code, _, err) = common::autotune(&[
            "simulate", p, "--out", r, "--steps", "2000", "--seed", &seed_s,
        ]);
        assert_eq!(code, Some(0), "{err}");
        let (code, out, err) = common::autotune(&[
            "estimate",
            p,
            "--measurements",
            r,
            "--json",
            "--out",
            est.to_str().unwrap(),
        ]);
        assert_eq!(code, Some(0), "{err}");
        let j: serde_json::Value = serde_json::from_str(&out).unwrap();
        let theta: Vec<f64> = j["estimate"]["theta"]
            .as_array()
            .unwrap()
            .iter()
            .map(|v| v.as_f64().unwrap())
            .collect();
        let se: Vec<f64> = j["estimate"]["std_errors"]
            .as_array()
            .unwrap()
            .iter()
            .map(|v| v.as_f64().unwrap_or(f64::INFINITY))
            .collect();
        let names: Vec<String> = j["params"]
            .as_array()
            .unwrap()
            .iter()
            .map(|v| v.as_str().unwrap().to_string())
            .collect();
        let (check, _, _) = common::autotune(&[
            "check",
            p,
            "--measurements",
            r,
            "--config",
            est.to_str().unwrap(),
        ]);
        let (code, out, err) = common::autotune(&[
            "tune",
            p,
            "--measurements",
            r,
            "--out",
            tuned.to_str().unwrap(),
        ]);
        assert!(err.contains("start: ml estimate"), "{err}");
        if check == Some(0) {
            ml_passes += 1;
            assert_eq!(
                code,
                Some(0),
                "seed {seed}: ML passes, tune does not\n{out}{err}"
            );
        }
        assert!(
            check != Some(0) || !out.contains("no value of the free parameters"),
            "seed {seed}: {out}"
        );
        let t: toml::Table = std::fs::read_to_string(&tuned).unwrap().parse().unwrap();
        for (i, name) in names.iter().enumerate() {
            let v = t["params"][name.as_str()].as_float().unwrap();
            // In log θ, where the information is computed and a variance's likelihood is
            // nearly symmetric: se / θ is the standard error of log θ.
            let z = (v / theta[i]).ln() / (se[i] / theta[i]);
            eprintln!(
                "seed {seed} {name}: tuned {v:.4e} ml {:.4e} z {z:.2}",
                theta[i]
            );
            assert!(
                z.abs() <= 4.0,
                "seed {seed} {name}: tuned {v} vs ML {} ± {}",
                theta[i],
                se[i]
            );
        }
    }
    assert!(
        ml_passes >= 4,
        "the ML estimate passed on {ml_passes} of 6 records"
    );
}

/// A likelihood defined on one side of a bound only (the filter fails past θ = 1), searched
/// from the bound itself: the gradient there is one-sided rather than infinite, so the line
/// search ends, and the search finds the maximum inside (θ = 0.5). (With an infinite
/// gradient the Armijo line search never met its condition.)
#[test]
fn a_search_from_a_failure_boundary_ends() {
    let nll = |t: &[f64]| (t[0] <= 1.0).then(|| 100.0 * (t[0] - 0.5).powi(2));
    let est = ml::estimate_by(&nll, 1, &[1.0], &[false], 100).expect("the search runs");
    assert!((est.theta[0] - 0.5).abs() < 1e-3, "{est:?}");
}
