//! Regression tests for issue 11 (hardening), through the real binary: each test is named
//! after what it guards and failed on the code before the fix.
//!
//! Items: 8 (bounds instead of panics and unbounded memory), 9 (a closed stdout keeps the
//! verdict's exit code), 10 (outputs checked before the work, written all or nothing),
//! 12 (an interrupt leaves no temporary file), 14 (smaller ones: weights, special files,
//! `--quiet --json`, number formats, statistics without data, `check` validation, identical
//! reports, stale rejected configs, messages).

use crate::common;

use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};
use std::time::{Duration, Instant};

use common::problem_path;

const CV1D: &str = include_str!("../../problems/cv1d.toml");

/// The binary, run in `dir`.
fn autotune_in(dir: &Path) -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_autotune"));
    c.current_dir(dir).env("NO_COLOR", "1");
    c
}

/// Run `cmd`, killing it after `limit` (a run that should have been refused at once must
/// not be waited for as long as the work it would have done).
fn run_for(mut cmd: Command, limit: Duration) -> Output {
    let mut child = cmd
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    // Drain the pipes on threads, so a chatty child cannot block on a full pipe.
    let mut out = child.stdout.take().unwrap();
    let mut err = child.stderr.take().unwrap();
    let out_t = std::thread::spawn(move || {
        let mut v = Vec::new();
        std::io::Read::read_to_end(&mut out, &mut v).unwrap();
        v
    });
    let err_t = std::thread::spawn(move || {
        let mut v = Vec::new();
        std::io::Read::read_to_end(&mut err, &mut v).unwrap();
        v
    });
    let start = Instant::now();
    let status = loop {
        if let Some(s) = child.try_wait().unwrap() {
            break s;
        }
        if start.elapsed() > limit {
            let _ = child.kill();
            let _ = child.wait();
            panic!("still running after {limit:?}: {cmd:?}");
        }
        std::thread::sleep(Duration::from_millis(20));
    };
    Output {
        status,
        stdout: out_t.join().unwrap(),
        stderr: err_t.join().unwrap(),
    }
}

/// Run with a one-minute limit.
fn run(cmd: Command) -> Output {
    run_for(cmd, Duration::from_secs(60))
}

fn text(b: &[u8]) -> String {
    String::from_utf8_lossy(b).into_owned()
}

/// Exit 2 with exactly one line on stderr, `error: …`, containing every string of `must`.
#[track_caller]
fn assert_one_line_error(out: &Output, must: &[&str]) {
    let err = text(&out.stderr);
    assert_eq!(
        out.status.code(),
        Some(2),
        "expected exit 2; stderr: {err}; stdout: {}",
        text(&out.stdout)
    );
    assert_eq!(err.lines().count(), 1, "one line on stderr: {err}");
    assert!(err.starts_with("error: "), "{err}");
    for m in must {
        assert!(err.contains(m), "stderr lacks '{m}': {err}");
    }
}

/// cv1d.toml with `extra` appended, written into `dir`.
fn cv1d_with(dir: &Path, name: &str, extra: &str) -> PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, format!("{CV1D}\n{extra}\n")).unwrap();
    p
}

/// Whether a file name is that of an output's temporary file (`.NAME.XXXXXXXX.tmp`).
fn is_temporary(name: &str) -> bool {
    name.starts_with('.') && name.ends_with(".tmp")
}

/// Files under `dir` (recursively) whose name marks a temporary file.
fn temporary_files(dir: &Path) -> Vec<PathBuf> {
    let mut found = Vec::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).unwrap() {
            let e = e.unwrap();
            let p = e.path();
            if e.file_type().unwrap().is_dir() {
                stack.push(p);
            } else if is_temporary(&p.file_name().unwrap().to_string_lossy()) {
                found.push(p);
            }
        }
    }
    found
}

// ---- item 8: bounds, never a panic, memory that does not grow with N ----

