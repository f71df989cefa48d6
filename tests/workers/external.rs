//! Issue #12: a simulator in another language as a worker. The protocol's failure table
//! (each a one-line error and exit 2, or +∞ for a diverged candidate), bit-identical
//! statistics on 1, 2 and 4 workers, and the seed-contract check, with the scripted pure
//! Python worker `tests/data/workers/fake_worker.py` (a scalar random walk and its Kalman
//! filter).

use std::path::{Path, PathBuf};

use crate::common;
use autotune::internals::experiment::Experiment;
use autotune::internals::problem::Problem;
use autotune::internals::tune::{Silent, TuneError, TuneSettings, tune};
use common::autotune;

fn worker_script() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/workers/fake_worker.py")
}

/// A problem file for the fake worker in `mode`, with `workers` workers, written into `dir`.
fn problem(dir: &Path, mode: &str, workers: usize, runs: usize, extra: &str) -> PathBuf {
    let text = format!(
        r#"name = "walk_{mode}"
state_names = ["x"]

[montecarlo]
runs = {runs}
steps = 20
seed = 5

[external]
command = ["python3", "{script}", "{mode}"]
sensors = {{ z = ["pos"] }}
workers = {workers}
timeout = 3
truth = {{ q = 0.5, r = 2.0 }}
{extra}

[params.q]
value = 0.5
lower = 0.01
upper = 100.0

[params.r]
value = 2.0
lower = 0.01
upper = 100.0
"#,
        script = worker_script().display()
    );
    let path = dir.join(format!("walk_{mode}_{workers}.toml"));
    std::fs::write(&path, text).unwrap();
    path
}

/// `autotune check` on the fake worker in `mode`: exit 2, one line of stderr that names the
/// command and the request and contains `expect`.
fn fails_with(mode: &str, expect: &[&str]) {
    let dir = tempfile::tempdir().unwrap();
    let p = problem(dir.path(), mode, 2, 100, "");
    let start = std::time::Instant::now();
    let (code, stdout, stderr) = autotune(&["check", p.to_str().unwrap()]);
    assert_eq!(code, Some(2), "{mode}: stdout {stdout}\nstderr {stderr}");
    assert!(stdout.is_empty(), "{mode}: nothing judged, yet: {stdout}");
    let lines: Vec<&str> = stderr.lines().collect();
    assert_eq!(lines.len(), 1, "{mode}: one line, got {stderr}");
    assert!(
        lines[0].contains("fake_worker.py"),
        "{mode}: names the command: {stderr}"
    );
    for e in expect {
        assert!(lines[0].contains(e), "{mode}: expected '{e}' in: {stderr}");
    }
    // Never a hang: the slowest case is the 3 s timeout.
    assert!(
        start.elapsed().as_secs() < 20,
        "{mode}: took {:?}",
        start.elapsed()
    );
}

#[test]
fn a_worker_that_exits_at_start_is_a_one_line_error_with_its_stderr() {
    fails_with(
        "exit_at_start",
        &["exited with status 3", "cannot import the filter module"],
    );
}

#[test]
fn a_worker_that_exits_mid_request_is_a_one_line_error_with_its_stderr() {
    fails_with(
        "exit_mid",
        &["request", "exited with status 1", "ZeroDivisionError"],
    );
}

#[test]
fn a_worker_that_prints_non_protocol_text_is_a_one_line_error() {
    fails_with(
        "garbage",
        &["'iteration 1: P = 3.2'", "not a protocol line"],
    );
}

#[test]
fn a_worker_that_answers_another_id_is_a_one_line_error() {
    fails_with("wrong_id", &["answered id", "to request"]);
}

#[test]
fn a_worker_that_returns_the_wrong_shape_is_a_one_line_error() {
    fails_with("wrong_shape", &["e has 2 entries", "expected 1"]);
}

#[test]
fn a_worker_that_leaves_out_a_run_is_a_one_line_error() {
    fails_with("missing_run", &["is missing"]);
}

#[test]
fn a_worker_that_times_out_is_killed_and_a_one_line_error() {
    fails_with("timeout", &["no answer within the timeout of 3 s"]);
}

#[test]
fn a_malformed_records_file_names_its_line_and_field() {
    fails_with("bad_file", &["records file", ".jsonl:", "P: not a number"]);
}

