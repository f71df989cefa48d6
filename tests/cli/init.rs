//! `autotune init` (starter problem files) and `autotune completions` from the command line.

use autotune::Structure;
use std::path::Path;

use assert_cmd::Command;
use autotune::internals::experiment::Experiment;
use autotune::internals::problem::Problem;
use nalgebra::DMatrix;

fn autotune() -> Command {
    Command::cargo_bin("autotune").unwrap()
}

fn stderr_of(out: &std::process::Output) -> String {
    String::from_utf8(out.stderr.clone()).unwrap()
}

/// The models `init --model` offers, read from the CLI itself (the error for an unknown
/// model lists them), so a model added later is tested without editing this file.
fn offered_models() -> Vec<String> {
    let out = autotune()
        .args(["init", "x", "--model", "no-such-model"])
        .assert()
        .code(2);
    let err = stderr_of(out.get_output());
    assert_eq!(err.trim_end().lines().count(), 1, "{err}");
    let list = err
        .split_once("(known: ")
        .and_then(|(_, rest)| rest.split_once(')'))
        .unwrap_or_else(|| panic!("no list of known models in {err:?}"))
        .0;
    let models: Vec<String> = list.split(", ").map(str::to_string).collect();
    for m in ["cv1d", "cv2d", "dcmotor"] {
        assert!(models.iter().any(|x| x == m), "{m} not offered: {err}");
    }
    models
}

/// Largest entry of |a − b| relative to the largest entry of |b| (0 when both are zero).
fn rel_diff(a: &DMatrix<f64>, b: &DMatrix<f64>) -> f64 {
    assert_eq!(a.shape(), b.shape());
    let scale = b.amax().max(f64::MIN_POSITIVE);
    (a - b).amax() / scale
}

/// Run `init` in `dir` and return the file's text.
fn init_in(dir: &Path, args: &[&str]) -> String {
    autotune()
        .current_dir(dir)
        .arg("init")
        .args(args)
        .assert()
        .code(0);
    let name = args[0];
    std::fs::read_to_string(dir.join(format!("{name}.toml"))).unwrap()
}

#[test]
fn every_starter_passes_check_unchanged() {
    for model in offered_models() {
        let dir = tempfile::tempdir().unwrap();
        let name = "my-filter_2";
        let text = init_in(dir.path(), &[name, "--model", &model]);
        let path = dir.path().join(format!("{name}.toml"));

        // Commented, named after the argument, nothing left of the template.
        let comments = text
            .lines()
            .filter(|l| l.trim_start().starts_with('#'))
            .count();
        assert!(comments >= 20, "{model}: only {comments} comment lines");
        assert!(text.contains(&format!("name = \"{name}\"")), "{model}");
        assert!(text.contains(&format!("--model {model}")), "{model}");
        assert!(text.contains("Replace with your guess"), "{model}");
        assert!(!text.contains("{{"), "{model}: template placeholder left");

        // A valid problem whose filter, at the parameter values as written, is the truth.
        let p = Problem::load(&path).unwrap_or_else(|e| panic!("{model}: {e}"));
        assert_eq!(p.name(), name);
        let kf = p.linear().unwrap().filter_at(&p.params().values());
        let t = &p.linear().unwrap().truth;
        for (what, a, b) in [
            ("F", &kf.F, &t.F),
            ("H", &kf.H, &t.H),
            ("Q", &kf.Q, &t.Q),
            ("R", &kf.R, &t.R),
            ("P0", &kf.P0, &t.P0),
        ] {
            let d = rel_diff(a, b);
            assert!(
                d < 1e-12,
                "{model}: filter {what} differs from the truth's by {d}"
            );
        }
        assert!((&kf.x0 - &t.x0).amax() < 1e-12, "{model}: x0");

        // `autotune check` passes on the file exactly as written, with its own seed.
        let out = autotune().arg("check").arg(&path).assert().code(0);
        let stdout = String::from_utf8(out.get_output().stdout.clone()).unwrap();
        assert!(
            stdout.contains(&format!("autotune check {name}:")),
            "{stdout}"
        );
        assert!(stdout.contains("verdict: consistent"), "{stdout}");

        // The check has power on this file: every parameter ×10 (P about ten times too
        // large) is caught.
        let mut check = autotune();
        check.arg("check").arg(&path).arg("--quiet");
        for param in &p.params().params {
            check
                .arg("--set")
                .arg(format!("{}={}", param.name, param.value * 10.0));
        }
        check.assert().code(1);
    }
}

