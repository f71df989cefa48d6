//! A Rust user's own model gets the whole command line from one call
//! (`autotune::app::run_for`, what `main_for` runs on the process's arguments), and it
//! writes the same tuned config, report.html/md/json, advice, JSON and JUnit as the problem
//! file that describes the same truth and filter (issue #10, point 7).
//!
//! The model is the catalog's CTRV target with a lidar and a radar, assembled in Rust from
//! its public parts (truth, fixed-size UKF, parameter definitions written out here) through
//! `RustModel::builder`; the problem file is `problems/ctrv.toml`. Both run the same generic
//! engine on the same draws, so everything but the source's name and hash must match to
//! the bit. The search is cut short (20 runs × 60 steps, 12 evaluations) because equality,
//! not the quality of the tuning, is under test.

use autotune::{HeldAsCode, Structure};
use std::path::{Path, PathBuf};
use std::process::ExitCode;

use autotune::internals::catalog::ModelContext;
use autotune::internals::catalog::ctrv::{CtrvModel, ENTRY};
use autotune::internals::experiment::{Experiment, RustModel};
use autotune::internals::params::{NoiseKind, ParamDef, Target};
use autotune::internals::problem::Problem;

const RUNS: &str = "20";
const STEPS: &str = "60";

/// The shipped problem with a search small enough for a test.
fn problem_file(dir: &Path) -> PathBuf {
    let text = include_str!("../../problems/ctrv.toml");
    let mut table: toml::Table = text.parse().unwrap();
    let tune = table["tune"].as_table_mut().unwrap();
    tune.insert("search_runs".into(), 20.into());
    tune.insert("max_evals".into(), 12.into());
    tune.insert("global_points".into(), 2.into());
    let path = dir.join("ctrv.toml");
    std::fs::write(&path, toml::to_string(&table).unwrap()).unwrap();
    path
}

/// The same truth and filter, defined in Rust as a user would.
fn rust_model(problem: &Problem) -> impl Experiment + use<> {
    let text = include_str!("../../problems/ctrv.toml");
    let table: toml::Table = text.parse().unwrap();
    let mut model_table = table["model"].as_table().unwrap().clone();
    model_table.remove("name");
    let ctx = ModelContext {
        dt: 0.1,
        steps: 250,
    };
    let model = CtrvModel::from_table(&model_table, &ctx).unwrap();
    let truth = model.truth.clone();
    let names = {
        use autotune::internals::catalog::CatalogModel;
        (model.state_names(), model.measurement_names())
    };
    let q = |name: &str, value: f64, lower: f64, upper: f64, unit: &str, about: &str| {
        ParamDef::new(name, value)
            .bounds(lower, upper)
            .unit(unit)
            .about(about)
    };
    let r = |name: &str, value: f64, unit: &str, about: &str| {
        q(name, value, value / 1e4, value * 1e4, unit, about).fixed()
    };
    let built = RustModel::builder("ctrv", truth, move |theta: &[f64]| model.ukf(theta))
        .description(&problem.info().description)
        .program("ctrv_rust")
        .states(names.0)
        .measurements(names.1)
        .param(
            q(
                "q_accel",
                0.05,
                1e-3,
                100.0,
                "(m/s²)²",
                "variance of the longitudinal acceleration, held over each filter step",
            ),
            Target::process(&[2]),
        )
        .param(
            q(
                "q_yaw_accel",
                0.01,
                1e-4,
                10.0,
                "(rad/s²)²",
                "variance of the yaw acceleration, held over each filter step",
            ),
            Target::process(&[3, 4]),
        )
        .param(
            r(
                "r_lidar",
                0.0225,
                "m²",
                "lidar position variance per axis (datasheet: 0.15 m)",
            ),
            Target::measurement(&[0, 1]),
        )
        .param(
            r(
                "r_radar_range",
                0.09,
                "m²",
                "radar range variance (datasheet: 0.3 m)",
            ),
            Target::measurement(&[2]),
        )
        .param(
            r(
                "r_radar_bearing",
                0.0009,
                "rad²",
                "radar bearing variance (datasheet: 0.03 rad)",
            ),
            Target::measurement(&[3]),
        )
        .param(
            r(
                "r_radar_rate",
                0.09,
                "(m/s)²",
                "radar range-rate variance (datasheet: 0.3 m/s)",
            ),
            Target::measurement(&[4]),
        )
        .montecarlo(*problem.mc())
        .replayable()
        .build()
        .unwrap();
    // The targets written out above are the catalog entry's.
    for (i, info) in ENTRY.params.iter().enumerate() {
        let t = built.target(i).unwrap();
        assert_eq!(
            (t.kind, t.components.as_slice()),
            (info.noise, info.components)
        );
    }
    assert_eq!(built.params(), problem.params());
    assert!(matches!(ENTRY.params[0].noise, NoiseKind::Process));
    built
}

