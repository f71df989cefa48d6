//! `autotune tune` from the command line: outputs, words, errors.

use crate::common;

use assert_cmd::Command;
use common::problem_path;

fn autotune() -> Command {
    Command::cargo_bin("autotune").unwrap()
}

#[test]
fn cv2d_report_says_which_axis_and_by_what_factor() {
    // The shipped cv2d start copies one guess to both axes: x's acceleration noise is too
    // small (truth 0.5, start 0.2) and y's too large (truth 0.1, start 0.2); the x sensor is
    // better than believed (1 vs 2 m²) and the y sensor worse (4 vs 2 m²).
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("cv2d.toml");
    let rep = dir.path().join("report");
    let assert = autotune()
        .arg("tune")
        .arg(problem_path("cv2d"))
        .arg("--out")
        .arg(&out)
        .arg("--report")
        .arg(&rep)
        .assert()
        .code(0);
    let stdout = String::from_utf8(assert.get_output().stdout.clone()).unwrap();
    let md = std::fs::read_to_string(rep.join("report.md")).unwrap();
    for text in [&stdout, &md] {
        assert!(text.contains("q_accel_x: x, vx (e²/P = "), "{text}");
        // The label is what the starting filter's numbers say; the action is the change.
        assert!(
            text.contains("mixed at the start; increase ×2.50"),
            "{text}"
        );
        assert!(text.contains("q_accel_y: y, vy"), "{text}");
        assert!(
            text.contains("overconfident at the start; decrease ×0.50 (÷2.00)"),
            "{text}"
        );
        assert!(text.contains("r_pos_x: x (ν²/S = "), "{text}");
        assert!(
            text.contains("underconfident at the start; decrease ×0.50"),
            "{text}"
        );
        assert!(text.contains("r_pos_y: y (ν²/S = "), "{text}");
        assert!(
            text.contains("overconfident at the start; increase ×2.00"),
            "{text}"
        );
        assert!(
            text.contains("20 of 20 fresh seeds pass the gate"),
            "{text}"
        );
    }
    assert!(
        md.contains("Verdict before: mixed. After (first fresh seed): consistent."),
        "{md}"
    );
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(rep.join("report.json")).unwrap()).unwrap();
    assert_eq!(json["result"]["status"], "consistent");
    assert_eq!(json["recommendations"].as_array().unwrap().len(), 4);

    // The tuned config is what `check --config` reads, with its provenance.
    let cfg = std::fs::read_to_string(&out).unwrap();
    for key in [
        "problem = \"cv2d\"",
        "[params]",
        "problem_sha256",
        "search_seed",
        "confirm_seed",
        "objective",
        "autotune_version",
        "[provenance.confirmation]",
    ] {
        assert!(cfg.contains(key), "missing {key}: {cfg}");
    }
    autotune()
        .arg("check")
        .arg(problem_path("cv2d"))
        .arg("--config")
        .arg(&out)
        .assert()
        .code(0);
}

#[test]
fn shipped_linear_tuned_configs_are_what_tune_writes_and_pass_check() {
    // The files in tuned/ are the CI gate's inputs; they must be what the current code
    // writes from the shipped problems (exact scoring: deterministic to the bit), not
    // stale files that happen to pass. The catalog ones take minutes each to regenerate;
    // tests/tuning/catalog_tune.rs tunes those problems with cheaper settings.
    let dir = tempfile::tempdir().unwrap();
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
    for name in ["cv1d", "cv2d", "dcmotor"] {
        let out = dir.path().join(format!("{name}.toml"));
        autotune()
            .current_dir(root)
            .args(["tune", &format!("problems/{name}.toml"), "--quiet", "--out"])
            .arg(&out)
            .assert()
            .code(0);
        let written = std::fs::read_to_string(&out).unwrap();
        let shipped =
            std::fs::read_to_string(root.join("tuned").join(format!("{name}.toml"))).unwrap();
        assert_eq!(
            written, shipped,
            "tuned/{name}.toml is stale: run autotune tune"
        );
        autotune()
            .arg("check")
            .arg(problem_path(name))
            .arg("--config")
            .arg(&out)
            .assert()
            .code(0);
    }
}

