//! Issue #21, external workers: a worker's file answer is contained in its scratch directory
//! (nothing outside it read or deleted), scratch directories are private and fresh, an
//! interrupt stops the workers' process groups and removes the scratch directories, a worker
//! that exits while its child holds its stdout is noticed at once, and the seed-contract
//! check catches runs all seeded alike and a worker whose answers depend on its state. With
//! the scripted pure Python worker `tests/data/workers/fake_worker.py`.

use crate::common;

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

fn worker_script() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/workers/fake_worker.py")
}

/// A problem file for the fake worker in `mode`, written into `dir`.
fn problem(dir: &Path, mode: &str, workers: usize, runs: usize, timeout: f64) -> PathBuf {
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
timeout = {timeout}

[params.q]
value = 0.5

[params.r]
value = 2.0
"#,
        script = worker_script().display()
    );
    let path = dir.join(format!("walk_{mode}.toml"));
    std::fs::write(&path, text).unwrap();
    path
}

/// `autotune check PROBLEM` with the scratch space under `tmp` and the worker's log in `log`.
fn check(problem: &Path, tmp: &Path, log: &Path) -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_autotune"));
    c.arg("check")
        .arg(problem)
        .env("TMPDIR", tmp)
        .env("FAKE_WORKER_LOG", log)
        .stdin(Stdio::null());
    c
}

/// Exit code, stdout, stderr.
fn run(mut c: Command) -> (Option<i32>, String, String) {
    let out = c.output().unwrap();
    (
        out.status.code(),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

/// The worker log's lines, as JSON.
fn log_lines(log: &Path) -> Vec<serde_json::Value> {
    std::fs::read_to_string(log)
        .unwrap_or_default()
        .lines()
        .filter_map(|l| serde_json::from_str(l).ok())
        .collect()
}

/// What lies in `dir` whose name starts with `autotune-`.
fn scratch_left(dir: &Path) -> Vec<String> {
    std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|n| n.starts_with("autotune-"))
        .collect()
}

/// Whether process `pid` is running (a zombie is not).
fn alive(pid: i32) -> bool {
    // SAFETY: signal 0 only checks that the process exists.
    let exists = unsafe { libc::kill(pid, 0) } == 0;
    let zombie = std::fs::read_to_string(format!("/proc/{pid}/stat"))
        .map(|s| {
            s.rsplit(')')
                .next()
                .unwrap_or("")
                .trim_start()
                .starts_with('Z')
        })
        .unwrap_or(false);
    exists && !zombie
}

/// Every process the workers logged is gone within `within`.
fn all_gone(log: &Path, within: Duration) -> Result<(), Vec<i32>> {
    let pids: Vec<i32> = log_lines(log)
        .iter()
        .filter_map(|v| v["pid"].as_i64())
        .map(|p| p as i32)
        .collect();
    assert!(!pids.is_empty(), "the workers logged no pids");
    let start = Instant::now();
    loop {
        let left: Vec<i32> = pids.iter().copied().filter(|&p| alive(p)).collect();
        if left.is_empty() {
            return Ok(());
        }
        if start.elapsed() > within {
            return Err(left);
        }
        std::thread::sleep(Duration::from_millis(20));
    }
}

// ---- item 1: a worker's file answer is contained ----

#[test]
fn issue21_a_file_answer_outside_the_scratch_dir_is_refused_and_nothing_deleted() {
    let dir = tempfile::tempdir().unwrap();
    let tmp = dir.path().join("t");
    std::fs::create_dir(&tmp).unwrap();
    let victim = tmp.join("victim.jsonl");
    std::fs::write(&victim, "precious\n").unwrap();
    let p = problem(dir.path(), "escape", 1, 10, 10.0);
    let (code, stdout, stderr) = run(check(&p, &tmp, &dir.path().join("log")));
    assert_eq!(
        std::fs::read_to_string(&victim).ok().as_deref(),
        Some("precious\n"),
        "autotune deleted or changed a file it did not create"
    );
    assert_eq!(code, Some(2), "{stdout}\n{stderr}");
    assert_eq!(stderr.lines().count(), 1, "{stderr}");
    assert!(
        stderr.contains("not inside the worker's scratch directory"),
        "{stderr}"
    );
    assert!(stderr.contains("victim.jsonl"), "{stderr}");
    assert_eq!(scratch_left(&tmp), Vec::<String>::new());
}

#[test]
fn issue21_a_file_answer_through_a_symlink_out_of_the_scratch_dir_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let tmp = dir.path().join("t");
    std::fs::create_dir(&tmp).unwrap();
    // The worker writes valid records outside its scratch directory and names a link to
    // them inside it: read, they would pass.
    let p = problem(dir.path(), "escape_link", 1, 10, 10.0);
    let (code, stdout, stderr) = run(check(&p, &tmp, &dir.path().join("log")));
    assert_eq!(code, Some(2), "{stdout}\n{stderr}");
    assert_eq!(stderr.lines().count(), 1, "{stderr}");
    assert!(
        stderr.contains("not inside the worker's scratch directory"),
        "{stderr}"
    );
    assert!(
        tmp.join("victim.jsonl").is_file(),
        "the link's target is kept"
    );
    assert_eq!(scratch_left(&tmp), Vec::<String>::new());
}