#[test]
fn issue11_huge_max_seconds_is_a_one_line_error_not_a_panic() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("o.toml");
    for v in ["1e19", "1e20", "1e308"] {
        let mut c = autotune_in(dir.path());
        c.arg("tune")
            .arg(problem_path("cv1d"))
            .args(["--max-evals", "3", "--max-seconds", v, "--out"])
            .arg(&out);
        assert_one_line_error(&run(c), &["--max-seconds", v]);
        let p = cv1d_with(dir.path(), "p.toml", &format!("[tune]\nmax_seconds = {v}"));
        let mut c = autotune_in(dir.path());
        c.arg("tune")
            .arg(&p)
            .args(["--max-evals", "3", "--out"])
            .arg(&out);
        assert_one_line_error(&run(c), &["p.toml", "tune.max_seconds"]);
    }
    assert!(!out.exists());
}

#[test]
fn issue11_huge_global_points_is_refused_before_allocating() {
    let dir = tempfile::tempdir().unwrap();
    for v in ["9223372036854775807", "100000000"] {
        let p = cv1d_with(
            dir.path(),
            "p.toml",
            &format!("[tune]\nglobal_points = {v}"),
        );
        let mut c = autotune_in(dir.path());
        c.arg("tune")
            .arg(&p)
            .args(["--max-evals", "5", "--out", "o.toml"]);
        assert_one_line_error(&run(c), &["p.toml", "tune.global_points", v]);
    }
}

#[test]
fn issue11_huge_run_counts_are_one_line_errors_not_aborts() {
    let dir = tempfile::tempdir().unwrap();
    let runs = dir.path().join("runs.toml");
    std::fs::write(
        &runs,
        CV1D.replacen("runs = 200", "runs = 9223372036854775807", 1),
    )
    .unwrap();
    for cmd in ["check", "tune"] {
        let mut c = autotune_in(dir.path());
        c.args([cmd, "runs.toml"]);
        if cmd == "tune" {
            c.args(["--max-evals", "3"]);
        }
        assert_one_line_error(&run(c), &["runs.toml", "montecarlo.runs"]);

        let mut c = autotune_in(dir.path());
        c.arg(cmd)
            .arg(problem_path("cv1d"))
            .args(["--runs", "18446744073709551615"]);
        assert_one_line_error(&run(c), &["--runs"]);
    }
    let p = cv1d_with(
        dir.path(),
        "search.toml",
        "[tune]\nsearch_runs = 9223372036854775807",
    );
    let mut c = autotune_in(dir.path());
    c.arg("tune").arg(&p).args(["--max-evals", "3"]);
    assert_one_line_error(&run(c), &["search.toml", "tune.search_runs"]);
    // The default search runs are 4 N: an N that fits the check but not four times over.
    let mut c = autotune_in(dir.path());
    c.arg("tune")
        .arg(problem_path("cv1d"))
        .args(["--runs", "900000000000", "--max-evals", "3"]);
    assert_one_line_error(&run(c), &["--runs", "search_runs"]);
    assert!(!dir.path().join("tuned").exists());
}

/// Peak resident memory of process `pid` so far, kB (Linux).
fn peak_rss_kb(pid: u32) -> Option<u64> {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).ok()?;
    status
        .lines()
        .find(|l| l.starts_with("VmHWM:"))?
        .split_whitespace()
        .nth(1)?
        .parse()
        .ok()
}

#[test]
fn issue11_ten_billion_runs_stream_in_bounded_memory() {
    // 10¹⁰ runs take hours; their memory must not grow with N. Watch the process for a few
    // seconds of work and stop it: before the fix it listed every chunk of runs up front
    // (1.6·10⁸ ranges, 2.5 GB) and grew until it was killed.
    let dir = tempfile::tempdir().unwrap();
    let mut child = autotune_in(dir.path())
        .arg("check")
        .arg(problem_path("cv1d"))
        .args(["--runs", "10000000000", "--quiet"])
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let mut peak = 0;
    let start = Instant::now();
    while start.elapsed() < Duration::from_secs(4) {
        if let Some(kb) = peak_rss_kb(child.id()) {
            peak = peak.max(kb);
        }
        assert!(
            child.try_wait().unwrap().is_none(),
            "10¹⁰ runs cannot have finished"
        );
        std::thread::sleep(Duration::from_millis(50));
    }
    let _ = child.kill();
    let _ = child.wait();
    assert!(peak > 0, "no /proc status read");
    // The streamed engine holds a few chunks' sums (kB each) besides the program itself.
    assert!(peak < 200_000, "peak resident memory {peak} kB");
}

// ---- item 9: a closed stdout keeps the verdict's exit code ----