fn ok(code: Result<ExitCode, autotune::app::AppError>) -> ExitCode {
    code.unwrap_or_else(|e| panic!("{e}"))
}

/// A TOML or JSON text with the fields that name the source removed.
fn without_source(json: &str) -> serde_json::Value {
    let mut v: serde_json::Value = serde_json::from_str(json).unwrap();
    let o = v.as_object_mut().unwrap();
    assert!(o.remove("file").is_some() && o.remove("problem_hash").is_some());
    if let Some(r) = o.get_mut("result") {
        r.as_object_mut().unwrap().remove("seconds");
    }
    v
}

/// Report text with the source's label replaced.
fn unlabelled(text: &str, labels: &[&str]) -> String {
    let mut t = text.to_string();
    for l in labels {
        t = t.replace(l, "SOURCE");
    }
    t.lines()
        // The markdown's lines with the run's duration and with the file and its hash.
        .filter(|l| {
            !l.starts_with("- scoring:")
                && !l.starts_with("Problem file")
                && !l.starts_with("Model `")
        })
        .collect::<Vec<_>>()
        .join("\n")
}

#[test]
fn a_rust_model_through_the_one_call_cli_writes_what_a_problem_file_does() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let file = problem_file(d);
    let problem = Problem::load(&file).unwrap();
    let model = rust_model(&problem);
    let s = |p: PathBuf| p.to_string_lossy().into_owned();

    let file_run = autotune::app::run([
        "autotune",
        "tune",
        &s(file.clone()),
        "--runs",
        RUNS,
        "--steps",
        STEPS,
        "--quiet",
        "--out",
        &s(d.join("a.toml")),
        "--report",
        &s(d.join("a")),
    ]);
    let rust_run = autotune::app::run_for(
        &model,
        &problem.tune,
        [
            "ctrv_rust",
            "tune",
            "--runs",
            RUNS,
            "--steps",
            STEPS,
            "--quiet",
            "--out",
            &s(d.join("b.toml")),
            "--report",
            &s(d.join("b")),
        ],
    );
    assert_eq!(ok(file_run), ok(rust_run));

    let read = |name: &str| std::fs::read_to_string(d.join(name)).unwrap();
    // The tuned configs: the same values, and the same provenance but for the source.
    let config = |name: &str| {
        let mut t: toml::Table = read(name).parse().unwrap();
        let prov = t["provenance"].as_table_mut().unwrap();
        prov.remove("problem_file");
        prov.remove("problem_sha256");
        t
    };
    assert_eq!(config("a.toml"), config("b.toml"));
    assert!(read("b.toml").contains("# Check it with: ctrv_rust check --config <this file>"));

    let labels = [file.to_str().unwrap(), "ctrv_rust (Rust model)"];
    assert_eq!(
        without_source(&read("a/report.json")),
        without_source(&read("b/report.json")),
        "report.json (parameters, statistics, advice)"
    );
    for name in ["report.md", "report.html"] {
        assert_eq!(
            unlabelled(&read(&format!("a/{name}")), &labels),
            unlabelled(&read(&format!("b/{name}")), &labels),
            "{name}"
        );
    }
    let advice: serde_json::Value = serde_json::from_str(&read("b/report.json")).unwrap();
    assert_eq!(advice["recommendations"].as_array().unwrap().len(), 6);

    // check --config on each side's tuned config: the same JSON and JUnit.
    let check = |args: &[&str]| {
        let json = d.join(format!("{}.junit.xml", args[0]));
        let mut v: Vec<String> = args.iter().map(|a| a.to_string()).collect();
        v.extend(["--runs", RUNS, "--steps", STEPS, "--quiet", "--junit"].map(String::from));
        v.push(s(json.clone()));
        v.extend([
            "--report".to_string(),
            s(d.join(format!("check-{}", args[0]))),
        ]);
        (v, json)
    };
    let (a_args, a_junit) = check(&[
        "autotune",
        "check",
        file.to_str().unwrap(),
        "--config",
        d.join("a.toml").to_str().unwrap(),
    ]);
    let (b_args, b_junit) = check(&[
        "ctrv_rust",
        "check",
        "--config",
        d.join("b.toml").to_str().unwrap(),
    ]);
    let a_code = ok(autotune::app::run(a_args));
    let b_code = ok(autotune::app::run_for(&model, &problem.tune, b_args));
    assert_eq!(a_code, b_code);
    assert_eq!(
        std::fs::read_to_string(a_junit).unwrap(),
        std::fs::read_to_string(b_junit).unwrap()
    );
    assert_eq!(
        without_source(&read("check-autotune/report.json")),
        without_source(&read("check-ctrv_rust/report.json"))
    );
}

