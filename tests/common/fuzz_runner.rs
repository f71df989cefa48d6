//! Running a fuzzed input through the binary and tallying what happened, for the fuzzers
//! that run `autotune` on files (`tests/fuzz/inputs.rs`, `tests/fuzz/shards.rs`). Included
//! with `#[path]`, beside `common/fuzzing.rs`.
#![allow(dead_code)]

use std::collections::BTreeMap;
use std::ffi::{OsStr, OsString};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use super::fuzzing::{proc_status_kb, spawn_limited};

/// The address space a run may map: beyond, an allocation fails and the process aborts
/// (a failure), instead of the machine swapping.
pub const ADDRESS_SPACE: u64 = 4 << 30;
/// The resident memory a run may reach on any of these inputs (issue #21: bounded memory
/// whatever the input); a run is stopped as soon as it passes it.
pub const RSS_LIMIT_MB: u64 = 500;
/// Failing inputs kept on disk.
pub const SAVED_FAILURES: usize = 40;

/// One binary run to make.
pub struct Case {
    /// What kind of input, for grouping failures (`records/npz`, `worker/fifo`, …).
    pub kind: String,
    pub args: Vec<OsString>,
    /// The directory it runs in; its `tmp/` is the run's `TMPDIR`.
    pub dir: PathBuf,
    pub limit: Duration,
    pub json: bool,
    /// An exit-2 error must contain one of these (the input's file names, the command).
    pub names: Vec<String>,
    /// The input files, saved when the run fails.
    pub files: Vec<PathBuf>,
}

/// How a run ended.
pub struct Outcome {
    pub code: usize,
    /// The error line of an exit 2.
    pub error: String,
    pub seconds: f64,
    pub rss_mb: u64,
}

/// A failed run: its symptom in a few words (for grouping) and the whole story.
pub struct Failed {
    pub symptom: String,
    pub detail: String,
}

pub fn failed(symptom: &str, detail: String) -> Failed {
    Failed {
        symptom: symptom.into(),
        detail,
    }
}

/// Run `case` under the address-space limit, sampling its peak resident memory; check what
/// every run must satisfy.
// The child is reaped by `waitpid` (which `Child` cannot see), on every path.
#[allow(clippy::zombie_processes)]
pub fn run(case: &Case, env: &[(&str, &OsStr)]) -> Result<Outcome, Failed> {
    run_program(env!("CARGO_BIN_EXE_autotune").as_ref(), case, env)
}