#[test]
fn a_worker_that_reports_an_error_is_a_one_line_error() {
    fails_with("error", &["reported an error", "theta out of range"]);
}

#[test]
fn a_command_that_does_not_exist_is_a_one_line_error() {
    let dir = tempfile::tempdir().unwrap();
    let p = problem(dir.path(), "good", 1, 10, "");
    let text = std::fs::read_to_string(&p)
        .unwrap()
        .replace("\"python3\"", "\"no-such-interpreter-xyz\"");
    std::fs::write(&p, text).unwrap();
    let (code, _, stderr) = autotune(&["check", p.to_str().unwrap()]);
    assert_eq!(code, Some(2), "{stderr}");
    assert!(stderr.contains("cannot start it"), "{stderr}");
}

#[test]
fn a_worker_that_breaks_the_seed_contract_is_detected() {
    fails_with("unseeded", &["breaks the seed contract"]);
}

/// NaN covariances are a diverged filter: `check` says so (exit 1, not 2), and in a tune
/// the candidate scores +∞ while the search goes on to a consistent filter.
#[test]
fn nan_covariances_are_a_diverged_candidate_not_a_protocol_error() {
    let dir = tempfile::tempdir().unwrap();
    let p = problem(dir.path(), "nan", 2, 64, "");
    let (code, stdout, stderr) = autotune(&["check", p.to_str().unwrap(), "--set", "q=5"]);
    assert_eq!(code, Some(1), "{stdout}\n{stderr}");
    assert!(stdout.contains("diverged"), "{stdout}");

    // The worker's P turns NaN for every q > 1: a start of q = 4 diverges; the search
    // must walk out of the region rather than stop.
    let p = Problem::load(&p).unwrap();
    let mut start = p.params().values();
    start[0] = 4.0;
    let settings = TuneSettings::default()
        .with_max_evals(120)
        .unwrap()
        .with_confirm_seeds(4)
        .unwrap();
    let r = tune(&p, &start, &[false, false], p.mc(), &settings, &Silent).unwrap();
    assert!(r.diverged_evaluations > 0, "the start diverged");
    assert!(
        r.tuned[0] < 1.0 && r.tuned[0] > 0.2,
        "q tuned to {} (truth 0.5)",
        r.tuned[0]
    );
}

/// A worker that honours the seed contract gives bit-identical sums on 1, 2 and 4
/// workers: runs go out in the engine's fixed chunks and their sums merge in chunk order.
#[test]
fn statistics_are_bit_identical_on_one_two_and_four_workers() {
    let dir = tempfile::tempdir().unwrap();
    // 300 runs: five chunks, the last one short.
    let sums: Vec<_> = [1, 2, 4]
        .iter()
        .map(|&w| {
            let p = Problem::load(&problem(dir.path(), "good", w, 300, "")).unwrap();
            let theta = [0.7, 1.5];
            p.monte_carlo(&theta, p.mc()).unwrap()
        })
        .collect();
    assert_eq!(sums[0].runs(), 300);
    assert!(sums[0].nees_sum().iter().all(|v| *v > 0.0));
    assert_eq!(sums[0], sums[1], "1 vs 2 workers");
    assert_eq!(sums[0], sums[2], "1 vs 4 workers");
    // Inline records and a records file are the same records.
    let p = Problem::load(&problem(dir.path(), "file", 2, 300, "")).unwrap();
    assert_eq!(
        p.monte_carlo(&[0.7, 1.5], p.mc()).unwrap(),
        sums[0],
        "file vs inline"
    );
}

/// `[external] drives` names what each parameter drives: the advice then shows that
/// evidence; a component that is not the problem's is a one-line error naming the field.
#[test]
fn drives_names_the_evidence_of_the_advice() {
    let dir = tempfile::tempdir().unwrap();
    let p = problem(
        dir.path(),
        "good",
        2,
        128,
        r#"drives = { q = ["x"], r = ["z_pos"] }"#,
    );
    let (code, stdout, stderr) = autotune(&[
        "tune",
        p.to_str().unwrap(),
        "--set",
        "q=0.1",
        "--set",
        "r=10",
        "--out",
        dir.path().join("t.toml").to_str().unwrap(),
    ]);
    assert!(code == Some(0) || code == Some(1), "{stdout}\n{stderr}");
    assert!(stdout.contains("q: x (e²/P ="), "{stdout}");
    assert!(stdout.contains("r: z_pos (ν²/S ="), "{stdout}");

    let bad = problem(
        dir.path(),
        "good",
        2,
        128,
        r#"drives = { q = ["velocity"] }"#,
    );
    let (code, _, stderr) = autotune(&["check", bad.to_str().unwrap()]);
    assert_eq!(code, Some(2), "{stderr}");
    assert!(stderr.contains("external.drives.q"), "{stderr}");
    assert!(stderr.contains("x, z_pos"), "{stderr}");
}