#[test]
fn fixing_r_and_nis_only_from_the_cli() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("t.toml");
    autotune()
        .arg("tune")
        .arg(problem_path("cv2d"))
        .args([
            "--fix",
            "r_pos_x=1",
            "--fix",
            "r_pos_y=4",
            "--quiet",
            "--out",
        ])
        .arg(&out)
        .assert()
        .code(0)
        .stdout("");
    let cfg = std::fs::read_to_string(&out).unwrap();
    assert!(
        cfg.contains("r_pos_x = 1.0\n") && cfg.contains("r_pos_y = 4.0\n"),
        "{cfg}"
    );
    autotune()
        .arg("tune")
        .arg(problem_path("cv1d"))
        .args(["--nis-only", "--quiet", "--out"])
        .arg(&out)
        .assert()
        .code(0);
    autotune()
        .arg("check")
        .arg(problem_path("cv1d"))
        .arg("--config")
        .arg(&out)
        .assert()
        .code(0);
}

#[test]
fn bad_tune_options_are_one_line_errors_with_exit_2() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("never.toml");
    let cases: &[(&[&str], &str)] = &[
        (&["--max-evals", "0"], "--max-evals"),
        (&["--max-seconds", "0"], "--max-seconds"),
        (&["--fix", "q_nothing"], "--fix"),
        (&["--weight", "colour=1"], "--weight"),
        (&["--weight", "mean=-1"], "--weight"),
        (&["--scoring", "magic"], "--scoring"),
        (&["--local", "newton"], "--local"),
        (&["--set", "q_accel_x=1e9"], "--set"),
        (&["--runs", "abc"], "--runs"),
    ];
    for (args, field) in cases {
        let a = autotune()
            .arg("tune")
            .arg(problem_path("cv2d"))
            .args(*args)
            .arg("--out")
            .arg(&out)
            .assert()
            .code(2);
        let err = String::from_utf8(a.get_output().stderr.clone()).unwrap();
        assert_eq!(err.trim_end().lines().count(), 1, "{args:?}: {err}");
        assert!(err.contains(field), "{args:?}: {err}");
        assert!(!out.exists(), "{args:?} wrote a file");
    }
    // The same errors from the problem file's [tune] name the file and the field.
    let file = dir.path().join("p.toml");
    for (line, field, says) in [
        ("max_evals = 0", "tune.max_evals", "≥ 1"),
        ("local = \"newton\"", "tune.local", "gauss_newton"),
    ] {
        let text =
            std::fs::read_to_string(problem_path("cv1d")).unwrap() + "\n[tune]\n" + line + "\n";
        std::fs::write(&file, text).unwrap();
        let a = autotune()
            .arg("tune")
            .arg(&file)
            .arg("--out")
            .arg(&out)
            .assert()
            .code(2);
        let err = String::from_utf8(a.get_output().stderr.clone()).unwrap();
        assert_eq!(err.trim_end().lines().count(), 1, "{line}: {err}");
        assert!(
            err.contains("p.toml") && err.contains(field) && err.contains(says),
            "{line}: {err}"
        );
        assert!(!out.exists(), "{line} wrote a file");
    }
}