/// A stdout whose reader is already gone: every write fails with a broken pipe.
fn closed_stdout() -> Stdio {
    let (ours, theirs) = std::os::unix::net::UnixStream::pair().unwrap();
    drop(ours);
    Stdio::from(std::os::fd::OwnedFd::from(theirs))
}

#[test]
fn issue11_closed_stdout_keeps_the_verdicts_exit_code() {
    // cv1d's shipped start is overconfident: the gate fails (exit 1), and `… | head` must
    // not turn that into a pass under `set -o pipefail`.
    let dir = tempfile::tempdir().unwrap();
    for json in [false, true] {
        let mut c = autotune_in(dir.path());
        c.arg("check")
            .arg(problem_path("cv1d"))
            .args(["--runs", "20"]);
        if json {
            c.arg("--json");
        }
        let out = c
            .stdout(closed_stdout())
            .stderr(Stdio::piped())
            .output()
            .unwrap();
        assert_eq!(out.status.code(), Some(1), "{}", text(&out.stderr));
        assert_eq!(text(&out.stderr), "", "a closed pipe is not an error");
    }
    // The same for tune: a budget of 3 evaluations does not confirm (exit 1).
    let out = autotune_in(dir.path())
        .arg("tune")
        .arg(problem_path("cv1d"))
        .args(["--max-evals", "3", "--runs", "20", "--out", "o.toml"])
        .stdout(closed_stdout())
        .stderr(Stdio::piped())
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(1), "{}", text(&out.stderr));
    // And the pass stays a pass: the truth's values are consistent.
    let out = autotune_in(dir.path())
        .arg("check")
        .arg(problem_path("cv1d"))
        .args(["--set", "q_accel=0.5", "--set", "r_pos=1", "--json"])
        .stdout(closed_stdout())
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(0));
}

// ---- item 10: every output checked before the work, the set written all or nothing ----

#[test]
fn issue11_unwritable_report_dir_leaves_the_tuned_config_alone() {
    // A full tune of cv1d confirms, so without the check it replaced tuned/cv1d.toml.
    let dir = tempfile::tempdir().unwrap();
    std::fs::create_dir(dir.path().join("tuned")).unwrap();
    let tuned = dir.path().join("tuned/cv1d.toml");
    // A config an earlier run wrote (it carries autotune's mark, so it may be replaced).
    let old = "# Tuned by autotune 0.0.1: old\n";
    std::fs::write(&tuned, old).unwrap();
    std::fs::write(dir.path().join("blocker"), "a file, not a directory").unwrap();
    let mut c = autotune_in(dir.path());
    c.arg("tune")
        .arg(problem_path("cv1d"))
        .args(["--report", "blocker/report"]);
    let out = run(c);
    assert_eq!(std::fs::read_to_string(&tuned).unwrap(), old);
    assert!(!dir.path().join("tuned/cv1d.rejected.toml").exists());
    assert_one_line_error(&out, &["blocker", "not a directory"]);
    assert_eq!(temporary_files(dir.path()), Vec::<PathBuf>::new());
}

#[test]
fn issue11_check_with_a_bad_report_dir_writes_no_junit() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("blocker"), "a file").unwrap();
    let mut c = autotune_in(dir.path());
    c.arg("check").arg(problem_path("cv1d")).args([
        "--runs",
        "20",
        "--junit",
        "j.xml",
        "--report",
        "blocker/r",
    ]);
    assert_one_line_error(&run(c), &["blocker"]);
    assert!(!dir.path().join("j.xml").exists(), "J was written");
    // A report that is a file, and a JUnit path under a file, the other way round.
    let mut c = autotune_in(dir.path());
    c.arg("check").arg(problem_path("cv1d")).args([
        "--runs",
        "20",
        "--report",
        "rep",
        "--junit",
        "blocker/j.xml",
    ]);
    assert_one_line_error(&run(c), &["blocker/j.xml", "not a directory"]);
    assert!(!dir.path().join("rep").exists(), "the report was written");
}