/// A protocol failure inside a tune stops it with the error, not a verdict.
#[test]
fn a_protocol_failure_stops_a_tune_with_the_error() {
    let dir = tempfile::tempdir().unwrap();
    let p = Problem::load(&problem(dir.path(), "wrong_id", 1, 64, "")).unwrap();
    let start = p.params().values();
    let err = tune(
        &p,
        &start,
        &[false, false],
        p.mc(),
        &TuneSettings::default(),
        &Silent,
    )
    .unwrap_err();
    assert!(matches!(err, TuneError::Experiment(_)), "{err}");
    assert!(err.to_string().contains("to request"), "{err}");
}

/// The fake worker at the truth passes the gate, and from a start 5× off a tune lands
/// near the truth; it is the whole loop (requests, records, search, confirmation) in a
/// few seconds.
#[test]
fn a_tune_through_the_worker_finds_the_truth() {
    let dir = tempfile::tempdir().unwrap();
    let path = problem(dir.path(), "good", 2, 200, "");
    let (code, stdout, _) = autotune(&["check", path.to_str().unwrap()]);
    assert_eq!(code, Some(0), "{stdout}");
    let out = dir.path().join("walk.toml");
    let (code, stdout, stderr) = autotune(&[
        "tune",
        path.to_str().unwrap(),
        "--set",
        "q=0.1",
        "--set",
        "r=10",
        "--out",
        out.to_str().unwrap(),
        "--quiet",
    ]);
    assert_eq!(code, Some(0), "{stdout}\n{stderr}");
    let tuned: toml::Table = std::fs::read_to_string(&out).unwrap().parse().unwrap();
    let params = tuned["params"].as_table().unwrap();
    let q = params["q"].as_float().unwrap();
    let r = params["r"].as_float().unwrap();
    // 200 runs × 20 steps: q and r are determined to a few percent; 15% is several
    // standard errors.
    assert!((q / 0.5 - 1.0).abs() < 0.15, "q = {q}");
    assert!((r / 2.0 - 1.0).abs() < 0.15, "r = {r}");
    let (code, stdout, _) = autotune(&[
        "check",
        path.to_str().unwrap(),
        "--config",
        out.to_str().unwrap(),
        "--seed",
        "777",
    ]);
    assert_eq!(code, Some(0), "{stdout}");
}

/// Found by `tests/fuzz/loaders.rs`: a worker that prints without newlines was read into one
/// growing line until the memory ran out; a pool of workers that ignore their stdin took a
/// second each to stop. Now the line is refused past its limit, and the pool stops in
/// about a second whatever its size.
#[test]
fn an_endless_line_is_an_error_and_a_deaf_pool_stops_together() {
    let dir = tempfile::tempdir().unwrap();
    let write = |name: &str, command: &str, workers: usize, timeout: f64| {
        let path = dir.path().join(name);
        std::fs::write(
            &path,
            format!(
                r#"name = "deaf"
state_names = ["x"]

[montecarlo]
runs = 2
steps = 3
seed = 1

[external]
command = {command}
sensors = {{ z = ["pos"] }}
workers = {workers}
timeout = {timeout}

[params.q]
value = 1.0
"#
            ),
        )
        .unwrap();
        path
    };
    let endless = write(
        "endless.toml",
        r#"["sh", "-c", "yes | tr -d '\\n'"]"#,
        1,
        60.0,
    );
    let start = std::time::Instant::now();
    let (code, _, stderr) = autotune(&["check", endless.to_str().unwrap()]);
    assert_eq!(code, Some(2), "{stderr}");
    assert_eq!(stderr.lines().count(), 1, "{stderr}");
    assert!(stderr.contains("a line longer than 64 MB"), "{stderr}");
    assert!(start.elapsed().as_secs() < 30, "{:?}", start.elapsed());

    let deaf = write(
        "deaf.toml",
        r#"["sh", "-c", "trap '' TERM; sleep 5"]"#,
        8,
        0.5,
    );
    let start = std::time::Instant::now();
    let (code, _, stderr) = autotune(&["check", deaf.to_str().unwrap()]);
    assert_eq!(code, Some(2), "{stderr}");
    assert!(stderr.contains("no answer within the timeout"), "{stderr}");
    assert!(
        start.elapsed().as_secs_f64() < 5.0,
        "8 deaf workers took {:?} to stop",
        start.elapsed()
    );
}