#[test]
fn budget_exhaustion_is_a_status_not_a_panic_and_keeps_the_good_config() {
    // Regression (review of issue #3): argmin's Nelder-Mead unwrapped the refused costs.
    let dir = tempfile::tempdir().unwrap();
    for args in [
        &["--max-evals", "40"][..],
        &["--max-evals", "200"],
        &["--max-seconds", "0.01"],
    ] {
        let a = autotune()
            .current_dir(dir.path())
            .arg("tune")
            .arg(problem_path("cv2d"))
            .args(args)
            .assert();
        let out = a.get_output();
        assert!(
            matches!(out.status.code(), Some(0) | Some(1)),
            "{args:?}: {:?}",
            out.status
        );
        assert!(!String::from_utf8_lossy(&out.stderr).contains("panicked"));
    }
    // A run that fails its confirmation goes beside the config, never over it.
    let dir = tempfile::tempdir().unwrap();
    let a = autotune()
        .current_dir(dir.path())
        .arg("tune")
        .arg(problem_path("cv2d"))
        .args(["--max-evals", "40"])
        .assert()
        .code(1);
    assert!(String::from_utf8_lossy(&a.get_output().stdout).contains("stopped on its budget"));
    assert!(dir.path().join("tuned/cv2d.rejected.toml").is_file());
    assert!(!dir.path().join("tuned/cv2d.toml").exists());
}

#[test]
fn nothing_free_to_tune_is_judged_by_the_confirmation() {
    let dir = tempfile::tempdir().unwrap();
    autotune()
        .current_dir(dir.path())
        .arg("tune")
        .arg(problem_path("cv1d"))
        .args(["--fix", "q_accel=0.5", "--fix", "r_pos=1", "--quiet"])
        .assert()
        .code(0);
    let cfg = std::fs::read_to_string(dir.path().join("tuned/cv1d.toml")).unwrap();
    assert!(cfg.contains("status = \"consistent\""), "{cfg}");
}

#[test]
fn a_value_stopped_at_its_bound_is_flagged() {
    let dir = tempfile::tempdir().unwrap();
    let text = std::fs::read_to_string(problem_path("cv1d")).unwrap();
    let text = text.replace(
        "[params.q_accel]\nvalue = 0.1\n",
        "[params.q_accel]\nvalue = 0.1\nupper = 0.2\n",
    );
    assert!(text.contains("upper = 0.2"));
    let file = dir.path().join("bounded.toml");
    std::fs::write(&file, text).unwrap();
    let a = autotune()
        .current_dir(dir.path())
        .arg("tune")
        .arg(&file)
        .assert();
    let stdout = String::from_utf8_lossy(&a.get_output().stdout).to_string();
    assert!(
        stdout.contains("q_accel: stopped at its search bound"),
        "{stdout}"
    );
}

#[test]
fn unsafe_names_and_runaway_dynamics_are_input_errors() {
    let dir = tempfile::tempdir().unwrap();
    let text = std::fs::read_to_string(problem_path("cv1d")).unwrap();
    let escaped = text.replace("name = \"cv1d\"", "name = \"../../escaped\"");
    assert_ne!(escaped, text);
    let file = dir.path().join("p.toml");
    std::fs::write(&file, escaped).unwrap();
    let a = autotune()
        .current_dir(dir.path())
        .arg("tune")
        .arg(&file)
        .assert()
        .code(2);
    assert!(String::from_utf8_lossy(&a.get_output().stderr).contains("p.toml: name:"));
    let motor = std::fs::read_to_string(problem_path("dcmotor")).unwrap();
    let runaway = motor.replace("dt = 0.01", "dt = 1e6");
    assert_ne!(runaway, motor);
    std::fs::write(&file, runaway).unwrap();
    let a = autotune().arg("check").arg(&file).assert().code(2);
    assert!(String::from_utf8_lossy(&a.get_output().stderr).contains("truth.A"));
}