/// [`run`] of another program than `autotune` (a test binary fuzzing the C ABI in a child).
#[allow(clippy::zombie_processes)]
pub fn run_program(
    program: &OsStr,
    case: &Case,
    env: &[(&str, &OsStr)],
) -> Result<Outcome, Failed> {
    let tmp = case.dir.join("tmp");
    std::fs::create_dir_all(&tmp).unwrap();
    let mut cmd = Command::new(program);
    cmd.current_dir(&case.dir)
        .args(&case.args)
        .env("NO_COLOR", "1")
        .env("TMPDIR", &tmp)
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped());
    for (k, v) in env {
        cmd.env(k, v);
    }
    let (mut child, out, err) = spawn_limited(&mut cmd, ADDRESS_SPACE);
    let start = Instant::now();
    let pid = child.id() as libc::pid_t;
    let mut status = 0;
    // The child's peak memory, read while it runs (its ru_maxrss would count this
    // process's, which it was forked from).
    let mut hwm_kb = 0;
    let mut stopped = None;
    loop {
        if let Some(kb) = proc_status_kb(pid, "VmHWM:") {
            hwm_kb = hwm_kb.max(kb);
        }
        // SAFETY: pid is our child, not yet reaped; status is valid.
        let r = unsafe { libc::waitpid(pid, &mut status, libc::WNOHANG) };
        if r == pid {
            break;
        }
        assert!(r == 0, "waitpid failed");
        // A run past either bound is stopped at once: waiting for the limit of the
        // address space (or forever) tells nothing more.
        if hwm_kb / 1024 > RSS_LIMIT_MB {
            stopped = Some(failed(
                "memory over the limit",
                format!(
                    "more than {RSS_LIMIT_MB} MB of memory after {:.1} s (stopped)",
                    start.elapsed().as_secs_f64()
                ),
            ));
        } else if start.elapsed() > case.limit {
            stopped = Some(failed(
                "hang",
                format!("still running after {:?} (stopped)", case.limit),
            ));
        }
        if stopped.is_some() {
            let _ = child.kill();
            // SAFETY: as above, blocking until the killed child is reaped.
            unsafe { libc::waitpid(pid, &mut status, 0) };
            break;
        }
        std::thread::sleep(Duration::from_millis(2));
    }
    let seconds = start.elapsed().as_secs_f64();
    // A worker the run left behind may hold the pipes: do not wait for it.
    let join = |h: std::thread::JoinHandle<Vec<u8>>| {
        let until = Instant::now() + Duration::from_secs(10);
        while !h.is_finished() && Instant::now() < until {
            std::thread::sleep(Duration::from_millis(5));
        }
        if h.is_finished() {
            h.join().unwrap()
        } else {
            b"<the pipe stayed open: a process the run started still holds it>".to_vec()
        }
    };
    let stdout = join(out);
    let stderr = String::from_utf8_lossy(&join(err)).into_owned();
    if let Some(f) = stopped {
        return Err(f);
    }
    let code = libc::WIFEXITED(status).then(|| libc::WEXITSTATUS(status));
    let rss_mb = hwm_kb / 1024;
    let shown = |s: &str| s.chars().take(600).collect::<String>();
    if stderr.contains("panicked") {
        return Err(failed(
            "panic",
            format!("exit {code:?}: {}", shown(&stderr)),
        ));
    }
    if !matches!(code, Some(0..=2)) {
        let signal = libc::WIFSIGNALED(status).then(|| libc::WTERMSIG(status));
        let symptom = match signal {
            Some(libc::SIGABRT) => "aborted (SIGABRT)".to_string(),
            Some(s) => format!("killed by signal {s}"),
            None => format!("exit {code:?}"),
        };
        return Err(failed(
            &symptom,
            format!("{symptom} at {rss_mb} MB: {}", shown(stderr.trim_end())),
        ));
    }
    if code == Some(2) {
        if stderr.lines().count() != 1 || !stderr.starts_with("error: ") {
            return Err(failed(
                "exit 2 without a one-line error",
                format!("exit 2, stderr {:?}", shown(&stderr)),
            ));
        }
        if !case.names.iter().any(|n| stderr.contains(n.as_str())) {
            return Err(failed(
                "error does not name the input",
                format!(
                    "the error names none of {:?}: {}",
                    case.names,
                    shown(&stderr)
                ),
            ));
        }
    }
    if code != Some(2) && case.json && serde_json::from_slice::<serde_json::Value>(&stdout).is_err()
    {
        return Err(failed(
            "--json output is not JSON",
            format!(
                "exit {code:?} with --json, stdout {:?}",
                String::from_utf8_lossy(&stdout[..stdout.len().min(300)])
            ),
        ));
    }
    if rss_mb > RSS_LIMIT_MB {
        return Err(failed(
            "memory over the limit",
            format!("{rss_mb} MB of memory (more than {RSS_LIMIT_MB} MB)"),
        ));
    }
    Ok(Outcome {
        code: code.unwrap_or(2) as usize,
        error: if code == Some(2) {
            stderr.trim_end().to_string()
        } else {
            String::new()
        },
        seconds,
        rss_mb,
    })
}

/// What the runs gave: counts, extremes, and the failures grouped by kind and symptom.
#[derive(Default)]
pub struct Tally {
    pub runs: usize,
    pub exits: [usize; 3],
    pub slowest: (f64, String),
    pub max_rss: (u64, String),
    /// (kind, symptom) → count and the first failure.
    pub classes: BTreeMap<(String, String), (usize, String)>,
    pub failures: usize,
}