#[test]
fn default_model_is_cv2d() {
    let dir = tempfile::tempdir().unwrap();
    let default = init_in(dir.path(), &["zzdefault"]);
    let cv2d = init_in(dir.path(), &["zzexplicit", "--model", "cv2d"]);
    assert_eq!(default.replace("zzdefault", "zzexplicit"), cv2d);
}

#[test]
fn refuses_to_overwrite_without_force() {
    let dir = tempfile::tempdir().unwrap();
    let first = init_in(dir.path(), &["plant"]);
    let path = dir.path().join("plant.toml");

    let out = autotune()
        .current_dir(dir.path())
        .args(["init", "plant", "--model", "cv1d"])
        .assert()
        .code(2);
    let err = stderr_of(out.get_output());
    assert_eq!(err.trim_end().lines().count(), 1, "{err}");
    assert!(err.contains("plant.toml"), "{err}");
    assert!(err.contains("--force"), "{err}");
    assert!(out.get_output().stdout.is_empty());
    assert_eq!(std::fs::read_to_string(&path).unwrap(), first);

    // Also through --out, and for a file that is not a starter at all.
    let other = dir.path().join("mine.toml");
    std::fs::write(&other, "keep me\n").unwrap();
    let out = autotune()
        .args(["init", "plant", "--out"])
        .arg(&other)
        .assert()
        .code(2);
    assert!(stderr_of(out.get_output()).contains("mine.toml"));
    assert_eq!(std::fs::read_to_string(&other).unwrap(), "keep me\n");

    // --force overwrites.
    autotune()
        .current_dir(dir.path())
        .args(["init", "plant", "--model", "cv1d", "--force"])
        .assert()
        .code(0);
    let second = std::fs::read_to_string(&path).unwrap();
    assert_ne!(second, first);
    assert!(second.contains("--model cv1d"));
    autotune()
        .arg("check")
        .arg(&path)
        .arg("--quiet")
        .assert()
        .code(0);

    // Nothing else was left in the directory (the atomic write's temporary file).
    let mut names: Vec<String> = std::fs::read_dir(dir.path())
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    names.sort();
    assert_eq!(names, ["mine.toml", "plant.toml"]);
}

#[test]
fn out_writes_where_asked() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("sub").join("motor.toml");
    autotune()
        .args(["init", "motor", "--model", "dcmotor", "--out"])
        .arg(&path)
        .assert()
        .code(0);
    let text = std::fs::read_to_string(&path).unwrap();
    assert!(text.contains("name = \"motor\""));
    assert!(!dir.path().join("motor.toml").exists());
}

#[test]
fn invalid_names_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    for bad in ["a b", "a/b", "x.toml", "quo\"te", "ä", ""] {
        let out = autotune()
            .current_dir(dir.path())
            .args(["init", bad])
            .assert()
            .code(2);
        let err = stderr_of(out.get_output());
        assert_eq!(err.trim_end().lines().count(), 1, "{bad:?}: {err}");
        assert!(err.contains("letters, digits"), "{bad:?}: {err}");
    }
    assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 0);
}

#[test]
fn completions_for_every_shell() {
    for shell in ["bash", "zsh", "fish", "elvish", "powershell"] {
        let out = autotune().args(["completions", shell]).assert().code(0);
        let script = String::from_utf8(out.get_output().stdout.clone()).unwrap();
        assert!(script.len() > 200, "{shell}: {script}");
        assert!(script.contains("autotune"), "{shell}");
        for sub in ["check", "tune", "init", "completions"] {
            assert!(script.contains(sub), "{shell}: no {sub}");
        }
        // The init models are completed too (elvish and powershell scripts complete
        // subcommands and flags only).
        if ["bash", "zsh", "fish"].contains(&shell) {
            assert!(script.contains("dcmotor"), "{shell}: no model names");
        }
    }
    let out = autotune().args(["completions", "tcsh"]).assert().code(2);
    let err = stderr_of(out.get_output());
    assert_eq!(err.trim_end().lines().count(), 1, "{err}");
    assert!(err.contains("bash, elvish, fish, powershell, zsh"), "{err}");
}
