//! A fuzzer for `autotune nis`, the field-log readers (`src/fieldlog/`), in the style of
//! `tests/fuzz/loaders.rs`: on stable Rust, inside the suite, from a fixed seed.
//!
//! 1. Generic field logs: CSV and JSON Lines logs are built here (several sensors of 1 to 3
//!    components, S full, lower, upper or diagonal, precomputed `nis` + `dof` rows) and
//!    mutated: cells replaced by extreme numbers (1e308, -0, NaN, inf, 1e-320, huge
//!    integers), empty cells, quotes and bytes that are not UTF-8; rows and columns deleted,
//!    duplicated or reordered; the header renamed; times made decreasing; dimensions changed
//!    mid-file; JSON values of another type; bytes flipped, the text cut short.
//! 2. PX4 ULog: the fixtures `legacy_ekf2.ulg`, `white_new.ulg` and `v1_15_events.ulg` are
//!    walked message by message (16-byte header, then `u16 size`, `u8 type`, payload) and
//!    mutated structurally (a message's size or type byte, a `msg_id` in 'D' and 'A', the
//!    field types and array sizes of an 'F' format, a subscription duplicated under another
//!    format, topic names swapped, messages deleted, duplicated or moved, the flag bits and
//!    appended-data offsets, crafted short messages) or byte by byte; a few inputs are built
//!    to cost memory or time (huge or zero-sized nested arrays, thousands of subscriptions,
//!    thousands of channels in many instances).
//! 3. `--follow` (`--for 1` or `--idle 1`) on a mutated CSV / JSON Lines log written in two
//!    parts while it is followed, shrunk, or never written; a few runs only, each costs a
//!    second or two.
//!
//! Every input goes to the binary (`autotune nis FILE --json`, with and without
//! `--skip-bad-rows`, `--allow-truncated`, `--in-air`), which must exit 0, 1 or 2, print no
//! panic, print an error as one line naming the file, print valid JSON with `--json`, stay
//! under 30 s and under [`RSS_LIMIT_MB`] of memory (a memory limit of the address space
//! makes a runaway allocation abort); inputs the binary survived also go to
//! `autotune::internals::fieldlog::analyze` in-process (and the reports are rendered), which must
//! return `Ok` or `Err`, never panic.
//!
//! It runs for `AUTOTUNE_FUZZ_SECONDS` (default 8 s, split 40 / 40 / 20 % among the three
//! parts) from seed `AUTOTUNE_FUZZ_SEED` (default 1), and reports the inputs tried per
//! second. Failing inputs are saved under the cargo target's temporary directory
//! (`fuzz-failures-fieldlog-*/`) and printed. To fuzz longer:
//!
//! ```text
//! AUTOTUNE_FUZZ_SECONDS=600 AUTOTUNE_FUZZ_SEED=7 cargo test --release --test fuzz -- fieldlog:: --nocapture
//! ```

use std::ffi::OsString;
use std::panic::AssertUnwindSafe;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use autotune::internals::fieldlog::{NisSettings, ReadOptions, Window, analyze};

use crate::fuzzing;
use fuzzing::{Rng, proc_status_kb, settings, spawn_limited};

/// How long a batch run may take: the inputs are at most a few megabytes, read in well
/// under a second; a run this long is a hang the input caused.
const PROCESS_LIMIT: Duration = Duration::from_secs(30);
/// How long a `--follow --for 1` / `--idle 1` run may take.
const FOLLOW_LIMIT: Duration = Duration::from_secs(10);
/// The address space a run may map: beyond, an allocation fails and the process aborts
/// (a failure), instead of the machine swapping.
const ADDRESS_SPACE: u64 = 4 << 30;
/// The resident memory a run may reach on these small inputs.
const RSS_LIMIT_MB: u64 = 400;

// ---------------------------------------------------------------------------------------
// Shared: running the binary (the random numbers and the settings: common/fuzzing.rs).

/// A binary run under way.
struct Running {
    child: Child,
    out: JoinHandle<Vec<u8>>,
    err: JoinHandle<Vec<u8>>,
    start: Instant,
}

/// How a run ended.
struct Outcome {
    code: usize,
    /// The error line of an exit 2.
    error: String,
    seconds: f64,
    rss_mb: u64,
}

/// Start the binary with `args` in `dir`, its address space limited.
fn spawn(dir: &Path, args: &[OsString]) -> Running {
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_autotune"));
    cmd.current_dir(dir)
        .args(args)
        .env("NO_COLOR", "1")
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped());
    let (child, out, err) = spawn_limited(&mut cmd, ADDRESS_SPACE);
    Running {
        child,
        out,
        err,
        start: Instant::now(),
    }
}