#[test]
fn issue11_out_that_is_a_directory_fails_before_the_search() {
    // 10⁸ confirmation runs take many minutes: the refusal must come first, not after.
    let dir = tempfile::tempdir().unwrap();
    std::fs::create_dir(dir.path().join("outdir")).unwrap();
    let mut c = autotune_in(dir.path());
    c.arg("tune")
        .arg(problem_path("cv1d"))
        .args(["--runs", "100000000", "--out", "outdir"]);
    assert_one_line_error(
        &run_for(c, Duration::from_secs(30)),
        &["outdir", "is a directory"],
    );
    assert_eq!(
        std::fs::read_dir(dir.path().join("outdir"))
            .unwrap()
            .count(),
        0
    );
}

// ---- item 12: an interrupt leaves no temporary file ----

/// Send `signal` (e.g. `INT`) to `pid`.
fn kill(signal: &str, pid: u32) {
    let ok = Command::new("kill")
        .arg(format!("-{signal}"))
        .arg(pid.to_string())
        .status()
        .unwrap()
        .success();
    assert!(ok, "kill -{signal} {pid}");
}

#[test]
fn issue11_interrupt_removes_temporary_files() {
    // The test hook holds a commit with its temporary files written; the signal arrives
    // there, the worst moment: every temporary file must go, and nothing be replaced.
    // Exit 128 + the signal's number (issue 21: 130, 143, 129; it was 130 for all three).
    for (signal, cmd, code) in [
        ("INT", "check", 130),
        ("TERM", "tune", 143),
        ("HUP", "check", 129),
    ] {
        let dir = tempfile::tempdir().unwrap();
        std::fs::write(
            dir.path().join("j.xml"),
            "<!-- written by autotune 0.0.1 -->old",
        )
        .unwrap();
        let mut c = autotune_in(dir.path());
        c.arg(cmd)
            .arg(problem_path("cv1d"))
            .args(["--runs", "20", "--report", "rep/deeper", "--quiet"])
            .env("AUTOTUNE_TEST_HOLD_TEMPORARY_MS", "60000")
            .stdout(Stdio::null())
            .stderr(Stdio::piped());
        common::with_default_signals(&mut c);
        if cmd == "check" {
            c.args(["--junit", "j.xml"]);
        } else {
            c.args(["--max-evals", "3", "--out", "j.xml"]);
        }
        let mut child = c.spawn().unwrap();
        let start = Instant::now();
        while temporary_files(dir.path()).len() < 4 {
            assert!(
                start.elapsed() < Duration::from_secs(30),
                "{cmd}: no temporary files appeared: {:?}",
                temporary_files(dir.path())
            );
            assert!(child.try_wait().unwrap().is_none(), "{cmd} finished early");
            std::thread::sleep(Duration::from_millis(10));
        }
        kill(signal, child.id());
        let status = child.wait().unwrap();
        assert_eq!(status.code(), Some(code), "{cmd} after SIG{signal}");
        assert_eq!(temporary_files(dir.path()), Vec::<PathBuf>::new());
        assert_eq!(
            std::fs::read_to_string(dir.path().join("j.xml")).unwrap(),
            "<!-- written by autotune 0.0.1 -->old"
        );
        assert!(
            !dir.path().join("rep").exists(),
            "directories made for the outputs are removed"
        );
    }
}

#[test]
fn issue11_a_signal_ignored_at_start_stays_ignored() {
    // Under `nohup` SIGHUP is ignored, and a script's background job ignores SIGINT: the
    // cleanup handler must not turn those back into a way to stop the run.
    let dir = tempfile::tempdir().unwrap();
    let mut child = Command::new("sh")
        .current_dir(dir.path())
        .arg("-c")
        .arg("trap '' HUP INT; exec \"$0\" \"$@\"")
        .arg(env!("CARGO_BIN_EXE_autotune"))
        .arg("check")
        .arg(problem_path("cv1d"))
        .args(["--runs", "20", "--junit", "j.xml", "--quiet"])
        .env("AUTOTUNE_TEST_HOLD_TEMPORARY_MS", "1500")
        .spawn()
        .unwrap();
    let start = Instant::now();
    while temporary_files(dir.path()).is_empty() {
        assert!(
            start.elapsed() < Duration::from_secs(30),
            "no temporary file"
        );
        std::thread::sleep(Duration::from_millis(10));
    }
    kill("HUP", child.id());
    kill("INT", child.id());
    let status = child.wait().unwrap();
    assert_eq!(
        status.code(),
        Some(1),
        "the gate's verdict, not an interrupt"
    );
    assert!(dir.path().join("j.xml").is_file());
    assert_eq!(temporary_files(dir.path()), Vec::<PathBuf>::new());
}