// ---- item 2: scratch directories are private and fresh ----

#[test]
fn issue21_scratch_dirs_are_private_and_not_named_after_the_pid() {
    let dir = tempfile::tempdir().unwrap();
    let tmp = dir.path().join("t");
    std::fs::create_dir(&tmp).unwrap();
    let log = dir.path().join("log");
    let p = problem(dir.path(), "good", 2, 100, 10.0);
    let child = check(&p, &tmp, &log)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let pid = child.id().to_string();
    let out = child.wait_with_output().unwrap();
    assert_ne!(
        out.status.code(),
        Some(2),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let lines = log_lines(&log);
    assert!(!lines.is_empty());
    for l in &lines {
        assert_eq!(l["mode"].as_i64(), Some(0o700), "{l}");
        let name = Path::new(l["dir"].as_str().unwrap())
            .file_name()
            .unwrap()
            .to_string_lossy()
            .into_owned();
        assert!(!name.contains(&pid), "{name} is predictable from pid {pid}");
    }
    assert_eq!(scratch_left(&tmp), Vec::<String>::new());
}

#[test]
fn issue21_a_planted_scratch_dir_or_symlink_is_not_used() {
    let dir = tempfile::tempdir().unwrap();
    let tmp = dir.path().join("t");
    std::fs::create_dir(&tmp).unwrap();
    let target = dir.path().join("elsewhere");
    std::fs::create_dir(&target).unwrap();
    let log = dir.path().join("log");
    let p = problem(dir.path(), "file", 2, 100, 10.0);
    // The names the old scheme would have used (autotune-<pid>-w<k>-<n>), planted before
    // autotune starts: `exec` keeps the shell's pid.
    let mut c = Command::new("sh");
    c.arg("-c")
        .arg(
            r#"ln -s "$PLANT" "$TMPDIR/autotune-$$-w0-0"
mkdir "$TMPDIR/autotune-$$-w1-1" && touch "$TMPDIR/autotune-$$-w1-1/keep"
exec "$0" check "$1""#,
        )
        .arg(env!("CARGO_BIN_EXE_autotune"))
        .arg(&p)
        .env("TMPDIR", &tmp)
        .env("PLANT", &target)
        .env("FAKE_WORKER_LOG", &log)
        .stdin(Stdio::null());
    let child = c
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let pid = child.id();
    let out = child.wait_with_output().unwrap();
    assert_ne!(
        out.status.code(),
        Some(2),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let planted = [
        format!("autotune-{pid}-w0-0"),
        format!("autotune-{pid}-w1-1"),
    ];
    let real_target = target.canonicalize().unwrap();
    let lines = log_lines(&log);
    assert!(!lines.is_empty());
    for l in &lines {
        let d = Path::new(l["dir"].as_str().unwrap());
        let name = d.file_name().unwrap().to_string_lossy().into_owned();
        assert!(!planted.contains(&name), "a planted {name} was used");
        assert_ne!(Path::new(l["real"].as_str().unwrap()), real_target);
    }
    assert_eq!(std::fs::read_dir(&target).unwrap().count(), 0);
    // What autotune did not make, it leaves alone.
    assert!(tmp.join(&planted[0]).symlink_metadata().is_ok());
    assert!(tmp.join(&planted[1]).join("keep").is_file());
    let mut left = scratch_left(&tmp);
    left.sort();
    assert_eq!(left, planted.to_vec());
}

// ---- item 3: an interrupt stops the workers and removes the scratch directories ----

#[test]
fn issue21_an_interrupt_stops_worker_groups_and_removes_scratch_dirs() {
    for (signal, code) in [
        (libc::SIGINT, 130),
        (libc::SIGTERM, 143),
        (libc::SIGHUP, 129),
    ] {
        let dir = tempfile::tempdir().unwrap();
        let tmp = dir.path().join("t");
        std::fs::create_dir(&tmp).unwrap();
        let log = dir.path().join("log");
        // Workers that ignore SIGTERM and the closing of their stdin, each with a child
        // that ignores SIGTERM too, both busy answering.
        let p = problem(dir.path(), "stubborn", 2, 200, 60.0);
        let mut cmd = check(&p, &tmp, &log);
        let mut child = common::with_default_signals(&mut cmd)
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap();
        let start = Instant::now();
        while log_lines(&log)
            .iter()
            .filter(|l| l["busy"].is_boolean())
            .count()
            < 2
        {
            assert!(
                start.elapsed() < Duration::from_secs(30),
                "the workers never got busy"
            );
            assert!(child.try_wait().unwrap().is_none(), "finished early");
            std::thread::sleep(Duration::from_millis(20));
        }
        assert_eq!(scratch_left(&tmp).len(), 2);
        let pid = child.id() as i32;
        // SAFETY: sends a signal to the autotune process this test started.
        unsafe {
            libc::kill(pid, signal);
        }
        let sent = Instant::now();
        let status = loop {
            if let Some(s) = child.try_wait().unwrap() {
                break s;
            }
            assert!(sent.elapsed() < Duration::from_secs(10), "no exit");
            std::thread::sleep(Duration::from_millis(20));
        };
        assert_eq!(status.code(), Some(code), "signal {signal}");
        assert_eq!(scratch_left(&tmp), Vec::<String>::new(), "signal {signal}");
        if let Err(left) = all_gone(&log, Duration::from_secs(2)) {
            panic!("signal {signal}: worker processes {left:?} outlived autotune");
        }
    }
}

// ---- item 8: a worker that exits while its child holds its stdout ----

#[test]
fn issue21_a_worker_that_exits_leaving_a_child_on_its_stdout_is_noticed_at_once() {
    let dir = tempfile::tempdir().unwrap();
    let tmp = dir.path().join("t");
    std::fs::create_dir(&tmp).unwrap();
    let log = dir.path().join("log");
    let p = problem(dir.path(), "orphan", 1, 10, 60.0);
    let start = Instant::now();
    let (code, stdout, stderr) = run(check(&p, &tmp, &log));
    let took = start.elapsed();
    assert_eq!(code, Some(2), "{stdout}\n{stderr}");
    assert_eq!(stderr.lines().count(), 1, "{stderr}");
    assert!(
        stderr.contains("exited with status 4 before answering"),
        "{stderr}"
    );
    assert!(stderr.contains("lost the filter state"), "{stderr}");
    assert!(
        took < Duration::from_secs(10),
        "took {took:?} (the timeout is 60 s)"
    );
    if let Err(left) = all_gone(&log, Duration::from_secs(2)) {
        panic!("the worker's child {left:?} outlived it");
    }
    assert_eq!(scratch_left(&tmp), Vec::<String>::new());
}

// ---- item 14: the seed contract ----

/// `autotune check` on the fake worker in `mode`: exit 2 and one line with each of `expect`.
fn breaks_contract(mode: &str, workers: usize, expect: &[&str]) {
    let dir = tempfile::tempdir().unwrap();
    let p = problem(dir.path(), mode, workers, 100, 10.0);
    let (code, stdout, stderr) = run(check(&p, dir.path(), &dir.path().join("log")));
    assert_eq!(code, Some(2), "{mode}: {stdout}\n{stderr}");
    assert_eq!(stderr.lines().count(), 1, "{mode}: {stderr}");
    assert!(
        stderr.contains("breaks the seed contract"),
        "{mode}: {stderr}"
    );
    for e in expect {
        assert!(stderr.contains(e), "{mode}: expected '{e}' in {stderr}");
    }
}

#[test]
fn issue21_runs_all_seeded_alike_break_the_seed_contract() {
    breaks_contract("seed0", 2, &["all gave the same records", "(seed, i)"]);
    breaks_contract("seed0", 1, &["all gave the same records"]);
}

#[test]
fn issue21_one_worker_with_a_truth_cache_not_keyed_on_the_seed_breaks_the_contract() {
    breaks_contract("cached_truth", 1, &["asked for again", "a fresh worker"]);
}

#[test]
fn issue21_one_worker_whose_state_advances_between_requests_breaks_the_contract() {
    breaks_contract("advancing", 1, &["asked for again"]);
    breaks_contract("advancing", 2, &["asked for again", "worker 2"]);
}

/// Item 4: where `[external]` is introduced (the guide's Workers chapter, before its first
/// example and before the protocol's reference; the `init --external` starter) a reader
/// learns that `check`/`tune` on such a file run the program it names.
#[test]
fn issue21_the_docs_say_a_problem_file_with_external_is_code() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let read = |p: &str| std::fs::read_to_string(root.join(p)).unwrap();
    let doc = read("docs/src/workers.md");
    let intro = doc
        .find("**Your simulator in the loop.**")
        .expect("the guide introduces [external] workers");
    let first_example = intro
        + doc[intro..]
            .find("```toml")
            .expect("an example problem file follows");
    let paragraph = &doc[intro..first_example];
    assert!(
        paragraph.contains("is therefore code") && paragraph.contains("files you trust"),
        "docs/src/workers.md, before the first [external] example: {paragraph}"
    );
    let warning = doc
        .find("**A problem file with `[external]` is code.**")
        .expect("docs/src/workers.md warns");
    assert!(
        warning < intro
            && warning < doc.find("## The worker protocol").unwrap()
            && doc[warning..].contains("files you trust"),
        "docs/src/workers.md warns before its first example and the protocol"
    );
    let starter = read("src/commands/templates/external.toml");
    assert!(
        starter.contains("RUN THE COMMAND") && starter.contains("is code"),
        "the `init --external` starter warns"
    );
}