impl Running {
    /// Wait for the run (at most `limit`); a failure if it exits other than 0, 1 or 2,
    /// prints a panic, prints an error on more than one line or without `names` (the
    /// input's file name), prints invalid JSON with `json`, hangs, or takes too much memory.
    fn finish(mut self, limit: Duration, json: bool, names: &[&str]) -> Result<Outcome, String> {
        let pid = self.child.id() as libc::pid_t;
        let mut status = 0;
        // The child's peak memory, read while it runs (its ru_maxrss would count the memory
        // of this process, which it was forked from; growing memory takes far longer than
        // the 2 ms between looks).
        let mut hwm_kb = 0;
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
            if self.start.elapsed() > limit {
                let _ = self.child.kill();
                // SAFETY: as above, blocking until the killed child is reaped.
                unsafe { libc::waitpid(pid, &mut status, 0) };
                return Err(format!("still running after {limit:?}"));
            }
            std::thread::sleep(Duration::from_millis(2));
        }
        let seconds = self.start.elapsed().as_secs_f64();
        let stdout = self.out.join().unwrap();
        let stderr = String::from_utf8_lossy(&self.err.join().unwrap()).into_owned();
        let code = libc::WIFEXITED(status).then(|| libc::WEXITSTATUS(status));
        let rss_mb = hwm_kb / 1024;
        if stderr.contains("panicked") || !matches!(code, Some(0..=2)) {
            let signal = libc::WIFSIGNALED(status).then(|| libc::WTERMSIG(status));
            return Err(format!(
                "exit {code:?} (signal {signal:?}, {rss_mb} MB): {}",
                stderr.trim_end()
            ));
        }
        if code == Some(2)
            && (stderr.lines().count() != 1
                || !stderr.starts_with("error: ")
                || !names.iter().any(|n| stderr.contains(n)))
        {
            return Err(format!(
                "exit 2 without a one-line error naming {names:?}: {stderr:?}"
            ));
        }
        if code != Some(2) && json && serde_json::from_slice::<serde_json::Value>(&stdout).is_err()
        {
            return Err(format!(
                "exit {code:?} with --json, and stdout is not JSON: {:?}",
                String::from_utf8_lossy(&stdout[..stdout.len().min(300)])
            ));
        }
        if rss_mb > RSS_LIMIT_MB {
            return Err(format!(
                "{rss_mb} MB of memory (more than {RSS_LIMIT_MB} MB)"
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
}

/// The reports in-process: `analyze` must return `Ok` or `Err`, and an `Ok` report must
/// serialize and render; never a panic.
fn analyze_in_process(
    paths: &[PathBuf],
    options: &ReadOptions,
    settings: NisSettings,
    render: bool,
) -> Result<bool, String> {
    let result = std::panic::catch_unwind(AssertUnwindSafe(|| {
        let r = analyze(paths, options, settings)?;
        let _ = serde_json::to_string_pretty(&r).expect("the report serializes");
        if render {
            let _ = autotune::report::nis::nis_summary_text(&r);
            let _ = autotune::report::nis::nis_markdown(&r);
            let _ = autotune::report::nis::nis_junit_xml(&r);
            let _ = autotune::report::nis::html::nis_html(&r);
        }
        Ok::<_, autotune::internals::input::FileError>(())
    }));
    match result {
        Ok(Ok(())) => Ok(true),
        Ok(Err(e)) => {
            let text = e.to_string();
            if text.lines().count() != 1 {
                return Err(format!("in-process error on several lines: {text:?}"));
            }
            Ok(false)
        }
        Err(p) => Err(format!(
            "in-process analyze panicked: {}",
            p.downcast_ref::<String>()
                .cloned()
                .or_else(|| p.downcast_ref::<&str>().map(|s| s.to_string()))
                .unwrap_or_default()
        )),
    }
}

/// Random test settings, for the binary (flags) and in-process alike.
fn random_settings(rng: &mut Rng) -> (Vec<OsString>, NisSettings) {
    let mut flags: Vec<OsString> = Vec::new();
    let mut s = NisSettings::default();
    if rng.chance(0.2) {
        let lags = *rng.pick(&[1usize, 2, 10, 100]);
        flags.extend(["--lags".into(), lags.to_string().into()]);
        s = s.with_lags(lags).unwrap();
    }
    if rng.chance(0.2) {
        let (text, w) = *rng.pick(&[
            ("2", Window::Updates(2)),
            ("1000000", Window::Updates(1_000_000)),
            ("0.05s", Window::Seconds(0.05)),
            ("10s", Window::Seconds(10.0)),
            ("1e300s", Window::Seconds(1e300)),
        ]);
        flags.extend(["--window".into(), text.into()]);
        s = s.with_window(w).unwrap();
    }
    if rng.chance(0.1) {
        let (a, g) = *rng.pick(&[(0.5, 0.01), (1e-9, 1e-12), (0.05, 1e-12)]);
        flags.extend([
            "--alpha".into(),
            a.to_string().into(),
            "--gate".into(),
            g.to_string().into(),
        ]);
        s = s.with_alpha(a).unwrap().with_gate(g).unwrap();
    }
    (flags, s)
}

/// What a fuzz loop keeps about its runs.
#[derive(Default)]
struct Tally {
    inputs: usize,
    runs: usize,
    exits: [usize; 3],
    in_process_ok: usize,
    failures: Vec<String>,
    /// The slowest run: seconds and what it was.
    slowest: (f64, String),
    /// The run of most memory: megabytes and what it was.
    max_rss: (u64, String),
    /// The errors seen, by shape (digits and the directory left out): count and example.
    errors: std::collections::BTreeMap<String, (usize, String)>,
}

impl Tally {
    /// Count a run of `args` on `files`; the slowest and the most memory-hungry inputs are
    /// kept in `keep/slowest` and `keep/memory` (not failures: to look at).
    fn ran(&mut self, o: &Outcome, args: &[OsString], files: &[PathBuf], keep: &Path) {
        self.runs += 1;
        self.exits[o.code] += 1;
        if o.code == 2 {
            let text = match o.error.find("tmp") {
                Some(at) => &o.error[at..],
                None => &o.error,
            };
            let shape: String = text
                .chars()
                .filter(|c| !c.is_ascii_digit())
                .take(90)
                .collect();
            let e = self.errors.entry(shape).or_insert((0, o.error.clone()));
            e.0 += 1;
        }
        let what = || {
            let a: Vec<String> = args
                .iter()
                .map(|a| a.to_string_lossy().into_owned())
                .collect();
            a.join(" ")
        };
        let save = |sub: &str| {
            let d = keep.join(sub);
            let _ = std::fs::remove_dir_all(&d);
            std::fs::create_dir_all(&d).unwrap();
            for f in files {
                let _ = std::fs::copy(f, d.join(f.file_name().unwrap()));
            }
        };
        if o.rss_mb > self.max_rss.0 {
            self.max_rss = (o.rss_mb, what());
            save("memory");
        }
        if o.seconds > self.slowest.0 {
            self.slowest = (o.seconds, what());
            save("slowest");
        }
    }

    fn summary(&self, name: &str, seed: u64, seconds: f64, elapsed: f64) {
        // AUTOTUNE_FUZZ_VERBOSE=1: every kind of error seen, to read them over.
        if std::env::var_os("AUTOTUNE_FUZZ_VERBOSE").is_some() {
            for (n, example) in self.errors.values() {
                eprintln!("{name} error ×{n}: {example}");
            }
        }
        eprintln!(
            "fuzz {name} (seed {seed}, {seconds:.1} s): {} inputs in {elapsed:.1} s ({:.1}/s), {} binary runs (exit 0/1/2: {}/{}/{}), {} in-process reports; slowest run {:.2} s ({}); most memory {} MB ({}); {} failures",
            self.inputs,
            self.inputs as f64 / elapsed,
            self.runs,
            self.exits[0],
            self.exits[1],
            self.exits[2],
            self.in_process_ok,
            self.slowest.0,
            self.slowest.1,
            self.max_rss.0,
            self.max_rss.1,
            self.failures.len()
        );
        assert!(
            self.failures.is_empty(),
            "{} inputs failed:\n{}",
            self.failures.len(),
            self.failures.join("\n")
        );
    }
}

/// This part's share of the budget: its seconds and its deadline.
fn share(seconds: f64, part: f64) -> (f64, Instant) {
    (
        seconds * part,
        Instant::now() + Duration::from_secs_f64(seconds * part),
    )
}

/// Save `files` into `dir/<n>/` and describe the failure with the saved paths.
fn save_failure(dir: &Path, n: usize, args: &[OsString], files: &[PathBuf], e: &str) -> String {
    let saved = dir.join(format!("{n:04}"));
    std::fs::create_dir_all(&saved).unwrap();
    let mut shown = Vec::new();
    for a in args {
        let p = Path::new(a);
        match files.iter().find(|f| f.as_path() == p) {
            Some(f) => {
                let to = saved.join(f.file_name().unwrap());
                let _ = std::fs::copy(f, &to);
                shown.push(to.display().to_string());
            }
            None => shown.push(a.to_string_lossy().into_owned()),
        }
    }
    let e: String = e.chars().take(2000).collect();
    format!("autotune {}: {e}", shown.join(" "))
}

// ---------------------------------------------------------------------------------------
// Part 1: generic CSV and JSON Lines field logs.

/// How a row gives S.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Form {
    Full,
    Lower,
    Upper,
    Diag,
}

struct Sensor {
    name: &'static str,
    dim: usize,
    /// Precomputed `nis` and `dof` instead of ν and S.
    nis_only: bool,
}

struct Row {
    time: f64,
    sensor: usize,
    nu: Vec<f64>,
    /// m × m, row-major.
    s: Vec<f64>,
    form: Form,
    nis: f64,
}

const SENSOR_NAMES: &[&str] = &[
    "gps",
    "baro",
    "mag",
    "flow",
    "ekf0.gps_hpos[1]",
    "range finder",
    "vision_pos",
    "é",
];

/// A seed log: 1 to 4 sensors, 5 to 100 rows (sometimes thousands).
fn seed_log(rng: &mut Rng) -> (Vec<Sensor>, Vec<Row>) {
    let mut names: Vec<&'static str> = SENSOR_NAMES.to_vec();
    let n = 1 + rng.below(4);
    let mut sensors = Vec::new();
    for _ in 0..n {
        let name = names.remove(rng.below(names.len()));
        sensors.push(Sensor {
            name,
            dim: 1 + rng.below(3),
            nis_only: rng.chance(0.2),
        });
    }
    let rows_n = if rng.chance(0.02) {
        3000 + rng.below(20000)
    } else {
        5 + rng.below(96)
    };
    // Times in whole hundredths, so that every way of printing them keeps their order.
    let mut ticks = rng.below(1000);
    let mut rows = Vec::with_capacity(rows_n);
    for _ in 0..rows_n {
        if !rng.chance(0.1) {
            ticks += 1 + rng.below(10);
        }
        let t = ticks as f64 / 100.0;
        let sensor = rng.below(n);
        let m = sensors[sensor].dim;
        // In thousandths, so that every way of printing them gives the same number (S
        // symmetric to the last bit).
        let r3 = |v: f64| (v * 1000.0).round() / 1000.0;
        let nu: Vec<f64> = (0..m).map(|_| r3((rng.unit() - 0.5) * 4.0)).collect();
        let mut s = vec![0.0; m * m];
        for i in 0..m {
            s[i * m + i] = r3(0.5 + 2.0 * rng.unit());
            for j in 0..i {
                let v = r3(0.1 * (rng.unit() - 0.5));
                s[i * m + j] = v;
                s[j * m + i] = v;
            }
        }
        let nis = (0..m).map(|j| nu[j] * nu[j] / s[j * m + j]).sum();
        let form = *rng.pick(&[Form::Full, Form::Lower, Form::Upper, Form::Diag]);
        rows.push(Row {
            time: t,
            sensor,
            nu,
            s,
            form,
            nis,
        });
    }
    (sensors, rows)
}

/// A number as a log writer might print it.
fn num(v: f64, rng: &mut Rng) -> String {
    match rng.below(4) {
        0 => format!("{v:e}"),
        1 => format!("{v:.3}"),
        _ => format!("{v:?}"),
    }
}

/// The CSV text of a seed log, as lines of cells.
fn csv_cells(sensors: &[Sensor], rows: &[Row], rng: &mut Rng) -> Vec<Vec<Vec<u8>>> {
    let big_m = sensors
        .iter()
        .filter(|s| !s.nis_only)
        .map(|s| s.dim)
        .max()
        .unwrap_or(0);
    let hform = *rng.pick(&[Form::Full, Form::Lower, Form::Upper, Form::Diag]);
    let in_header = |i: usize, j: usize| match hform {
        Form::Full => true,
        Form::Lower => i >= j,
        Form::Upper => i <= j,
        Form::Diag => i == j,
    };
    let has_nis = sensors.iter().any(|s| s.nis_only) || (big_m == 0) || rng.chance(0.2);
    let mut head: Vec<String> = vec!["time".into(), "sensor".into()];
    head.extend((1..=big_m).map(|j| format!("nu_{j}")));
    for i in 1..=big_m {
        for j in 1..=big_m {
            if in_header(i, j) {
                head.push(format!("S_{i}_{j}"));
            }
        }
    }
    if has_nis {
        head.extend(["nis".into(), "dof".into()]);
    }
    // Columns in another order now and then: they are found by name.
    let mut order: Vec<usize> = (0..head.len()).collect();
    if rng.chance(0.2) {
        for k in (1..order.len()).rev() {
            order.swap(k, rng.below(k + 1));
        }
    }
    let mut lines = vec![
        order
            .iter()
            .map(|&c| head[c].clone().into_bytes())
            .collect(),
    ];
    for r in rows {
        let sensor = &sensors[r.sensor];
        let mut cells: Vec<String> = vec![num(r.time, rng), sensor.name.to_string()];
        cells.resize(head.len(), String::new());
        if sensor.nis_only {
            if has_nis {
                let c = head.len() - 2;
                cells[c] = num(r.nis, rng);
                cells[c + 1] = sensor.dim.to_string();
            }
        } else {
            let m = sensor.dim;
            let form = if hform == Form::Full || r.form == Form::Diag {
                r.form
            } else {
                hform
            };
            let filled = |i: usize, j: usize| match form {
                Form::Full => true,
                Form::Lower => i >= j,
                Form::Upper => i <= j,
                Form::Diag => i == j,
            };
            for j in 0..m {
                cells[2 + j] = num(r.nu[j], rng);
            }
            for (c, h) in head.iter().enumerate() {
                if let Some(rest) = h.strip_prefix("S_") {
                    let (i, j) = rest.split_once('_').unwrap();
                    let (i, j): (usize, usize) = (i.parse().unwrap(), j.parse().unwrap());
                    if i <= m && j <= m && filled(i, j) {
                        cells[c] = num(r.s[(i - 1) * m + (j - 1)], rng);
                    }
                }
            }
        }
        lines.push(
            order
                .iter()
                .map(|&c| cells[c].clone().into_bytes())
                .collect(),
        );
    }
    lines
}

/// The JSON Lines text of a seed log, as lines.
fn jsonl_lines(sensors: &[Sensor], rows: &[Row], rng: &mut Rng) -> Vec<Vec<u8>> {
    let mut out = Vec::new();
    for r in rows {
        let sensor = &sensors[r.sensor];
        let name = serde_json::to_string(sensor.name).unwrap();
        let mut parts = vec![
            format!("\"time\": {}", num(r.time, rng)),
            format!("\"sensor\": {name}"),
        ];
        if sensor.nis_only {
            parts.push(format!("\"nis\": {}", num(r.nis, rng)));
            parts.push(format!("\"dof\": {}", sensor.dim));
        } else {
            let m = sensor.dim;
            let nu: Vec<String> = r.nu.iter().map(|&v| num(v, rng)).collect();
            parts.push(format!("\"nu\": [{}]", nu.join(", ")));
            let s = match r.form {
                Form::Diag => {
                    let d: Vec<String> = (0..m).map(|i| num(r.s[i * m + i], rng)).collect();
                    format!("[{}]", d.join(", "))
                }
                Form::Lower => {
                    let rows: Vec<String> = (0..m)
                        .map(|i| {
                            let v: Vec<String> =
                                (0..=i).map(|j| num(r.s[i * m + j], rng)).collect();
                            format!("[{}]", v.join(", "))
                        })
                        .collect();
                    format!("[{}]", rows.join(", "))
                }
                Form::Full | Form::Upper => {
                    let rows: Vec<String> = (0..m)
                        .map(|i| {
                            let v: Vec<String> = (0..m).map(|j| num(r.s[i * m + j], rng)).collect();
                            format!("[{}]", v.join(", "))
                        })
                        .collect();
                    format!("[{}]", rows.join(", "))
                }
            };
            parts.push(format!("\"S\": {s}"));
        }
        if rng.chance(0.1) {
            for k in (1..parts.len()).rev() {
                parts.swap(k, rng.below(k + 1));
            }
        }
        out.push(format!("{{{}}}", parts.join(", ")).into_bytes());
    }
    out
}

/// CSV cells that have broken readers before.
const CELLS: &[&[u8]] = &[
    b"",
    b"NaN",
    b"nan",
    b"inf",
    b"-inf",
    b"Infinity",
    b"-0",
    b"-0.0",
    b"0",
    b"1",
    b"3",
    b"64",
    b"65",
    b"1000001",
    b"1e308",
    b"-1e308",
    b"1.7976931348623157e308",
    b"1e-320",
    b"4.9e-324",
    b"1e400",
    b"123456789012345678901234567890",
    b"18446744073709551616",
    b"9007199254740993",
    b"\"\"",
    b"\"",
    b"\"1\"",
    b"\"a,b\"",
    b"\"x\ny\"",
    b"\"x\ry\"",
    b"\xff\xfe",
    b"\xc3",
    b" 1 ",
    b"1_000",
    b"0x10",
    b"+1",
    b".5",
    b"5.",
    b"1e",
    b"--1",
    b"\t",
    b"garbage",
    b"gps",
    b"baro",
    b"a\x07b",
    b"xxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxx",
];

/// Header names a column may be renamed to.
const HEADER_NAMES: &[&[u8]] = &[
    b"time",
    b"sensor",
    b"nu_1",
    b"nu_2",
    b"nu_3",
    b"nu_4",
    b"nu_0",
    b"nu_64",
    b"nu_65",
    b"nu_99999999999999999999",
    b"nu_1_1",
    b"nu_01",
    b"nu_+1",
    b"S_1_1",
    b"S_2_1",
    b"S_1_2",
    b"S_3_3",
    b"S_4_4",
    b"S_64_64",
    b"S_65_1",
    b"S_1",
    b"S_0_0",
    b"S_-1_1",
    b"nis",
    b"dof",
    b"Time",
    b"",
    b"\"time\"",
    b"\"a\nb\"",
    b"\"a\rb\"",
    b"\xff",
    b"sensor ",
    b"run",
    b"step",
    b"nu_r_1",
    b"nu_r_3",
    b"S_r_1_1",
    b"S_r_2_2",
    b"S_r_99999_1",
    b"nis_r",
    b"nis_dof_r",
    b"u_r_1",
    b"diverged",
    b"e_1",
    b"P_1_1",
];

/// Names a row's sensor may become.
const ODD_SENSORS: &[&str] = &[
    "gps",
    "baro",
    "",
    " ",
    "a\u{7}b",
    "\u{1b}[31mred",
    "éééééééééééééééééééééééééééééééééééé",
    "xxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxx",
    "NaN",
    "\u{202e}rtl",
];

/// JSON values a number may become (as text: non-finite ones are not JSON).
const JSON_VALUES: &[&str] = &[
    "null",
    "NaN",
    "Infinity",
    "-Infinity",
    "\"x\"",
    "\"1\"",
    "[]",
    "[[1]]",
    "[1, [2]]",
    "{}",
    "true",
    "1e400",
    "-1e400",
    "1e308",
    "-1e308",
    "1e-320",
    "-0",
    "0",
    "-1",
    "64",
    "65",
    "1000001",
    "2.5",
    "123456789012345678901234567890",
    "18446744073709551616",
];

/// Byte ranges of the numbers in `b`.
fn number_spans(b: &[u8]) -> Vec<(usize, usize)> {
    let mut spans = Vec::new();
    let mut i = 0;
    while i < b.len() {
        let starts = b[i].is_ascii_digit()
            && (i == 0 || !(b[i - 1].is_ascii_alphanumeric() || b[i - 1] == b'_'));
        if starts {
            let s = if i > 0 && b[i - 1] == b'-' { i - 1 } else { i };
            let mut e = i;
            while e < b.len() && (b[e].is_ascii_alphanumeric() || b".+-".contains(&b[e])) {
                e += 1;
            }
            spans.push((s, e));
            i = e;
        } else {
            i += 1;
        }
    }
    spans
}

/// Byte ranges of the `"…"` strings in `b`.
fn string_spans(b: &[u8]) -> Vec<(usize, usize)> {
    let mut spans = Vec::new();
    let mut start = None;
    for (i, &c) in b.iter().enumerate() {
        if c == b'"' && (i == 0 || b[i - 1] != b'\\') {
            match start.take() {
                None => start = Some(i),
                Some(s) => spans.push((s, i + 1)),
            }
        }
    }
    spans
}

/// Byte-level damage: a byte changed, bytes deleted, inserted or duplicated.
fn mutate_bytes(b: &mut Vec<u8>, rng: &mut Rng) {
    if b.is_empty() {
        b.push(*rng.pick(b"0,\n{"));
        return;
    }
    match rng.below(5) {
        0 => {
            let i = rng.below(b.len());
            b[i] = *rng.pick(b",;\"\n\r {}[]:0123456789.-eE\\\x00\xff\xc3");
        }
        1 => {
            let i = rng.below(b.len());
            b[i] ^= 1 << rng.below(8);
        }
        2 => {
            let i = rng.below(b.len());
            let n = 1 + rng.below(16);
            b.drain(i..(i + n).min(b.len()));
        }
        3 => {
            let i = rng.below(b.len());
            let n = 1 + rng.below(8);
            let junk: Vec<u8> = (0..n).map(|_| rng.next() as u8).collect();
            b.splice(i..i, junk);
        }
        _ => {
            let i = rng.below(b.len());
            let n = 1 + rng.below(60);
            let piece = b[i..(i + n).min(b.len())].to_vec();
            let at = rng.below(b.len());
            b.splice(at..at, piece);
        }
    }
}

/// The column of CSV line cells named `name`.
fn column(lines: &[Vec<Vec<u8>>], name: &[u8]) -> Option<usize> {
    lines.first()?.iter().position(|c| c == name)
}

/// Mutate CSV lines of cells.
fn mutate_csv(lines: &mut Vec<Vec<Vec<u8>>>, rng: &mut Rng) {
    if lines.len() < 2 || lines[0].is_empty() {
        lines.push(vec![b"0".to_vec(), b"gps".to_vec()]);
        return;
    }
    let data_row = |rng: &mut Rng, n: usize| 1 + rng.below(n - 1);
    match rng.below(16) {
        0..=3 => {
            let i = data_row(rng, lines.len());
            if !lines[i].is_empty() {
                let j = rng.below(lines[i].len());
                lines[i][j] = rng.pick(CELLS).to_vec();
            }
        }
        4 => {
            let j = rng.below(lines[0].len());
            lines[0][j] = rng.pick(HEADER_NAMES).to_vec();
        }
        5 => {
            let i = rng.below(lines.len());
            lines.remove(i);
        }
        6 => {
            let i = data_row(rng, lines.len());
            let l = lines[i].clone();
            let at = 1 + rng.below(lines.len());
            lines.insert(at, l);
        }
        7 => {
            let i = data_row(rng, lines.len());
            let l = lines.remove(i);
            let at = rng.below(lines.len() + 1);
            lines.insert(at, l);
        }
        8 => {
            // A column deleted, duplicated, or two swapped, in every line.
            let j = rng.below(lines[0].len());
            let k = rng.below(lines[0].len());
            let op = rng.below(3);
            for l in lines.iter_mut() {
                if j >= l.len() || k >= l.len() {
                    continue;
                }
                match op {
                    0 => {
                        l.remove(j);
                    }
                    1 => {
                        let c = l[j].clone();
                        l.insert(k, c);
                    }
                    _ => l.swap(j, k),
                }
            }
        }
        9 => {
            // Times made decreasing: a row set before the one above, or a block reversed.
            if let Some(t) = column(lines, b"time") {
                if rng.chance(0.5) {
                    let i = data_row(rng, lines.len());
                    if t < lines[i].len() {
                        lines[i][t] = rng.pick(&[&b"-1"[..], b"0", b"-1e308", b"1e-320"]).to_vec();
                    }
                } else {
                    let a = data_row(rng, lines.len());
                    let b = (a + 2 + rng.below(20)).min(lines.len());
                    lines[a..b].reverse();
                }
            }
        }
        10 => {
            // The dimension changed mid-file: a row's last innovation cleared, or one more
            // filled (with its variance).
            let i = data_row(rng, lines.len());
            let nus: Vec<usize> = (1..=4)
                .filter_map(|j| column(lines, format!("nu_{j}").as_bytes()))
                .collect();
            if let Some(&last) = nus
                .iter()
                .rev()
                .find(|&&c| lines[i].get(c).is_some_and(|v| !v.is_empty()))
            {
                if rng.chance(0.5) {
                    lines[i][last] = Vec::new();
                } else if let Some(&next) = nus
                    .iter()
                    .find(|&&c| lines[i].get(c).is_some_and(|v| v.is_empty()))
                {
                    lines[i][next] = b"0.5".to_vec();
                    let k = nus.iter().position(|&c| c == next).unwrap() + 1;
                    if let Some(s) = column(lines, format!("S_{k}_{k}").as_bytes())
                        && s < lines[i].len()
                    {
                        lines[i][s] = b"1.5".to_vec();
                    }
                }
            }
        }
        11 => {
            if let Some(c) = column(lines, b"sensor") {
                let i = data_row(rng, lines.len());
                if c < lines[i].len() {
                    lines[i][c] = rng.pick(ODD_SENSORS).as_bytes().to_vec();
                }
            }
        }
        12 => {
            // A cell too many or too few.
            let i = rng.below(lines.len());
            if rng.chance(0.5) || lines[i].is_empty() {
                lines[i].push(rng.pick(CELLS).to_vec());
            } else {
                lines[i].pop();
            }
        }
        13 => {
            // A precomputed row: nis and dof filled, innovations cleared.
            let (Some(n), Some(d)) = (column(lines, b"nis"), column(lines, b"dof")) else {
                return;
            };
            let i = data_row(rng, lines.len());
            if n < lines[i].len() && d < lines[i].len() {
                lines[i][n] = rng.pick(CELLS).to_vec();
                lines[i][d] = rng
                    .pick(&[
                        &b"0"[..],
                        b"1",
                        b"2.5",
                        b"1000000",
                        b"1000001",
                        b"-1",
                        b"1e308",
                    ])
                    .to_vec();
            }
        }
        _ => {
            // Many rows of the same sensor at the same time, or far apart in time.
            if let Some(t) = column(lines, b"time") {
                let v = rng
                    .pick(&[&b"1e308"[..], b"1.7976931348623157e308", b"1e15", b"0"])
                    .to_vec();
                for l in lines.iter_mut().skip(1 + rng.below(3)) {
                    if t < l.len() {
                        l[t] = v.clone();
                    }
                }
            }
        }
    }
}

/// Mutate a JSON Lines line as a JSON tree; false when it is not an object.
fn mutate_json_tree(line: &mut Vec<u8>, rng: &mut Rng) -> bool {
    use serde_json::{Value, json};
    let Ok(Value::Object(mut o)) = serde_json::from_slice::<Value>(line) else {
        return false;
    };
    let keys: Vec<String> = o.keys().cloned().collect();
    match rng.below(9) {
        0 => {
            if !keys.is_empty() {
                o.remove(rng.pick(&keys));
            }
        }
        1 => {
            if let Some(Value::Array(nu)) = o.get_mut("nu") {
                if rng.chance(0.5) {
                    nu.push(json!(0.5));
                } else {
                    nu.pop();
                }
            }
        }
        2 => {
            if let Some(Value::Array(s)) = o.get_mut("S") {
                match rng.below(5) {
                    0 => {
                        s.pop();
                    }
                    1 => s.push(json!([1.0, 0.0, 0.0, 0.0])),
                    2 => {
                        if !s.is_empty() {
                            let i = rng.below(s.len());
                            s[i] = json!(2.0);
                        }
                    }
                    3 => {
                        if let Some(Value::Array(r)) = s.last_mut() {
                            r.push(json!(0.25));
                        }
                    }
                    _ => *s = vec![json!([[[1.0]]])],
                }
            }
        }
        3 => {
            let v = *rng.pick(&[-1.0, 0.0, -1e308, 1e308, 1e-320]);
            o.insert("time".into(), json!(v));
        }
        4 => {
            o.insert("sensor".into(), json!(rng.pick(ODD_SENSORS)));
        }
        5 => {
            let v = *rng.pick(&[0.0, 0.5, 1e6, 1e7, -1.0, 2.5, 1000001.0, 64.0, 65.0]);
            o.insert("dof".into(), json!(v));
            if !o.contains_key("nis") {
                o.insert("nis".into(), json!(1.0));
            }
            if rng.chance(0.5) {
                o.remove("nu");
            }
        }
        6 => {
            let text = rng.pick(&["null", "true", "\"x\"", "[]", "{}", "[1]", "1e300", "-5"]);
            let v: Value = serde_json::from_str(text).unwrap();
            let k = if keys.is_empty() || rng.chance(0.3) {
                "extra".to_string()
            } else {
                rng.pick(&keys).clone()
            };
            o.insert(k, v);
        }
        7 => {
            // Dimension changed: ν and S of another size, consistent with each other.
            let m = *rng.pick(&[1usize, 2, 3, 4, 64, 65]);
            let nu: Vec<f64> = (0..m).map(|i| 0.1 * i as f64).collect();
            let s: Vec<f64> = vec![1.0; m];
            o.insert("nu".into(), json!(nu));
            o.insert("S".into(), json!(s));
        }
        _ => {
            *line = rng
                .pick(&[&b"[]"[..], b"1", b"\"x\"", b"null", b"{}", b"{\"time\": 1}"])
                .to_vec();
            return true;
        }
    }
    *line = serde_json::to_vec(&Value::Object(o)).unwrap();
    true
}

/// Mutate JSON Lines lines.
fn mutate_jsonl(lines: &mut Vec<Vec<u8>>, rng: &mut Rng) {
    if lines.is_empty() {
        lines.push(b"{}".to_vec());
        return;
    }
    let i = rng.below(lines.len());
    match rng.below(10) {
        0..=2 => {
            let spans = number_spans(&lines[i]);
            if !spans.is_empty() {
                let (s, e) = *rng.pick(&spans);
                lines[i].splice(s..e, rng.pick(JSON_VALUES).bytes());
            }
        }
        3 => {
            let spans = string_spans(&lines[i]);
            if !spans.is_empty() {
                let (s, e) = *rng.pick(&spans);
                let name = rng.pick(&[
                    "\"time\"",
                    "\"sensor\"",
                    "\"nu\"",
                    "\"S\"",
                    "\"nis\"",
                    "\"dof\"",
                    "\"Time\"",
                    "\"\"",
                    "\"\\u0000\"",
                    "\"\\ud800\"",
                    "\"run\"",
                    "\"step\"",
                    "\"nu_r\"",
                    "\"S_r\"",
                    "\"nis_r\"",
                    "\"u_r\"",
                    "\"diverged\"",
                    "\"e\"",
                ]);
                lines[i].splice(s..e, name.bytes());
            }
        }
        4 => {
            lines.remove(i);
        }
        5 => {
            let l = lines[i].clone();
            let at = rng.below(lines.len() + 1);
            lines.insert(at, l);
        }
        6 => {
            let l = lines.remove(i);
            let at = rng.below(lines.len() + 1);
            lines.insert(at, l);
        }
        _ => {
            if !mutate_json_tree(&mut lines[i], rng) {
                mutate_bytes(&mut lines[i], rng);
            }
        }
    }
}

/// Join lines with a line ending, sometimes CRLF, sometimes with a BOM, blank lines, or no
/// final newline.
fn join_lines(lines: &[Vec<u8>], rng: &mut Rng) -> Vec<u8> {
    let eol: &[u8] = if rng.chance(0.1) { b"\r\n" } else { b"\n" };
    let mut out = Vec::new();
    if rng.chance(0.03) {
        out.extend("\u{feff}".as_bytes());
    }
    for l in lines {
        out.extend(l);
        out.extend(eol);
        if rng.chance(0.01) {
            out.extend(eol);
        }
    }
    if rng.chance(0.1) {
        out.truncate(out.len() - eol.len().min(out.len()));
    }
    out
}

/// Records (`docs/external.md`) that `nis` reads as a field log: 1 to 3 runs of up to 30
/// steps, a sensor `r` of 1 or 2 components (raw, or a precomputed NIS with `u`), sometimes
/// a second sensor `q`, ground truth, and a diverged run; as CSV lines of cells or JSON
/// Lines.
fn records_input(rng: &mut Rng, jsonl: bool) -> (Vec<Vec<Vec<u8>>>, Vec<Vec<u8>>) {
    let m = 1 + rng.below(2);
    let normalized = rng.chance(0.3);
    let second = rng.chance(0.3);
    let truth = rng.chance(0.3);
    let diverged = rng.chance(0.2);
    let runs = 1 + rng.below(3);
    let steps = 1 + rng.below(30);
    let mut head: Vec<String> = vec!["run".into(), "step".into()];
    if truth {
        head.extend(["e_1", "P_1_1"].map(String::from));
    }
    if normalized {
        head.extend(["nis_r".into(), "nis_dof_r".into()]);
        head.extend((1..=m).map(|j| format!("u_r_{j}")));
    } else {
        head.extend((1..=m).map(|j| format!("nu_r_{j}")));
        for a in 1..=m {
            for b in 1..=a {
                head.push(format!("S_r_{a}_{b}"));
            }
        }
    }
    if second {
        head.extend(["nu_q_1".into(), "S_q_1_1".into()]);
    }
    if diverged {
        head.push("diverged".into());
    }
    let mut csv: Vec<Vec<Vec<u8>>> = vec![head.iter().map(|h| h.clone().into_bytes()).collect()];
    let mut json = Vec::new();
    for run in 0..runs {
        for step in 1..=steps {
            let broke = diverged && run == 0 && step == steps.div_ceil(2);
            let nu: Vec<f64> = (0..m).map(|_| (rng.unit() - 0.5) * 3.0).collect();
            let measured = step == 1 || rng.chance(0.8);
            let mut row: Vec<String> = vec![run.to_string(), step.to_string()];
            let mut obj = vec![format!("\"run\": {run}"), format!("\"step\": {step}")];
            if truth {
                let e = num(rng.unit() - 0.5, rng);
                row.extend([e.clone(), "1.5".into()]);
                obj.push(format!("\"e\": [{e}], \"P\": [[1.5]]"));
            }
            let nums = |v: &[f64], rng: &mut Rng| -> Vec<String> {
                v.iter().map(|&x| num(x, rng)).collect()
            };
            if !measured {
                row.extend(std::iter::repeat_n(String::new(), head.len() - row.len()));
            } else if normalized {
                let nis: f64 = nu.iter().map(|x| x * x).sum();
                let u = nums(&nu, rng);
                row.extend([num(nis, rng), m.to_string()]);
                row.extend(u.iter().cloned());
                obj.push(format!(
                    "\"nis_r\": {}, \"nis_dof_r\": {m}, \"u_r\": [{}]",
                    num(nis, rng),
                    u.join(", ")
                ));
            } else {
                let u = nums(&nu, rng);
                row.extend(u.iter().cloned());
                let mut s_rows = Vec::new();
                for a in 0..m {
                    let mut r = Vec::new();
                    for b in 0..=a {
                        let v = if a == b { "2.0" } else { "0.25" };
                        row.push(v.into());
                        r.push(v.to_string());
                    }
                    s_rows.push(format!("[{}]", r.join(", ")));
                }
                obj.push(format!(
                    "\"nu_r\": [{}], \"S_r\": [{}]",
                    u.join(", "),
                    s_rows.join(", ")
                ));
            }
            if second {
                let q = num(rng.unit() - 0.5, rng);
                if measured {
                    row.extend([q.clone(), "0.5".into()]);
                    obj.push(format!("\"nu_q\": [{q}], \"S_q\": [[0.5]]"));
                }
            }
            row.resize(head.len() - usize::from(diverged), String::new());
            if diverged {
                row.push(if broke { "1" } else { "0" }.into());
                if broke {
                    obj.push("\"diverged\": \"P lost positive definiteness\"".into());
                }
            }
            csv.push(row.into_iter().map(String::into_bytes).collect());
            json.push(format!("{{{}}}", obj.join(", ")).into_bytes());
            if broke && rng.chance(0.7) {
                break;
            }
        }
    }
    if jsonl {
        (Vec::new(), json)
    } else {
        (csv, Vec::new())
    }
}

/// A log of many sensors of many components, one or two rows each, built to cost memory:
/// CSV lines of cells.
fn wide_input(rng: &mut Rng) -> Vec<Vec<Vec<u8>>> {
    let m = *rng.pick(&[16usize, 64]);
    let sensors = 200 + rng.below(2000);
    let mut head: Vec<Vec<u8>> = vec![b"time".to_vec(), b"sensor".to_vec()];
    head.extend((1..=m).map(|j| format!("nu_{j}").into_bytes()));
    head.extend((1..=m).map(|j| format!("S_{j}_{j}").into_bytes()));
    let mut lines = vec![head];
    for k in 0..sensors {
        for r in 0..1 + rng.below(2) {
            let mut l = vec![
                format!("{k}.{r}").into_bytes(),
                format!("s{k}").into_bytes(),
            ];
            l.extend((0..m).map(|j| format!("0.{}", (j + r) % 10).into_bytes()));
            l.extend((0..m).map(|_| b"1".to_vec()));
            lines.push(l);
        }
    }
    lines
}

/// A mutated field log: its bytes and whether it is JSON Lines.
fn text_input(rng: &mut Rng) -> (Vec<u8>, bool) {
    let jsonl = rng.chance(0.5);
    // Rare: each costs about a second.
    if rng.chance(0.002) {
        let mut csv = wide_input(rng);
        if rng.chance(0.5) {
            mutate_csv(&mut csv, rng);
        }
        let lines: Vec<Vec<u8>> = csv.iter().map(|l| l.join(&b","[..])).collect();
        return (join_lines(&lines, rng), false);
    }
    if rng.chance(0.15) {
        // Records read as a field log.
        let (mut csv, mut json) = records_input(rng, jsonl);
        let mutations = if rng.chance(0.1) { 0 } else { 1 + rng.below(3) };
        for _ in 0..mutations {
            if jsonl {
                mutate_jsonl(&mut json, rng);
            } else {
                mutate_csv(&mut csv, rng);
            }
        }
        let lines: Vec<Vec<u8>> = if jsonl {
            json
        } else {
            csv.iter().map(|l| l.join(&b","[..])).collect()
        };
        let mut bytes = join_lines(&lines, rng);
        if rng.chance(0.1) {
            mutate_bytes(&mut bytes, rng);
        }
        return (bytes, jsonl);
    }
    let (sensors, rows) = seed_log(rng);
    let mutations = if rng.chance(0.1) { 0 } else { 1 + rng.below(4) };
    let mut bytes = if jsonl {
        let mut lines = jsonl_lines(&sensors, &rows, rng);
        for _ in 0..mutations {
            mutate_jsonl(&mut lines, rng);
        }
        join_lines(&lines, rng)
    } else {
        let mut lines = csv_cells(&sensors, &rows, rng);
        for _ in 0..mutations {
            mutate_csv(&mut lines, rng);
        }
        let joined: Vec<Vec<u8>> = lines.iter().map(|l| l.join(&b","[..])).collect();
        join_lines(&joined, rng)
    };
    if rng.chance(0.15) {
        for _ in 0..1 + rng.below(3) {
            mutate_bytes(&mut bytes, rng);
        }
    }
    if rng.chance(0.05) {
        let keep = rng.below(bytes.len() + 1);
        bytes.truncate(keep);
    }
    (bytes, jsonl)
}

#[test]
fn fuzz_csv_and_json_lines_field_logs() {
    let (seconds, seed, failures_dir) = settings("fuzz-failures-fieldlog-text");
    let (seconds, deadline) = share(seconds, 0.4);
    let dir = tempfile::tempdir().unwrap();
    let mut rng = Rng(seed);
    let start = Instant::now();
    let mut t = Tally::default();
    while Instant::now() < deadline && t.failures.len() < 10 {
        t.inputs += 1;
        let (bytes, jsonl) = text_input(&mut rng);
        let ext = if jsonl {
            *rng.pick(&["jsonl", "jsonl", "ndjson", "JSONL"])
        } else {
            *rng.pick(&["csv", "csv", "csv", "CSV"])
        };
        let file = dir.path().join(format!("log.{ext}"));
        std::fs::write(&file, &bytes).unwrap();
        let mut files = vec![file.clone()];
        // Now and then a second log judged with it (a sequence break between them).
        if rng.chance(0.05) {
            let (b2, j2) = text_input(&mut rng);
            let f2 = dir
                .path()
                .join(if j2 { "second.jsonl" } else { "second.csv" });
            std::fs::write(&f2, &b2).unwrap();
            files.push(f2);
        }
        let (flags, nis_settings) = random_settings(&mut rng);
        let mut ok_everywhere = true;
        for skip in [false, true] {
            let mut args: Vec<OsString> = vec!["nis".into()];
            args.extend(files.iter().map(|f| f.clone().into_os_string()));
            args.push("--json".into());
            if skip {
                args.push("--skip-bad-rows".into());
            }
            args.extend(flags.iter().cloned());
            let names: Vec<String> = files
                .iter()
                .map(|f| f.file_name().unwrap().to_string_lossy().into_owned())
                .collect();
            let names: Vec<&str> = names.iter().map(String::as_str).collect();
            match spawn(dir.path(), &args).finish(PROCESS_LIMIT, true, &names) {
                Ok(o) => t.ran(&o, &args, &files, &failures_dir),
                Err(e) => {
                    ok_everywhere = false;
                    let n = t.failures.len();
                    t.failures
                        .push(save_failure(&failures_dir, n, &args, &files, &e));
                    break;
                }
            }
        }
        if !ok_everywhere {
            continue;
        }
        for skip in [false, true] {
            let options = ReadOptions {
                skip_bad_rows: skip,
                ..ReadOptions::default()
            };
            let render = rng.chance(0.1);
            match analyze_in_process(&files, &options, nis_settings, render) {
                Ok(true) => t.in_process_ok += 1,
                Ok(false) => {}
                Err(e) => {
                    let n = t.failures.len();
                    let args: Vec<OsString> = files.iter().map(|f| f.clone().into()).collect();
                    t.failures.push(save_failure(
                        &failures_dir,
                        n,
                        &args,
                        &files,
                        &format!("(skip_bad_rows {skip}) {e}"),
                    ));
                    break;
                }
            }
        }
    }
    t.summary("csv/jsonl", seed, seconds, start.elapsed().as_secs_f64());
}

// ---------------------------------------------------------------------------------------
// Part 2: PX4 ULog.

/// One ULog message: its type byte, payload, and a size field that lies about it.
#[derive(Clone)]
struct UMsg {
    typ: u8,
    payload: Vec<u8>,
    size: Option<u16>,
}

impl UMsg {
    fn new(typ: u8, payload: impl Into<Vec<u8>>) -> UMsg {
        UMsg {
            typ,
            payload: payload.into(),
            size: None,
        }
    }
}

/// A ULog file as its header and messages.
#[derive(Clone)]
struct Ulog {
    header: Vec<u8>,
    msgs: Vec<UMsg>,
}

fn parse_ulog(b: &[u8]) -> Ulog {
    let mut msgs = Vec::new();
    let mut i = 16;
    while i + 3 <= b.len() {
        let size = u16::from_le_bytes([b[i], b[i + 1]]) as usize;
        if i + 3 + size > b.len() {
            break;
        }
        msgs.push(UMsg::new(b[i + 2], &b[i + 3..i + 3 + size]));
        i += 3 + size;
    }
    Ulog {
        header: b[..16].to_vec(),
        msgs,
    }
}

fn render_ulog(u: &Ulog) -> Vec<u8> {
    let mut out = u.header.clone();
    for m in &u.msgs {
        let size = m
            .size
            .unwrap_or(m.payload.len().min(u16::MAX as usize) as u16);
        out.extend(size.to_le_bytes());
        out.push(m.typ);
        out.extend(&m.payload[..m.payload.len().min(u16::MAX as usize)]);
    }
    out
}

/// Topic names a format or subscription may take.
const TOPICS: &[&str] = &[
    "estimator_innovations",
    "estimator_innovation_variances",
    "ekf2_innovations",
    "vehicle_land_detected",
    "estimator_status",
    "x",
    "",
];

/// Field types a format's field may take.
const TYPES: &[&str] = &[
    "float",
    "double",
    "uint8_t",
    "char",
    "int64_t",
    "uint64_t",
    "bool",
    "int8_t",
    "int16_t",
    "nosuchtype",
    "float[2]",
    "float[0]",
    "float[-1]",
];

/// Array sizes a field may take.
const ARRAY_SIZES: &[&str] = &[
    "0", "1", "2", "3", "99999", "32767", "-1", "-32768", "1000", "65535", "16000", "x", "",
];

/// Mutate an 'F' message's `name:type field;…` text.
fn mutate_format(p: &mut Vec<u8>, names: &[String], rng: &mut Rng) {
    let text = String::from_utf8_lossy(p).into_owned();
    let Some((name, body)) = text.split_once(':') else {
        mutate_bytes(p, rng);
        return;
    };
    let mut name = name.to_string();
    let mut fields: Vec<String> = body
        .split(';')
        .filter(|f| !f.is_empty())
        .map(String::from)
        .collect();
    if fields.is_empty() {
        fields.push("float x".into());
    }
    let i = rng.below(fields.len());
    let (ty, field) = fields[i]
        .split_once(' ')
        .map(|(a, b)| (a.to_string(), b.to_string()))
        .unwrap_or_else(|| (fields[i].clone(), String::new()));
    let base = ty.split('[').next().unwrap_or("").to_string();
    match rng.below(9) {
        0 | 1 => {
            fields[i] = format!("{base}[{}] {field}", rng.pick(ARRAY_SIZES));
        }
        2 => {
            let new_ty = if rng.chance(0.3) && !names.is_empty() {
                rng.pick(names).clone()
            } else if rng.chance(0.1) {
                name.clone()
            } else {
                rng.pick(TYPES).to_string()
            };
            let suffix = ty.find('[').map_or("", |p| &ty[p..]).to_string();
            fields[i] = format!("{new_ty}{suffix} {field}");
        }
        3 => {
            let new = *rng.pick(&[
                "timestamp",
                "timestamp_sample",
                "_padding0",
                "x",
                "gps_hpos",
                "heading",
                "landed",
                "mag_innov",
                "mag_innov_var",
                "a b",
                "",
            ]);
            fields[i] = format!("{ty} {new}");
        }
        4 => {
            fields.remove(i);
        }
        5 => {
            let f = fields[i].clone();
            fields.insert(rng.below(fields.len() + 1), f);
        }
        6 => {
            let j = rng.below(fields.len());
            fields.swap(i, j);
        }
        7 => {
            name = if rng.chance(0.5) && !names.is_empty() {
                rng.pick(names).clone()
            } else {
                rng.pick(TOPICS).to_string()
            };
        }
        _ => {
            // One more field: the layout grows, the data messages no longer fit it.
            let ty = rng.pick(TYPES);
            fields.insert(rng.below(fields.len() + 1), format!("{ty} fz_extra"));
        }
    }
    *p = format!("{name}:{};", fields.join(";")).into_bytes();
}

/// The names of the 'F' formats of `u`.
fn format_names(u: &Ulog) -> Vec<String> {
    u.msgs
        .iter()
        .filter(|m| m.typ == b'F')
        .filter_map(|m| {
            let t = String::from_utf8_lossy(&m.payload).into_owned();
            t.split_once(':').map(|(n, _)| n.to_string())
        })
        .collect()
}

/// Messages that are short or lie about their contents, of every type.
fn crafted_message(rng: &mut Rng) -> UMsg {
    let (typ, payload): (u8, Vec<u8>) = match rng.below(20) {
        0 => (b'P', Vec::new()),
        1 => (b'P', vec![200, b'x']),
        2 => (b'P', b"\x07float x\x00\x00".to_vec()),
        3 => (b'P', b"\x07float x\x00\x00\x80\x7f".to_vec()),
        4 => (b'A', Vec::new()),
        5 => (b'A', vec![0]),
        6 => (b'A', vec![0, 1]),
        7 => (b'A', b"\x00\x07\x00nosuchformat".to_vec()),
        8 => (b'A', b"\x00\x07\x00\xff\xfe".to_vec()),
        9 => (b'Q', vec![1, 200]),
        10 => (b'I', vec![250, b'a']),
        11 => (b'M', vec![1, 250]),
        12 => (b'L', vec![6]),
        13 => (b'C', vec![6, 0, 0]),
        14 => (b'O', vec![1]),
        15 => (b'S', vec![0x2f]),
        16 => (b'R', vec![0]),
        17 => (b'D', vec![0]),
        18 => (
            b'F',
            rng.pick(&[
                &b"x:"[..],
                b"x",
                b":",
                b"a:b c d;",
                b"fz:float[99999] a;",
                b"fz:fz[1] a;",
            ])
            .to_vec(),
        ),
        _ => (b'B', vec![0; rng.below(48)]),
    };
    UMsg::new(typ, payload)
}

/// The index of the first message after the definitions ('A'), or the end.
fn first_subscription(u: &Ulog) -> usize {
    u.msgs
        .iter()
        .position(|m| m.typ == b'A')
        .unwrap_or(u.msgs.len())
}

/// Insert formats built to cost time or memory, before the first subscription.
fn insert_bomb(u: &mut Ulog, rng: &mut Rng) {
    let at = first_subscription(u);
    match rng.below(3) {
        0 => {
            // Zero-sized nested arrays: every level multiplies the work, not the size.
            let levels = 2 + rng.below(3);
            let mut msgs = vec![UMsg::new(b'F', &b"fz_e0:"[..])];
            for l in 1..=levels {
                msgs.push(UMsg::new(
                    b'F',
                    format!("fz_e{l}:fz_e{}[32767] a;", l - 1).into_bytes(),
                ));
            }
            u.msgs.splice(at..at, msgs);
        }
        1 => {
            // A format of 32000 fields, subscribed thousands of times.
            let n = 1000 + rng.below(60000);
            let mut msgs = vec![UMsg::new(b'F', &b"fz_big:char[32000] c;"[..])];
            for k in 0..n {
                let id = (1000 + k) as u16;
                let mut p = vec![0u8];
                p.extend(id.to_le_bytes());
                p.extend(b"fz_big");
                msgs.push(UMsg::new(b'A', p));
            }
            u.msgs.splice(at..at, msgs);
        }
        _ => {
            // Formats that nest a large one many times over, within the size limit.
            let msgs = vec![
                UMsg::new(b'F', &b"fz_leaf:uint8_t[64] v;"[..]),
                UMsg::new(b'F', &b"fz_mid:fz_leaf[16] w;"[..]),
                UMsg::new(b'F', &b"fz_top:fz_mid[63] x;"[..]),
            ];
            u.msgs.splice(at..at, msgs);
        }
    }
}

/// A log built to have many channels: the legacy topic with `width` innovations beside
/// their variances, in `instances` instances, each with `rows` rows.
fn wide_ulog(header: &[u8], width: usize, instances: usize, rows: usize) -> Ulog {
    let mut msgs = vec![UMsg::new(b'B', vec![0u8; 40])];
    msgs.push(UMsg::new(
        b'F',
        format!(
            "ekf2_innovations:uint64_t timestamp;float[{width}] w_innov;float[{width}] w_innov_var;"
        )
        .into_bytes(),
    ));
    for i in 0..instances {
        let mut p = vec![i as u8];
        p.extend((i as u16).to_le_bytes());
        p.extend(b"ekf2_innovations");
        msgs.push(UMsg::new(b'A', p));
    }
    for r in 0..rows {
        for i in 0..instances {
            let mut p = (i as u16).to_le_bytes().to_vec();
            p.extend((1_000_000 + 10_000 * r as u64).to_le_bytes());
            for k in 0..width {
                p.extend((0.1 * (k + r) as f32).to_le_bytes());
            }
            for _ in 0..width {
                p.extend(1.0f32.to_le_bytes());
            }
            msgs.push(UMsg::new(b'D', p));
        }
    }
    Ulog {
        header: header.to_vec(),
        msgs,
    }
}

/// Floats that have broken statistics before.
const FLOAT_BITS: &[f32] = &[
    f32::NAN,
    f32::INFINITY,
    f32::NEG_INFINITY,
    0.0,
    -0.0,
    1e-45,
    1e-38,
    3.4e38,
    -1.0,
    1.0,
];

/// Mutate a ULog structurally, once.
fn mutate_ulog(u: &mut Ulog, rng: &mut Rng) {
    if u.msgs.is_empty() {
        u.msgs.push(crafted_message(rng));
        return;
    }
    let names = format_names(u);
    let i = rng.below(u.msgs.len());
    let of_type = |u: &Ulog, t: u8| -> Vec<usize> {
        (0..u.msgs.len()).filter(|&k| u.msgs[k].typ == t).collect()
    };
    match rng.below(16) {
        0 => {
            let len = u.msgs[i].payload.len();
            let size = match rng.below(5) {
                0 => len.wrapping_sub(1),
                1 => len + 1,
                2 => 0,
                3 => 65535,
                _ => rng.below(65536),
            };
            u.msgs[i].size = Some(size as u16);
        }
        1 => {
            u.msgs[i].typ = *rng.pick(b"FDAIMPRSOLCQBxZ\0");
        }
        2 => {
            // A msg_id changed in a data message or a subscription.
            let ids: Vec<usize> = (0..u.msgs.len())
                .filter(|&k| matches!(u.msgs[k].typ, b'D' | b'A'))
                .collect();
            if ids.is_empty() {
                return;
            }
            let k = *rng.pick(&ids);
            let at = if u.msgs[k].typ == b'D' { 0 } else { 1 };
            let id: u16 = *rng.pick(&[0, 1, 2, 3, 4, 5, 255, 256, 0xFFFF]);
            if u.msgs[k].payload.len() >= at + 2 {
                u.msgs[k].payload[at..at + 2].copy_from_slice(&id.to_le_bytes());
            }
        }
        3 => {
            let a = of_type(u, b'A');
            if let Some(&k) = a.get(rng.below(a.len().max(1)))
                && let Some(b) = u.msgs[k].payload.first_mut()
            {
                *b = *rng.pick(&[0, 1, 2, 9, 255]);
            }
        }
        4 | 5 => {
            let f = of_type(u, b'F');
            if let Some(&k) = f.get(rng.below(f.len().max(1))) {
                mutate_format(&mut u.msgs[k].payload, &names, rng);
            }
        }
        6 => {
            // Two formats' names swapped.
            let f = of_type(u, b'F');
            if f.len() >= 2 {
                let (a, b) = (*rng.pick(&f), *rng.pick(&f));
                let ta = String::from_utf8_lossy(&u.msgs[a].payload).into_owned();
                let tb = String::from_utf8_lossy(&u.msgs[b].payload).into_owned();
                if let (Some((na, ba)), Some((nb, bb))) = (ta.split_once(':'), tb.split_once(':')) {
                    u.msgs[a].payload = format!("{nb}:{ba}").into_bytes();
                    u.msgs[b].payload = format!("{na}:{bb}").into_bytes();
                }
            }
        }
        7 => {
            // A subscription duplicated under another format's name (a new msg_id, or the
            // same).
            let a = of_type(u, b'A');
            if let Some(&k) = a.get(rng.below(a.len().max(1))) {
                let mut m = u.msgs[k].clone();
                if m.payload.len() >= 3 {
                    let name = if names.is_empty() || rng.chance(0.3) {
                        rng.pick(TOPICS).to_string()
                    } else {
                        rng.pick(&names).clone()
                    };
                    m.payload.truncate(3);
                    m.payload.extend(name.as_bytes());
                    if rng.chance(0.7) {
                        let id = 100 + rng.below(50) as u16;
                        m.payload[1..3].copy_from_slice(&id.to_le_bytes());
                    }
                    u.msgs.insert(k + 1, m);
                }
            }
        }
        8 => {
            // Two subscriptions' topic names swapped.
            let a = of_type(u, b'A');
            if a.len() >= 2 {
                let (x, y) = (*rng.pick(&a), *rng.pick(&a));
                if u.msgs[x].payload.len() >= 3 && u.msgs[y].payload.len() >= 3 {
                    let nx = u.msgs[x].payload.split_off(3);
                    let ny = u.msgs[y].payload.split_off(3);
                    u.msgs[x].payload.extend(ny);
                    u.msgs[y].payload.extend(nx);
                }
            }
        }
        9 => {
            u.msgs.remove(i);
        }
        10 => {
            let m = u.msgs[i].clone();
            u.msgs.insert(rng.below(u.msgs.len() + 1), m);
        }
        11 => {
            let m = u.msgs.remove(i);
            u.msgs.insert(rng.below(u.msgs.len() + 1), m);
        }
        12 => {
            // A data message's timestamp or a float in it.
            let d = of_type(u, b'D');
            if let Some(&k) = d.get(rng.below(d.len().max(1))) {
                let p = &mut u.msgs[k].payload;
                if rng.chance(0.4) && p.len() >= 10 {
                    let t: u64 = *rng.pick(&[0, 1, u64::MAX, 1 << 63, 123_456]);
                    p[2..10].copy_from_slice(&t.to_le_bytes());
                } else if p.len() >= 14 {
                    let slots = (p.len() - 10) / 4;
                    let at = 10 + 4 * rng.below(slots);
                    let v = *rng.pick(FLOAT_BITS);
                    p[at..at + 4].copy_from_slice(&v.to_le_bytes());
                }
            }
        }
        13 => {
            // The flag bits: incompatible flags, appended-data offsets anywhere.
            let b = of_type(u, b'B');
            if let Some(&k) = b.first() {
                let total: usize = u.msgs.iter().map(|m| m.payload.len() + 3).sum::<usize>() + 16;
                let p = &mut u.msgs[k].payload;
                if p.len() >= 40 {
                    match rng.below(3) {
                        0 => p[8 + rng.below(8)] = *rng.pick(&[1, 2, 0x80, 0xff]),
                        _ => {
                            p[8] = 1;
                            let slot = rng.below(3);
                            let off: u64 = match rng.below(4) {
                                0 => rng.below(total + 1) as u64,
                                1 => 16,
                                2 => u64::MAX,
                                _ => (total + 1000) as u64,
                            };
                            p[16 + 8 * slot..24 + 8 * slot].copy_from_slice(&off.to_le_bytes());
                        }
                    }
                }
            }
        }
        14 => {
            let m = crafted_message(rng);
            u.msgs.insert(i, m);
        }
        _ => {
            // A payload cut short or grown.
            let p = &mut u.msgs[i].payload;
            if rng.chance(0.5) {
                let keep = rng.below(p.len() + 1);
                p.truncate(keep);
            } else {
                let n = 1 + rng.below(8);
                p.extend(std::iter::repeat_n(0u8, n));
            }
        }
    }
}

#[test]
fn fuzz_px4_ulog_files() {
    let (seconds, seed, failures_dir) = settings("fuzz-failures-fieldlog-ulog");
    let (seconds, deadline) = share(seconds, 0.4);
    let data = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/px4");
    let seeds: Vec<Ulog> = ["legacy_ekf2.ulg", "white_new.ulg", "v1_15_events.ulg"]
        .iter()
        .map(|n| {
            let b = std::fs::read(data.join(n)).unwrap();
            let u = parse_ulog(&b);
            assert_eq!(render_ulog(&u), b, "{n} does not walk back to itself");
            u
        })
        .collect();
    let dir = tempfile::tempdir().unwrap();
    let mut rng = Rng(seed);
    let start = Instant::now();
    let mut t = Tally::default();
    while Instant::now() < deadline && t.failures.len() < 10 {
        t.inputs += 1;
        let mut u = if rng.chance(0.01) {
            let width = *rng.pick(&[100, 2000, 8000]);
            let instances = *rng.pick(&[1, 8, 32]);
            wide_ulog(&seeds[0].header, width, instances, 1 + rng.below(3))
        } else {
            seeds[rng.below(seeds.len())].clone()
        };
        if rng.chance(0.02) {
            insert_bomb(&mut u, &mut rng);
        }
        let structural = if rng.chance(0.1) { 0 } else { 1 + rng.below(3) };
        for _ in 0..structural {
            mutate_ulog(&mut u, &mut rng);
        }
        let mut bytes = render_ulog(&u);
        if structural == 0 || rng.chance(0.2) {
            for _ in 0..1 + rng.below(4) {
                mutate_bytes(&mut bytes, &mut rng);
            }
        }
        if rng.chance(0.05) {
            let keep = rng.below(bytes.len() + 1);
            bytes.truncate(keep);
        }
        let file = dir.path().join("log.ulg");
        std::fs::write(&file, &bytes).unwrap();
        let files = vec![file.clone()];
        let (flags, nis_settings) = random_settings(&mut rng);
        let allow = rng.chance(0.6);
        let in_air = rng.chance(0.3);
        let mut args: Vec<OsString> = vec!["nis".into(), file.clone().into(), "--json".into()];
        if allow {
            args.push("--allow-truncated".into());
        }
        if in_air {
            args.push("--in-air".into());
        }
        args.extend(flags);
        match spawn(dir.path(), &args).finish(PROCESS_LIMIT, true, &["log.ulg"]) {
            Ok(o) => t.ran(&o, &args, &files, &failures_dir),
            Err(e) => {
                let n = t.failures.len();
                t.failures
                    .push(save_failure(&failures_dir, n, &args, &files, &e));
                continue;
            }
        }
        let options = ReadOptions {
            allow_truncated: allow,
            in_air,
            ..ReadOptions::default()
        };
        let render = rng.chance(0.1);
        match analyze_in_process(&files, &options, nis_settings, render) {
            Ok(true) => t.in_process_ok += 1,
            Ok(false) => {}
            Err(e) => {
                let n = t.failures.len();
                t.failures.push(save_failure(
                    &failures_dir,
                    n,
                    &args,
                    &files,
                    &format!("(allow_truncated {allow}, in_air {in_air}) {e}"),
                ));
            }
        }
    }
    t.summary("ulog", seed, seconds, start.elapsed().as_secs_f64());
}

// ---------------------------------------------------------------------------------------
// Part 3: `--follow`.

#[test]
fn fuzz_follow_on_a_mutated_log() {
    let (seconds, seed, failures_dir) = settings("fuzz-failures-fieldlog-follow");
    let (seconds, deadline) = share(seconds, 0.2);
    let dir = tempfile::tempdir().unwrap();
    let mut rng = Rng(seed ^ 0x5EED);
    let start = Instant::now();
    let mut t = Tally::default();
    // At least one run, whatever the budget.
    while (t.inputs == 0 || Instant::now() < deadline) && t.failures.len() < 5 {
        t.inputs += 1;
        let (bytes, jsonl) = text_input(&mut rng);
        let file = dir
            .path()
            .join(if jsonl { "live.jsonl" } else { "live.csv" });
        let _ = std::fs::remove_file(&file);
        let cut = rng.below(bytes.len() + 1);
        let fifo = rng.chance(0.03);
        if fifo {
            let c = std::ffi::CString::new(file.as_os_str().as_encoded_bytes()).unwrap();
            // SAFETY: a valid NUL-terminated path.
            assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o600) }, 0);
        } else if !rng.chance(0.1) {
            std::fs::write(&file, &bytes[..cut]).unwrap();
        }
        let mut args: Vec<OsString> = vec!["nis".into(), "--follow".into(), file.clone().into()];
        match rng.below(3) {
            0 => args.extend(["--for".into(), "1".into()]),
            1 => args.extend(["--idle".into(), "1".into()]),
            _ => args.extend(["--for".into(), "2".into(), "--idle".into(), "1".into()]),
        }
        let json = rng.chance(0.5);
        if json {
            args.push("--json".into());
        }
        if rng.chance(0.5) {
            args.push("--skip-bad-rows".into());
        }
        let name = file.file_name().unwrap().to_string_lossy().into_owned();
        let running = spawn(dir.path(), &args);
        // The rest of the log while it is followed: appended (in one or two parts), the
        // file shrunk or replaced, or a line without end.
        std::thread::sleep(Duration::from_millis(100 + rng.below(400) as u64));
        if !fifo {
            let append = |b: &[u8]| {
                use std::io::Write as _;
                let mut f = std::fs::OpenOptions::new()
                    .create(true)
                    .append(true)
                    .open(&file)
                    .unwrap();
                f.write_all(b).unwrap();
            };
            match rng.below(8) {
                0 => {
                    let keep = rng.below(cut + 1);
                    let _ = std::fs::OpenOptions::new()
                        .write(true)
                        .open(&file)
                        .and_then(|f| f.set_len(keep as u64));
                }
                1 => {
                    let tmp = dir.path().join("replacement");
                    std::fs::write(&tmp, &bytes[..rng.below(bytes.len() + 1)]).unwrap();
                    std::fs::rename(&tmp, &file).unwrap();
                }
                2 => append(&vec![b'7'; (1 << 20) + 10]),
                3 => {
                    let mid = cut + rng.below(bytes.len() - cut + 1);
                    append(&bytes[cut..mid]);
                    std::thread::sleep(Duration::from_millis(300));
                    append(&bytes[mid..]);
                }
                _ => append(&bytes[cut..]),
            }
        }
        let files = vec![file.clone()];
        match running.finish(FOLLOW_LIMIT, json, &[&name]) {
            Ok(o) => t.ran(&o, &args, &files, &failures_dir),
            Err(e) => {
                let n = t.failures.len();
                let e = if fifo { format!("(a FIFO) {e}") } else { e };
                t.failures
                    .push(save_failure(&failures_dir, n, &args, &files, &e));
            }
        }
    }
    t.summary("follow", seed, seconds, start.elapsed().as_secs_f64());
}