// ---- item 14: the smaller ones ----

#[test]
fn issue11_all_zero_weights_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let names = [
        "mean",
        "interval",
        "per_step",
        "components",
        "whiteness",
        "shape",
    ];
    let mut c = autotune_in(dir.path());
    c.arg("tune").arg(problem_path("cv1d"));
    for n in names {
        c.args(["--weight", &format!("{n}=0")]);
    }
    assert_one_line_error(&run(c), &["--weight", "every weight is 0"]);
    let zeros: String = names.iter().map(|n| format!("{n} = 0\n")).collect();
    let p = cv1d_with(dir.path(), "w.toml", &format!("[tune.weights]\n{zeros}"));
    for cmd in ["tune", "check"] {
        let mut c = autotune_in(dir.path());
        c.arg(cmd).arg(&p);
        assert_one_line_error(&run(c), &["w.toml", "tune.weights"]);
    }
    assert!(!dir.path().join("tuned").exists());
}

#[test]
fn issue11_out_never_replaces_a_symlink_or_fifo() {
    let dir = tempfile::tempdir().unwrap();
    let target = dir.path().join("real.toml");
    std::fs::write(&target, "keep").unwrap();
    std::os::unix::fs::symlink(&target, dir.path().join("link.toml")).unwrap();
    let made = Command::new("mkfifo")
        .arg(dir.path().join("fifo"))
        .status()
        .unwrap();
    assert!(made.success());
    for (name, what) in [("link.toml", "symbolic link"), ("fifo", "FIFO")] {
        let mut c = autotune_in(dir.path());
        c.arg("tune")
            .arg(problem_path("cv1d"))
            .args(["--max-evals", "3", "--out", name]);
        assert_one_line_error(&run(c), &[name, what]);
        let mut c = autotune_in(dir.path());
        c.arg("check")
            .arg(problem_path("cv1d"))
            .args(["--runs", "20", "--junit", name]);
        assert_one_line_error(&run(c), &[name, what]);
    }
    let link = std::fs::symlink_metadata(dir.path().join("link.toml")).unwrap();
    assert!(link.file_type().is_symlink());
    use std::os::unix::fs::FileTypeExt;
    let fifo = std::fs::symlink_metadata(dir.path().join("fifo")).unwrap();
    assert!(fifo.file_type().is_fifo());
    assert_eq!(std::fs::read_to_string(&target).unwrap(), "keep");
}

#[test]
fn issue11_quiet_json_prints_nothing_on_stdout() {
    let dir = tempfile::tempdir().unwrap();
    let mut c = autotune_in(dir.path());
    c.arg("check")
        .arg(problem_path("cv1d"))
        .args(["--runs", "20", "--quiet", "--json"]);
    let out = run(c);
    assert_eq!(text(&out.stdout), "");
    // The two ask for opposite things: a usage error naming both.
    assert_one_line_error(&out, &["--quiet", "--json"]);
}

/// The longest run of digits in `s`.
fn longest_digit_run(s: &str) -> usize {
    s.split(|c: char| !c.is_ascii_digit())
        .map(str::len)
        .max()
        .unwrap_or(0)
}