impl Tally {
    pub fn ok(&mut self, case: &Case, o: &Outcome) {
        self.runs += 1;
        self.exits[o.code] += 1;
        if o.seconds > self.slowest.0 {
            self.slowest = (o.seconds, case.kind.clone());
        }
        if o.rss_mb > self.max_rss.0 {
            self.max_rss = (o.rss_mb, case.kind.clone());
        }
    }

    /// Count a failure; the first [`SAVED_FAILURES`] have their inputs saved.
    pub fn fail(&mut self, case: &Case, f: Failed, failures_dir: &Path, note: &str) {
        self.runs += 1;
        self.failures += 1;
        // Numbered across the parts, so that the saved inputs do not overwrite each other.
        static SAVED: std::sync::atomic::AtomicUsize = std::sync::atomic::AtomicUsize::new(0);
        let n = SAVED.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        let mut args: Vec<String> = case
            .args
            .iter()
            .map(|a| a.to_string_lossy().into_owned())
            .collect();
        if n < SAVED_FAILURES {
            let saved = failures_dir.join(format!("{n:04}"));
            std::fs::create_dir_all(&saved).unwrap();
            for f in &case.files {
                let to = saved.join(f.file_name().unwrap());
                let meta = std::fs::symlink_metadata(f);
                // A symlink, a FIFO or a file of hundreds of megabytes is described, not
                // copied.
                match meta {
                    Ok(m) if m.file_type().is_file() && m.len() < 64 << 20 => {
                        let _ = std::fs::copy(f, &to);
                    }
                    Ok(m) => {
                        let what = match std::fs::read_link(f) {
                            Ok(t) => format!("a symlink to {}\n", t.display()),
                            Err(_) => format!("{:?}, {} bytes\n", m.file_type(), m.len()),
                        };
                        let _ = std::fs::write(to.with_extension("txt"), what);
                    }
                    Err(_) => {}
                }
                for a in &mut args {
                    if Path::new(a.as_str()) == f.as_path() {
                        *a = to.display().to_string();
                    }
                }
            }
        }
        let what = format!(
            "[{}] autotune {}{note}: {}",
            case.kind,
            args.join(" "),
            f.detail
        );
        let e = self
            .classes
            .entry((case.kind.clone(), f.symptom))
            .or_insert((0, what));
        e.0 += 1;
    }

    pub fn summary(&self, part: &str, seed: u64, seconds: f64, elapsed: f64, inputs: usize) {
        eprintln!(
            "fuzz inputs {part} (seed {seed}, {seconds:.1} s): {inputs} inputs in {elapsed:.1} s ({:.1}/s), {} binary runs (exit 0/1/2: {}/{}/{}); slowest run {:.2} s ({}); most memory {} MB ({}); {} failures",
            inputs as f64 / elapsed.max(1e-9),
            self.runs,
            self.exits[0],
            self.exits[1],
            self.exits[2],
            self.slowest.0,
            self.slowest.1,
            self.max_rss.0,
            self.max_rss.1,
            self.failures
        );
    }

    /// The failures, one line per (kind, symptom) with its count and first example.
    pub fn report(&self) -> String {
        let mut s = String::new();
        for ((kind, symptom), (n, first)) in &self.classes {
            s += &format!("\n{kind} → {symptom} (×{n})\n    {first}");
        }
        s
    }
}

/// Add `t`'s counts to `all`.
pub fn merge(all: &mut Tally, t: Tally) {
    all.runs += t.runs;
    for i in 0..3 {
        all.exits[i] += t.exits[i];
    }
    if t.slowest.0 > all.slowest.0 {
        all.slowest = t.slowest;
    }
    if t.max_rss.0 > all.max_rss.0 {
        all.max_rss = t.max_rss;
    }
    all.failures += t.failures;
    for (k, (n, first)) in t.classes {
        let e = all.classes.entry(k).or_insert((0, first));
        e.0 += n;
    }
}