/// The tune says where each evaluation's truth came from (issue 25): a catalog problem's
/// truth, which the parameters do not enter, is taped and replayed; a linear problem under
/// Monte Carlo scoring simulates it with the filter in its batched engine; a record has
/// none. The line is printed under Monte Carlo scoring only (exact scoring simulates
/// nothing).
#[test]
fn the_tune_says_where_each_evaluations_truth_came_from() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("t.toml");
    let run = |args: &[&str]| -> (serde_json::Value, String) {
        let mut json_args = args.to_vec();
        json_args.extend(["--json", "--out", out.to_str().unwrap()]);
        let (code, stdout, err) = common::autotune(&json_args);
        assert!(matches!(code, Some(0) | Some(1)), "{err}");
        let v: serde_json::Value = serde_json::from_str(&stdout).unwrap();
        let mut text_args = args.to_vec();
        text_args.extend(["--out", out.to_str().unwrap()]);
        let (_, text, _) = common::autotune(&text_args);
        (v["result"].clone(), text)
    };
    let ctrv = problem_path("ctrv");
    let (r, text) = run(&["tune", ctrv.to_str().unwrap()]);
    let t = &r["truth"];
    assert_eq!(t["kind"], "taped", "{t}");
    let (replayed, simulated) = (
        t["replayed"].as_u64().unwrap(),
        t["simulated"].as_u64().unwrap(),
    );
    // Every search evaluation after the first two replays; each of the 20 confirmation
    // seeds is a fresh seed set, simulated.
    let evals = r["evaluations"].as_u64().unwrap();
    assert!(
        replayed >= evals.saturating_sub(1),
        "{t}, {evals} evaluations"
    );
    assert!(simulated >= 20, "{t}");
    assert_eq!(t["too_large"], false);
    assert!(
        text.contains(&format!(
            "  truth: replayed from tapes at {replayed} of {}",
            replayed + simulated
        )),
        "{text}"
    );

    let cv2d = problem_path("cv2d");
    let (r, text) = run(&["tune", cv2d.to_str().unwrap(), "--scoring", "monte_carlo"]);
    assert_eq!(r["truth"]["kind"], "simulated");
    assert!(
        r["truth"]["why"]
            .as_str()
            .unwrap()
            .contains("linear problem's engine")
    );
    assert!(
        text.contains("  truth: simulated at every evaluation: a linear problem's engine"),
        "{text}"
    );
    let (_, text) = run(&["tune", cv2d.to_str().unwrap()]);
    assert!(!text.contains("truth:"), "exact scoring: {text}");

    let rec = dir.path().join("rec.csv");
    let (code, _, err) = common::autotune(&[
        "simulate",
        cv2d.to_str().unwrap(),
        "--out",
        rec.to_str().unwrap(),
        "--runs",
        "5",
        "--steps",
        "200",
        "--seed",
        "4",
    ]);
    assert_eq!(code, Some(0), "{err}");
    let (r, _) = run(&[
        "tune",
        cv2d.to_str().unwrap(),
        "--measurements",
        rec.to_str().unwrap(),
    ]);
    assert_eq!(r["truth"]["kind"], "recorded");
}

/// An error about the start names the flag that asked for it (issue 37, item 13): the
/// default start from `--measurements`, not `--init`, which was not given. (ins_gnss's
/// filter predicts from IMU samples, which a record does not carry: no start on it.)
#[test]
fn an_error_about_the_start_names_the_flag_given() {
    let dir = tempfile::tempdir().unwrap();
    let z = dir.path().join("z.csv");
    std::fs::write(&z, "step,z_1,z_2,z_3\n1,0.5,0,0\n2,0.7,0,0\n").unwrap();
    let out = dir.path().join("t.toml");
    for (extra, named, not_named) in [
        (&[][..], "--measurements", "--init"),
        (&["--init", "ml"][..], "--init", "--measurements"),
    ] {
        let assert = autotune()
            .arg("tune")
            .arg(problem_path("ins_gnss"))
            .arg("--measurements")
            .arg(&z)
            .args(extra)
            .arg("--out")
            .arg(&out)
            .assert()
            .code(2);
        let stderr = String::from_utf8(assert.get_output().stderr.clone()).unwrap();
        assert_eq!(stderr.lines().count(), 1, "{stderr}");
        assert!(stderr.contains(named), "{extra:?}: {stderr}");
        assert!(!stderr.contains(not_named), "{extra:?}: {stderr}");
    }
}