#[test]
fn issue11_huge_numbers_print_in_scientific_notation() {
    // A truth with 10¹⁰⁰ times the noise the filter expects: ANEES, ANIS and the
    // components are near 10¹⁰⁰.
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(
        dir.path().join("big.toml"),
        CV1D.replacen("value = 0.5 }", "value = 1e100 }", 1),
    )
    .unwrap();
    let mut c = autotune_in(dir.path());
    c.args([
        "check", "big.toml", "--runs", "5", "--steps", "10", "--report", "rep", "--junit", "j.xml",
    ]);
    let out = run(c);
    assert_eq!(out.status.code(), Some(1), "{}", text(&out.stderr));
    let stdout = text(&out.stdout);
    assert!(stdout.contains("e100"), "{stdout}");
    // The tuned config's provenance holds the same numbers, and must read back.
    let mut c = autotune_in(dir.path());
    c.args([
        "tune",
        "big.toml",
        "--runs",
        "5",
        "--steps",
        "10",
        "--max-evals",
        "3",
        "--out",
        "o.toml",
        "--quiet",
    ]);
    assert_eq!(run(c).status.code(), Some(1));
    let mut c = autotune_in(dir.path());
    c.args([
        "check", "big.toml", "--runs", "5", "--steps", "10", "--config", "o.toml",
    ]);
    assert_eq!(run(c).status.code(), Some(1), "the tuned config reads back");
    for (what, s) in [
        ("stdout", stdout),
        (
            "report.md",
            std::fs::read_to_string(dir.path().join("rep/report.md")).unwrap(),
        ),
        (
            "junit",
            std::fs::read_to_string(dir.path().join("j.xml")).unwrap(),
        ),
        (
            "tuned config",
            std::fs::read_to_string(dir.path().join("o.toml")).unwrap(),
        ),
    ] {
        assert!(
            longest_digit_run(&s) < 25,
            "{what} prints long numbers: {s}"
        );
    }
}

#[test]
fn issue11_a_statistic_without_data_prints_no_data_not_nan() {
    // orbit2d's stations see the satellite only after a while: in 7 steps none does.
    let dir = tempfile::tempdir().unwrap();
    let mut c = autotune_in(dir.path());
    c.arg("check").arg(problem_path("orbit2d")).args([
        "--runs", "3", "--steps", "7", "--report", "rep", "--junit", "j.xml",
    ]);
    let out = run(c);
    assert_ne!(out.status.code(), Some(2), "{}", text(&out.stderr));
    let mut c = autotune_in(dir.path());
    c.arg("tune").arg(problem_path("orbit2d")).args([
        "--runs",
        "3",
        "--steps",
        "7",
        "--max-evals",
        "3",
        "--report",
        "trep",
        "--out",
        "o.toml",
    ]);
    let tuned = run(c);
    assert_ne!(tuned.status.code(), Some(2), "{}", text(&tuned.stderr));
    let read = |p: &str| std::fs::read_to_string(dir.path().join(p)).unwrap();
    for (what, s) in [
        ("check stdout", text(&out.stdout)),
        ("tune stdout", text(&tuned.stdout)),
        ("report.md", read("rep/report.md")),
        ("report.html", read("rep/report.html")),
        ("junit", read("j.xml")),
        ("tune report.md", read("trep/report.md")),
    ] {
        assert!(!s.contains("NaN"), "{what} prints NaN: {s}");
        assert!(s.contains("no data"), "{what} does not say 'no data': {s}");
    }
}

#[test]
fn issue11_check_refuses_an_invalid_tune_table() {
    let dir = tempfile::tempdir().unwrap();
    let p = cv1d_with(dir.path(), "t.toml", "[tune]\nmax_evals = 0");
    let mut c = autotune_in(dir.path());
    c.arg("check").arg(&p);
    assert_one_line_error(&run(c), &["t.toml", "tune.max_evals"]);
}