/// A worker that times out is killed with everything it started: a shell wrapper's child
/// would otherwise outlive autotune.
#[cfg(unix)]
#[test]
fn a_timed_out_worker_is_killed_with_its_children() {
    let dir = tempfile::tempdir().unwrap();
    let marker = format!("{}.{}", 4000 + std::process::id() % 1000, 271);
    let text = format!(
        r#"state_names = ["x"]
[montecarlo]
runs = 10
steps = 5
[external]
command = ["sh", "-c", "python3 -c 'import time; time.sleep({marker})' ; cat"]
sensors = {{ z = ["pos"] }}
workers = 1
timeout = 1
[params.q]
value = 1.0
"#
    );
    let path = dir.path().join("wrapped.toml");
    std::fs::write(&path, text).unwrap();
    let (code, _, stderr) = autotune(&["check", path.to_str().unwrap()]);
    assert_eq!(code, Some(2), "{stderr}");
    assert!(stderr.contains("no answer within the timeout"), "{stderr}");
    std::thread::sleep(std::time::Duration::from_millis(300));
    let left = std::process::Command::new("pgrep")
        .args(["-f", &format!("time.sleep\\({marker}\\)")])
        .output()
        .unwrap();
    assert!(
        left.stdout.is_empty(),
        "the worker's child outlived it: pids {}",
        String::from_utf8_lossy(&left.stdout)
    );
}

/// A check of 10¹² runs (the documented maximum) on a worker holds memory to one wave of
/// chunks, not N (issue 37, item 4: it allocated 125 GB for the chunk list and aborted,
/// leaving its scratch directory), and an interrupt then stops it cleanly: exit 130, no
/// scratch directory left.
#[test]
fn a_check_of_a_trillion_runs_stays_small_and_stops_cleanly() {
    use std::process::{Command, Stdio};
    let dir = tempfile::tempdir().unwrap();
    let p = problem(dir.path(), "good", 2, 1_000_000_000_000, "");
    let tmp = dir.path().join("tmp");
    std::fs::create_dir(&tmp).unwrap();
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_autotune"));
    cmd.args(["check", p.to_str().unwrap(), "--quiet"])
        .env("TMPDIR", &tmp)
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::piped());
    let mut child = common::with_default_signals(&mut cmd).spawn().unwrap();
    let pid = child.id();
    let mut hwm_kb = 0u64;
    let start = std::time::Instant::now();
    // Three seconds of chunks (hundreds of requests), sampling the peak memory.
    while start.elapsed().as_secs_f64() < 3.0 {
        if let Ok(status) = std::fs::read_to_string(format!("/proc/{pid}/status"))
            && let Some(kb) = status
                .lines()
                .find(|l| l.starts_with("VmHWM:"))
                .and_then(|l| l.split_whitespace().nth(1)?.parse().ok())
        {
            hwm_kb = hwm_kb.max(kb);
        }
        assert!(child.try_wait().unwrap().is_none(), "it ended early");
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
    // SAFETY: pid is our running child.
    unsafe { libc::kill(pid as libc::pid_t, libc::SIGINT) };
    let out = child.wait_with_output().unwrap();
    assert_eq!(
        out.status.code(),
        Some(130),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(hwm_kb > 0 && hwm_kb < 500 << 10, "peak {hwm_kb} kB");
    let left: Vec<_> = std::fs::read_dir(&tmp).unwrap().collect();
    assert!(left.is_empty(), "left behind: {left:?}");
}