#[test]
fn the_one_call_cli_refuses_bad_options_by_flag() {
    let problem = Problem::load(Path::new(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/problems/ctrv.toml"
    )))
    .unwrap();
    let model = rust_model(&problem);
    let run = |args: &[&str]| autotune::app::run_for(&model, &problem.tune, args.iter().copied());
    let err = |args: &[&str]| run(args).unwrap_err().to_string();
    assert_eq!(err(&["m", "check", "--runs", "0"]), "--runs: 0 must be ≥ 1");
    assert_eq!(
        err(&["m", "check", "--set", "q_jerk=1"]),
        "--set: unknown parameter 'q_jerk' (known: q_accel, q_yaw_accel, r_lidar, r_radar_range, r_radar_bearing, r_radar_rate)"
    );
    assert!(
        err(&["m", "check", "--engine", "linear"])
            .starts_with("--engine linear: ctrv_rust (Rust model) has no linear fast path")
    );
    assert!(
        err(&["m", "tune", "--scoring", "exact"]).starts_with("--scoring: exact scoring needs")
    );
    assert!(err(&["m", "frobnicate"]).contains("(see 'ctrv_rust --help')"));
}

/// A Rust model made `replayable` runs over a recording as the catalog model it copies
/// does: over a 300-step ctrv record (alternating lidar and radar), the same `−log L` to the
/// bit at three θ, and the same maximum-likelihood estimate.
#[test]
fn a_replayable_rust_model_runs_over_a_recording_as_the_catalog_model_does() {
    use autotune::internals::estimate::{FilterReplay, ml, simulate_sensors};
    let dir = tempfile::tempdir().unwrap();
    let problem = Problem::load(&problem_file(dir.path())).unwrap();
    let model = rust_model(&problem);
    let start = problem.params().values();
    let dims = model
        .replay_filter(&start)
        .expect("replayable")
        .sensor_dims();
    let truth = model.simulation_truth().expect("the model's truth");
    let data = simulate_sensors(truth, &dims, 1, 300, 9).measurements;
    let ours = FilterReplay::new(&model, data.clone()).expect("the record fits");
    let catalog = FilterReplay::new(&problem, data).expect("the record fits");
    for f in [1.0, 10.0, 0.3] {
        let theta: Vec<f64> = start.iter().map(|v| v * f).collect();
        assert_eq!(
            ours.neg_log_likelihood(&theta).unwrap().to_bits(),
            catalog.neg_log_likelihood(&theta).unwrap().to_bits(),
            "θ × {f}"
        );
    }
    let fixed: Vec<bool> = problem.params().params.iter().map(|d| d.fixed).collect();
    let values = ours.data().values();
    let by = |r: &FilterReplay<'_>| {
        let nll = |t: &[f64]| r.neg_log_likelihood(t).ok();
        ml::estimate_by(&nll, values, &start, &fixed, 200).unwrap()
    };
    let (a, b) = (by(&ours), by(&catalog));
    assert!(a.converged);
    assert_eq!(a.theta, b.theta);
}