#[test]
fn issue11_check_refuses_a_tuned_config_whose_q_or_r_disagrees_with_its_values() {
    let dir = tempfile::tempdir().unwrap();
    let shipped =
        std::fs::read_to_string(PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tuned/cv1d.toml"))
            .unwrap();
    let cases = [
        ("R = [[", "R = [[2.0 + ", "R"),
        ("Q = [[", "Q = [[1.0, 0.0], [", "Q"),
    ];
    for (find, replace, field) in cases {
        // A hand edit of R's only entry, and a Q with a row too many.
        let edited = if field == "R" {
            let start = shipped.find("R = [[").unwrap();
            let end = start + shipped[start..].find('\n').unwrap();
            format!("{}R = [[2.0]]{}", &shipped[..start], &shipped[end..])
        } else {
            shipped.replacen(find, replace, 1)
        };
        assert_ne!(edited, shipped);
        std::fs::write(dir.path().join("cfg.toml"), &edited).unwrap();
        let mut c = autotune_in(dir.path());
        c.arg("check")
            .arg(problem_path("cv1d"))
            .args(["--runs", "20", "--config", "cfg.toml"]);
        assert_one_line_error(&run(c), &["cfg.toml", field]);
    }
    // The shipped config itself is accepted.
    std::fs::write(dir.path().join("cfg.toml"), &shipped).unwrap();
    let mut c = autotune_in(dir.path());
    c.arg("check")
        .arg(problem_path("cv1d"))
        .args(["--runs", "20", "--config", "cfg.toml"]);
    assert_ne!(run(c).status.code(), Some(2));
}

#[test]
fn issue11_identical_runs_write_identical_reports() {
    let dir = tempfile::tempdir().unwrap();
    for i in 0..2 {
        let mut c = autotune_in(dir.path());
        c.arg("tune").arg(problem_path("cv2d")).args([
            "--max-evals",
            "40",
            "--runs",
            "30",
            "--out",
            &format!("o{i}.toml"),
            "--report",
            &format!("rep{i}"),
            "--quiet",
        ]);
        let out = run(c);
        assert_ne!(out.status.code(), Some(2), "{}", text(&out.stderr));
    }
    let read = |p: String| std::fs::read(dir.path().join(p)).unwrap();
    for f in ["report.json", "report.md", "report.html"] {
        assert!(
            read(format!("rep0/{f}")) == read(format!("rep1/{f}")),
            "{f} differs between identical runs"
        );
    }
    assert!(read("o0.toml".into()) == read("o1.toml".into()));
}

#[test]
fn issue11_successful_tune_removes_a_stale_rejected_config() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::create_dir(dir.path().join("tuned")).unwrap();
    let rejected = dir.path().join("tuned/cv1d.rejected.toml");
    std::fs::write(
        &rejected,
        "# REJECTED by autotune 0.0.1: from a failed run\n",
    )
    .unwrap();
    let mut c = autotune_in(dir.path());
    c.arg("tune").arg(problem_path("cv1d")).arg("--quiet");
    let out = run(c);
    assert_eq!(out.status.code(), Some(0), "{}", text(&out.stderr));
    assert!(dir.path().join("tuned/cv1d.toml").is_file());
    assert!(!rejected.exists(), "the stale rejected config stayed");
}

#[test]
fn issue11_messages_name_what_is_wrong() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();

    // A missing PROBLEM argument is named.
    let mut c = autotune_in(d);
    c.arg("check");
    assert_one_line_error(&run(c), &["<PROBLEM>"]);

    // A negative number is a value the setter refuses, not an unknown '-0' argument.
    let mut c = autotune_in(d);
    c.arg("check")
        .arg(problem_path("cv1d"))
        .args(["--alpha", "-0.1"]);
    let out = run(c);
    assert_one_line_error(&out, &["--alpha", "-0.1", "(0, 1)"]);
    assert!(!text(&out.stderr).contains("unexpected argument"));

    // A --fix value outside its bounds is an error of --fix.
    let mut c = autotune_in(d);
    c.arg("tune")
        .arg(problem_path("cv1d"))
        .args(["--fix", "q_accel=-5"]);
    let out = run(c);
    assert_one_line_error(&out, &["--fix", "q_accel"]);
    assert!(!text(&out.stderr).contains("--set"));

    // An output under a regular file: "not a directory", not "File exists".
    std::fs::write(d.join("plain"), "x").unwrap();
    let mut c = autotune_in(d);
    c.arg("tune")
        .arg(problem_path("cv1d"))
        .args(["--max-evals", "3", "--out", "plain/sub/o.toml"]);
    let out = run(c);
    assert_one_line_error(&out, &["plain/sub/o.toml", "not a directory"]);
    assert!(!text(&out.stderr).contains("File exists"));

    // A covariance whose smallest eigenvalue is positive but too small to invert is not
    // called "not positive definite".
    let p = d.join("singular.toml");
    std::fs::write(
        &p,
        CV1D.replacen(
            "P0 = [[4.0, 0.0],\n      [0.0, 1.0]]",
            "P0 = [[1.0, 0.99999999999999],\n      [0.99999999999999, 1.0]]",
            1,
        ),
    )
    .unwrap();
    let mut c = autotune_in(d);
    c.arg("check").arg(&p);
    let out = run(c);
    assert_one_line_error(&out, &["singular.toml", "P0", "smallest eigenvalue"]);
    assert!(
        !text(&out.stderr).contains("not positive definite"),
        "{}",
        text(&out.stderr)
    );
}
