//! A fuzzer for the problem-file and tuned-config loaders, on stable Rust and inside the
//! suite: it mutates the shipped `problems/*.toml` and `tuned/*.toml` (bytes, lines, numbers
//! replaced by huge, negative, NaN or infinite ones, keys deleted or duplicated, values of
//! the wrong type, arrays grown and shrunk) and feeds every mutant
//!
//! - to the library's loaders (`Problem::from_toml`, `TunedConfig::load_values`), which must
//!   return `Ok` or `Err` and never panic, and
//! - to the binary, `autotune check` with tiny run counts (and sometimes `tune` with a tiny
//!   budget), which must exit 0, 1 or 2, print no panic, and print an error as one line.
//!
//! It runs for `AUTOTUNE_FUZZ_SECONDS` (default 8 s, as in `.ci/run`) from seed
//! `AUTOTUNE_FUZZ_SEED` (default 1, so a failure reproduces), and reports how many inputs
//! it tried per second. Failing inputs are saved under the cargo target's temporary
//! directory (`fuzz-failures/`) and printed. To fuzz longer, e.g. for an hour from a new seed:
//!
//! ```text
//! AUTOTUNE_FUZZ_SECONDS=3600 AUTOTUNE_FUZZ_SEED=7 cargo test --release --test fuzz -- loaders:: --nocapture
//! ```

use std::panic::AssertUnwindSafe;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use autotune::internals::problem::Problem;
use autotune::report::tuned::TunedConfig;

use crate::fuzzing;
use fuzzing::{Npy, Rng, mutate_bytes, number_spans, settings};

/// How long a binary run may take: with two runs of ten steps every shipped problem checks
/// in milliseconds, so a run this long is a hang the input caused.
const PROCESS_LIMIT: Duration = Duration::from_secs(30);

/// Numbers that have broken parsers and allocators before.
const NUMBERS: &[&str] = &[
    "0",
    "-1",
    "1",
    "2",
    "-0.0",
    "0.5",
    "1e-320",
    "1e-300",
    "1e19",
    "1e20",
    "1e308",
    "-1e308",
    "1.7976931348623157e308",
    "nan",
    "-nan",
    "inf",
    "-inf",
    "4294967296",
    "9223372036854775807",
    "-9223372036854775808",
    "1000000",
    "1000000000",
    "123456789012345678901234567890",
    "3.14159",
    "1_000",
];

/// TOML values of every type.
fn any_value(rng: &mut Rng) -> toml::Value {
    use toml::Value;
    match rng.below(12) {
        0 => Value::String(String::new()),
        1 => Value::String(
            rng.pick(&["x", "dwna", "diag", "ctrv_radar_lidar", "ekf", "\n", "é"])
                .to_string(),
        ),
        2 => Value::Boolean(rng.chance(0.5)),
        3 => Value::Integer(*rng.pick(&[0, -1, 1, 3, i64::MAX, i64::MIN, 1 << 40])),
        4 => Value::Float(*rng.pick(&[
            0.0,
            -0.0,
            -1.0,
            1e-320,
            1e308,
            f64::MAX,
            f64::NAN,
            f64::INFINITY,
            f64::NEG_INFINITY,
            0.3,
        ])),
        5 => Value::Array(Vec::new()),
        6 => Value::Array(vec![Value::Integer(1), Value::Float(2.5)]),
        7 => Value::Array(vec![Value::Array(vec![Value::Float(1.0)])]),
        8 => Value::Table(toml::Table::new()),
        9 => {
            let mut t = toml::Table::new();
            t.insert("value".into(), Value::Float(1.0));
            Value::Table(t)
        }
        10 => Value::Array(vec![Value::Table(toml::Table::new())]),
        _ => Value::Float(rng.next() as f64 * 1e-10),
    }
}

/// Every path into `v`: keys of tables and indices of arrays.
fn paths(v: &toml::Value, at: &mut Vec<Step>, out: &mut Vec<Vec<Step>>) {
    match v {
        toml::Value::Table(t) => {
            for (k, c) in t {
                at.push(Step::Key(k.clone()));
                out.push(at.clone());
                paths(c, at, out);
                at.pop();
            }
        }
        toml::Value::Array(a) => {
            for (i, c) in a.iter().enumerate() {
                at.push(Step::Index(i));
                out.push(at.clone());
                paths(c, at, out);
                at.pop();
            }
        }
        _ => {}
    }
}

#[derive(Clone, Debug)]
enum Step {
    Key(String),
    Index(usize),
}

/// The container holding the node at `path`, and the node's step in it.
fn parent<'a>(root: &'a mut toml::Value, path: &'a [Step]) -> (&'a mut toml::Value, &'a Step) {
    let (last, init) = path.split_last().unwrap();
    let mut v = root;
    for s in init {
        v = match s {
            Step::Key(k) => v.get_mut(k.as_str()).unwrap(),
            Step::Index(i) => v.get_mut(*i).unwrap(),
        };
    }
    (v, last)
}

/// Mutate the TOML tree of `text`: a value replaced (by another of any type, or a number by
/// an extreme one), a key deleted, an unknown key added, an array element dropped or
/// duplicated. `None` when `text` does not parse (earlier byte mutations).
fn mutate_tree(text: &str, rng: &mut Rng) -> Option<String> {
    let mut root = toml::Value::Table(text.parse::<toml::Table>().ok()?);
    let mut all = Vec::new();
    paths(&root, &mut Vec::new(), &mut all);
    if all.is_empty() {
        return None;
    }
    let path = rng.pick(&all).clone();
    let choice = rng.below(7);
    let (container, step) = parent(&mut root, &path);
    match (container, step) {
        (toml::Value::Table(t), Step::Key(k)) => match choice {
            0 => {
                t.remove(k);
            }
            1 => {
                t.insert(format!("{k}_unknown"), any_value(rng));
            }
            2 | 3 => {
                let old = t.get(k).cloned();
                let new = match old {
                    Some(toml::Value::Integer(_)) | Some(toml::Value::Float(_)) => {
                        extreme_number(rng)
                    }
                    _ => any_value(rng),
                };
                t.insert(k.clone(), new);
            }
            _ => {
                t.insert(k.clone(), any_value(rng));
            }
        },
        (toml::Value::Array(a), Step::Index(i)) => match choice {
            0 | 1 => {
                a.remove(*i);
            }
            2 | 3 => {
                let c = a[*i].clone();
                a.insert(*i, c);
            }
            4 => a[*i] = extreme_number(rng),
            _ => a[*i] = any_value(rng),
        },
        _ => return None,
    }
    match root {
        toml::Value::Table(t) => toml::to_string(&t).ok(),
        _ => None,
    }
}

/// One of [`NUMBERS`] as a TOML value (a parse failure becomes a string, itself a wrong
/// type).
fn extreme_number(rng: &mut Rng) -> toml::Value {
    let s = *rng.pick(NUMBERS);
    format!("x = {s}")
        .parse::<toml::Table>()
        .ok()
        .and_then(|t| t.get("x").cloned())
        .unwrap_or_else(|| toml::Value::String(s.into()))
}

/// Mutate the text itself: a number replaced by an extreme one, bytes flipped, deleted,
/// inserted or duplicated, a line deleted, duplicated or moved.
fn mutate_text(text: &str, rng: &mut Rng) -> Vec<u8> {
    let mut b = text.as_bytes().to_vec();
    if b.is_empty() {
        return b"x".to_vec();
    }
    match rng.below(8) {
        0 | 1 => {
            let spans = number_spans(text);
            if !spans.is_empty() {
                let (s, e) = *rng.pick(&spans);
                b.splice(s..e, rng.pick(NUMBERS).bytes());
            }
        }
        2 => {
            let i = rng.below(b.len());
            b[i] = *rng.pick(b"[]{}=\",.#\n 0-9eaz\\'\x00\xff");
        }
        3 => {
            let i = rng.below(b.len());
            let n = 1 + rng.below(40);
            b.drain(i..(i + n).min(b.len()));
        }
        4 => {
            let i = rng.below(b.len());
            let n = 1 + rng.below(60);
            let piece = b[i..(i + n).min(b.len())].to_vec();
            let at = rng.below(b.len());
            b.splice(at..at, piece);
        }
        _ => {
            let mut lines: Vec<&str> = text.lines().collect();
            let i = rng.below(lines.len());
            match rng.below(3) {
                0 => {
                    lines.remove(i);
                }
                1 => lines.insert(i, lines[i]),
                _ => {
                    let l = lines.remove(i);
                    let at = rng.below(lines.len() + 1);
                    lines.insert(at, l);
                }
            }
            b = lines.join("\n").into_bytes();
        }
    }
    b
}

/// A mutant of `text`: one to three mutations, of the tree or of the text.
fn mutant(text: &str, rng: &mut Rng) -> Vec<u8> {
    let mut cur = text.to_string();
    let mut bytes = cur.clone().into_bytes();
    for _ in 0..1 + rng.below(3) {
        let tree = rng.chance(0.5).then(|| mutate_tree(&cur, rng)).flatten();
        bytes = match tree {
            Some(t) => t.into_bytes(),
            None => mutate_text(&cur, rng),
        };
        cur = String::from_utf8_lossy(&bytes).into_owned();
    }
    bytes
}

/// A shipped problem and its tuned config.
struct Seed {
    name: String,
    problem_path: PathBuf,
    problem: String,
    tuned: String,
}

fn seeds() -> Vec<Seed> {
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    let mut out = Vec::new();
    for e in std::fs::read_dir(root.join("problems")).unwrap() {
        let p = e.unwrap().path();
        if p.extension().is_some_and(|x| x == "toml") {
            let name = p.file_stem().unwrap().to_string_lossy().into_owned();
            let tuned = std::fs::read_to_string(root.join("tuned").join(format!("{name}.toml")))
                .unwrap_or_default();
            out.push(Seed {
                problem: std::fs::read_to_string(&p).unwrap(),
                problem_path: p,
                name,
                tuned,
            });
        }
    }
    out.sort_by(|a, b| a.name.cmp(&b.name));
    assert!(out.len() >= 6, "the shipped problems were not found");
    out
}

/// What went wrong with one input.
struct Failure {
    what: String,
    input: PathBuf,
}

/// Run the binary with `args`; a failure if it exits other than 0, 1 or 2, prints a panic,
/// prints an error on more than one line, or hangs.
fn run_binary(dir: &Path, args: &[&std::ffi::OsStr]) -> Result<usize, String> {
    let mut child = Command::new(env!("CARGO_BIN_EXE_autotune"))
        .current_dir(dir)
        .args(args)
        .env("NO_COLOR", "1")
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let mut err_pipe = child.stderr.take().unwrap();
    let reader = std::thread::spawn(move || {
        let mut v = Vec::new();
        let _ = std::io::Read::read_to_end(&mut err_pipe, &mut v);
        v
    });
    let start = Instant::now();
    let status = loop {
        if let Some(s) = child.try_wait().unwrap() {
            break s;
        }
        if start.elapsed() > PROCESS_LIMIT {
            let _ = child.kill();
            let _ = child.wait();
            return Err(format!("still running after {PROCESS_LIMIT:?}"));
        }
        std::thread::sleep(Duration::from_millis(2));
    };
    let stderr = String::from_utf8_lossy(&reader.join().unwrap()).into_owned();
    let code = status.code();
    if stderr.contains("panicked") || !matches!(code, Some(0..=2)) {
        return Err(format!("exit {code:?}: {stderr}"));
    }
    if code == Some(2) && (stderr.lines().count() != 1 || !stderr.starts_with("error: ")) {
        return Err(format!("exit 2 without a one-line error: {stderr:?}"));
    }
    Ok(code.unwrap_or(2) as usize)
}

/// What the loaders made of an input.
enum Loaded {
    /// Refused with an error.
    Refused,
    /// Accepted; for a problem, the runs per search evaluation its `[tune]` asks for.
    Accepted { search_runs: Option<usize> },
}

/// The loaders in-process: `Ok` or `Err`, never a panic.
fn load_in_process(
    seed_problem: &Problem,
    kind: Kind,
    path: &Path,
    bytes: &[u8],
) -> Result<Loaded, String> {
    let text = String::from_utf8_lossy(bytes).into_owned();
    let result = std::panic::catch_unwind(AssertUnwindSafe(|| match kind {
        Kind::Problem => Problem::from_toml(&text, path).map(|p| {
            // What the commands do right after loading, short of running the filter.
            let e = p.experiment();
            let values = e.params().values();
            let _ = e.covariances(&values);
            let _ = (e.state_names(), e.measurement_names(), e.info());
            p.tune.search_runs()
        }),
        Kind::Tuned => TunedConfig::load_values(path, seed_problem.experiment()).map(|_| None),
    }));
    match result {
        Ok(Ok(search_runs)) => Ok(Loaded::Accepted { search_runs }),
        Ok(Err(_)) => Ok(Loaded::Refused),
        Err(p) => Err(format!(
            "the loader panicked: {}",
            p.downcast_ref::<String>()
                .cloned()
                .or_else(|| p.downcast_ref::<&str>().map(|s| s.to_string()))
                .unwrap_or_default()
        )),
    }
}

#[derive(Clone, Copy, Debug, PartialEq)]
enum Kind {
    Problem,
    Tuned,
}

#[test]
fn fuzz_loaders_never_panic_and_the_binary_exits_0_1_or_2() {
    let (seconds, seed, failures_dir) = settings("fuzz-failures");

    let seeds = seeds();
    let problems: Vec<Problem> = seeds
        .iter()
        .map(|s| Problem::load(&s.problem_path).expect("a shipped problem loads"))
        .collect();
    // The shipped files themselves must be accepted, or every mutant tests only the parser.
    for (s, p) in seeds.iter().zip(&problems) {
        if !s.tuned.is_empty() {
            let dir = tempfile::tempdir().unwrap();
            let f = dir.path().join("t.toml");
            std::fs::write(&f, &s.tuned).unwrap();
            TunedConfig::load_values(&f, p.experiment())
                .unwrap_or_else(|e| panic!("shipped tuned/{}.toml: {e}", s.name));
        }
    }

    let dir = tempfile::tempdir().unwrap();
    let mut rng = Rng(seed);
    let deadline = Instant::now() + Duration::from_secs_f64(seconds);
    let start = Instant::now();
    let (mut inputs, mut accepted, mut runs) = (0usize, 0usize, 0usize);
    let mut exits = [0usize; 3];
    let mut failures: Vec<Failure> = Vec::new();
    while Instant::now() < deadline && failures.len() < 10 {
        let i = rng.below(seeds.len());
        let s = &seeds[i];
        let kind = if !s.tuned.is_empty() && rng.chance(0.3) {
            Kind::Tuned
        } else {
            Kind::Problem
        };
        let base = if kind == Kind::Problem {
            &s.problem
        } else {
            &s.tuned
        };
        let bytes = mutant(base, &mut rng);
        let path = dir.path().join(format!("{}.toml", s.name));
        std::fs::write(&path, &bytes).unwrap();
        inputs += 1;
        let mut fail = |what: String| {
            let saved =
                failures_dir.join(format!("{:04}-{:?}-{}.toml", failures.len(), kind, s.name));
            std::fs::write(&saved, &bytes).unwrap();
            failures.push(Failure { what, input: saved });
        };
        let loaded = match load_in_process(&problems[i], kind, &path, &bytes) {
            Ok(ok) => ok,
            Err(e) => {
                fail(e);
                continue;
            }
        };
        // The binary costs milliseconds: run it on every accepted input (those reach the
        // engine) and on a sample of the refused ones (their message must be one line).
        let search_runs = match loaded {
            Loaded::Accepted { search_runs } => {
                accepted += 1;
                search_runs
            }
            Loaded::Refused if rng.chance(0.05) => None,
            Loaded::Refused => continue,
        };
        runs += 1;
        let small: [&std::ffi::OsStr; 4] = [
            "--runs".as_ref(),
            "2".as_ref(),
            "--steps".as_ref(),
            "10".as_ref(),
        ];
        let mut args: Vec<&std::ffi::OsStr> = Vec::new();
        let out = dir.path().join("out.toml");
        match kind {
            // `--runs` does not bound the search's own run count, which a valid file may
            // set to 10¹² (hours of honest work): tune only what asks for little.
            Kind::Problem if rng.chance(0.2) && search_runs.is_none_or(|n| n <= 1000) => {
                args.extend(["tune".as_ref(), path.as_os_str()]);
                args.extend(small);
                args.extend([
                    "--max-evals".as_ref(),
                    "2".as_ref(),
                    "--quiet".as_ref(),
                    "--out".as_ref(),
                    out.as_os_str(),
                ]);
            }
            Kind::Problem => {
                args.extend(["check".as_ref(), path.as_os_str()]);
                args.extend(small);
            }
            Kind::Tuned => {
                args.extend(["check".as_ref(), s.problem_path.as_os_str()]);
                args.extend(small);
                args.extend(["--config".as_ref(), path.as_os_str()]);
            }
        }
        match run_binary(dir.path(), &args) {
            Ok(code) => exits[code] += 1,
            Err(e) => {
                let shown: Vec<String> = args
                    .iter()
                    .map(|a| a.to_string_lossy().into_owned())
                    .collect();
                fail(format!("autotune {}: {e}", shown.join(" ")));
            }
        }
    }
    let elapsed = start.elapsed().as_secs_f64();
    eprintln!(
        "fuzz (seed {seed}, {seconds} s): {inputs} inputs in {elapsed:.1} s ({:.0}/s), {accepted} accepted by the loaders, {runs} binary runs ({:.1}/s; exit 0/1/2: {}/{}/{}), {} failures",
        inputs as f64 / elapsed,
        runs as f64 / elapsed,
        exits[0],
        exits[1],
        exits[2],
        failures.len()
    );
    if !failures.is_empty() {
        let mut msg = String::new();
        for f in &failures {
            msg += &format!(
                "\n{} ({})",
                f.what.lines().next().unwrap_or(""),
                f.input.display()
            );
        }
        for f in &failures {
            msg += &format!(
                "\n--- {} (saved as {})\n{}\n",
                f.what,
                f.input.display(),
                String::from_utf8_lossy(&std::fs::read(&f.input).unwrap())
            );
        }
        panic!("{} inputs failed:{msg}", failures.len());
    }
}

// ---------------------------------------------------------------------------------------
// Records (`autotune check --records`) and `[external]` problems.
//
// Seeds are built here: 3 runs × 4 steps of 2 states and a sensor `r` of 1 or 2
// components, not measured at some steps, raw (e, P, ν, S) or precomputed (NEES, NIS), one
// run sometimes diverged; written as CSV, JSON Lines and `.npy` files (byte by byte, in
// several dtypes and both orders). Mutants keep the file's structure where they can (a cell,
// a column name, a shape tuple, a dtype) so that they get past the first check.

/// CSV cells and JSON values that have broken readers before.
const CELLS: &[&str] = &[
    "",
    "NaN",
    "nan",
    "inf",
    "-inf",
    "-0",
    "0",
    "1",
    "3.0",
    "-1",
    "1e308",
    "-1e308",
    "1e-320",
    "9e15",
    "9.0e15",
    "18446744073709551615",
    "18446744073709551616",
    "1000000",
    "1000001",
    "4294967296",
    "garbage",
    "\"q\"",
];

/// Names a column, key or array may be renamed to.
const NAMES: &[&str] = &[
    "run",
    "step",
    "e_1",
    "e_3",
    "e_99999999999",
    "P_2_1",
    "P_3_3",
    "P_99999_99999",
    "P_9999999999_99999999999",
    "P_1",
    "x_1",
    "xhat_1",
    "nees",
    "nees_dof",
    "e2p_1",
    "nu_r_1",
    "nu_r_2",
    "nu_q_1",
    "nu_1",
    "S_r_1_2",
    "S_r_2_2",
    "nis_r",
    "nis_dof_r",
    "u_r_1",
    "diverged",
    "dof",
    "Q",
    "",
];

/// One step of the seed records.
struct SeedStep {
    run: usize,
    step: usize,
    e: [f64; 2],
    /// Depends on the step only, so that it may also be written without the runs axis.
    p: [f64; 4],
    /// ν and S (m × m, row-major), where measured.
    nu: Option<(Vec<f64>, Vec<f64>)>,
    diverged: bool,
}

/// Seed records: 3 runs × 4 steps, in the raw or the precomputed form, with or without
/// ground truth.
struct SeedRecords {
    m: usize,
    state: bool,
    normalized: bool,
    /// Run 1 diverged at step 3 (its steps 4 are left out of the text formats).
    diverged: bool,
    steps: Vec<SeedStep>,
}

const RUNS: usize = 3;
const STEPS: usize = 4;

fn seed_records(rng: &mut Rng) -> SeedRecords {
    let m = 1 + rng.below(2);
    let state = rng.chance(0.8);
    let normalized = rng.chance(0.3);
    let diverged = rng.chance(0.3);
    let small = |rng: &mut Rng| (rng.below(2001) as f64 - 1000.0) / 500.0;
    let p_of: Vec<[f64; 4]> = (1..=STEPS)
        .map(|k| {
            let d = 1.0 + k as f64 / 4.0;
            [d, 0.25, 0.25, 2.0 * d]
        })
        .collect();
    let mut steps = Vec::new();
    for run in 0..RUNS {
        for step in 1..=STEPS {
            if diverged && run == 1 && step > 3 {
                break;
            }
            let measured = step == 1 || rng.chance(0.7);
            let nu = measured.then(|| {
                let nu: Vec<f64> = (0..m).map(|_| small(rng)).collect();
                let mut s = vec![0.0; m * m];
                for a in 0..m {
                    for b in 0..m {
                        s[a * m + b] = if a == b { 2.0 + a as f64 } else { 0.5 };
                    }
                }
                (nu, s)
            });
            steps.push(SeedStep {
                run,
                step,
                e: [small(rng), small(rng)],
                p: p_of[step - 1],
                nu,
                diverged: diverged && run == 1 && step == 3,
            });
        }
    }
    SeedRecords {
        m,
        state,
        normalized,
        diverged,
        steps,
    }
}

fn num(v: f64) -> String {
    format!("{v:?}")
}

fn records_csv(s: &SeedRecords, rng: &mut Rng) -> String {
    let m = s.m;
    let triangle = rng.chance(0.5);
    let mut head = vec!["run".to_string(), "step".to_string()];
    if s.state {
        if s.normalized {
            head.extend(["nees", "nees_dof", "e2p_1", "e2p_2"].map(String::from));
        } else {
            head.extend(["e_1", "e_2", "P_1_1", "P_1_2"].map(String::from));
            if !triangle {
                head.push("P_2_1".into());
            }
            head.push("P_2_2".into());
        }
    }
    if s.normalized {
        head.extend(["nis_r".to_string(), "nis_dof_r".to_string()]);
        head.extend((1..=m).map(|j| format!("u_r_{j}")));
    } else {
        head.extend((1..=m).map(|j| format!("nu_r_{j}")));
        for a in 1..=m {
            for b in 1..=m {
                head.push(format!("S_r_{a}_{b}"));
            }
        }
    }
    if s.diverged {
        head.push("diverged".into());
    }
    let mut out = head.join(",") + "\n";
    for st in &s.steps {
        let mut row = vec![st.run.to_string(), st.step.to_string()];
        if s.state {
            let [e1, e2] = st.e;
            let p = st.p;
            if s.normalized {
                row.extend([e1 * e1 + e2 * e2, 2.0, e1 * e1, e2 * e2].map(num));
            } else {
                row.extend([e1, e2, p[0], p[1]].map(num));
                if !triangle {
                    row.push(num(p[2]));
                }
                row.push(num(p[3]));
            }
        }
        match (&st.nu, s.normalized) {
            (Some((nu, _)), true) => {
                row.push(num(nu.iter().map(|x| x * x).sum()));
                row.push(m.to_string());
                row.extend(nu.iter().map(|&x| num(x)));
            }
            (Some((nu, sm)), false) => {
                row.extend(nu.iter().chain(sm).map(|&x| num(x)));
            }
            (None, true) => row.extend(std::iter::repeat_n(String::new(), 2 + m)),
            (None, false) => row.extend(std::iter::repeat_n(String::new(), m + m * m)),
        }
        if s.diverged {
            row.push(if st.diverged { "1" } else { "0" }.into());
        }
        out += &(row.join(",") + "\n");
    }
    out
}

fn records_jsonl(s: &SeedRecords, rng: &mut Rng) -> String {
    use serde_json::json;
    let flat = rng.chance(0.3);
    let mut out = String::new();
    for st in &s.steps {
        let mut o = json!({"run": st.run, "step": st.step});
        if st.diverged {
            o["diverged"] = json!("P lost positive definiteness");
        }
        if s.state {
            let [e1, e2] = st.e;
            if s.normalized {
                o["nees"] = json!(e1 * e1 + e2 * e2);
                o["nees_dof"] = json!(2);
                o["e2p"] = json!([e1 * e1, e2 * e2]);
            } else {
                o["e"] = json!(st.e);
                let p = st.p;
                o["P"] = if flat {
                    json!(p)
                } else {
                    json!([[p[0], p[1]], [p[2], p[3]]])
                };
            }
        }
        if let Some((nu, sm)) = &st.nu {
            if s.normalized {
                o["nis_r"] = json!(nu.iter().map(|x| x * x).sum::<f64>());
                o["nis_dof_r"] = json!(s.m);
                o["u_r"] = json!(nu);
            } else {
                o["nu_r"] = json!(nu);
                let rows: Vec<&[f64]> = sm.chunks(s.m).collect();
                o["S_r"] = json!(rows);
            }
        }
        out += &format!("{o}\n");
    }
    out
}

fn records_npy(s: &SeedRecords, rng: &mut Rng) -> Vec<Npy> {
    let m = s.m;
    // Runs × steps, NaN after a divergence and where not measured.
    let at = |run: usize, step: usize| s.steps.iter().find(|x| x.run == run && x.step == step);
    let grid = |width: usize, f: &dyn Fn(&SeedStep) -> Option<Vec<f64>>| -> Vec<f64> {
        let mut v = Vec::new();
        for r in 0..RUNS {
            for k in 1..=STEPS {
                match at(r, k).and_then(f) {
                    Some(x) => v.extend(x),
                    None => v.extend(std::iter::repeat_n(f64::NAN, width)),
                }
            }
        }
        v
    };
    let shared = rng.chance(0.4);
    let mut out = Vec::new();
    if s.state {
        if s.normalized {
            out.push(Npy::new(
                "nees",
                &[RUNS, STEPS],
                grid(1, &|x| Some(vec![x.e[0] * x.e[0] + x.e[1] * x.e[1]])),
            ));
            out.push(Npy::new("nees_dof", &[], vec![2.0]));
            out.push(Npy::new(
                "e2p",
                &[RUNS, STEPS, 2],
                grid(2, &|x| Some(vec![x.e[0] * x.e[0], x.e[1] * x.e[1]])),
            ));
        } else {
            out.push(Npy::new(
                "e",
                &[RUNS, STEPS, 2],
                grid(2, &|x| Some(x.e.to_vec())),
            ));
            if shared {
                let p: Vec<f64> = (1..=STEPS).flat_map(|k| at(0, k).unwrap().p).collect();
                out.push(Npy::new("P", &[STEPS, 2, 2], p));
            } else {
                out.push(Npy::new(
                    "P",
                    &[RUNS, STEPS, 2, 2],
                    grid(4, &|x| Some(x.p.to_vec())),
                ));
            }
        }
    }
    let sm: Vec<f64> = (0..m * m)
        .map(|i| {
            if i / m == i % m {
                2.0 + (i / m) as f64
            } else {
                0.5
            }
        })
        .collect();
    if s.normalized {
        out.push(Npy::new(
            "nis_r",
            &[RUNS, STEPS],
            grid(1, &|x| {
                x.nu.as_ref()
                    .map(|(nu, _)| vec![nu.iter().map(|v| v * v).sum()])
            }),
        ));
        out.push(Npy::new("nis_dof_r", &[], vec![m as f64]));
        out.push(Npy::new(
            "u_r",
            &[RUNS, STEPS, m],
            grid(m, &|x| x.nu.as_ref().map(|(nu, _)| nu.clone())),
        ));
    } else {
        out.push(Npy::new(
            "nu_r",
            &[RUNS, STEPS, m],
            grid(m, &|x| x.nu.as_ref().map(|(nu, _)| nu.clone())),
        ));
        if shared {
            let all: Vec<f64> = (0..STEPS).flat_map(|_| sm.clone()).collect();
            out.push(Npy::new("S_r", &[STEPS, m, m], all));
        } else {
            let all: Vec<f64> = (0..RUNS * STEPS).flat_map(|_| sm.clone()).collect();
            out.push(Npy::new("S_r", &[RUNS, STEPS, m, m], all));
        }
    }
    if s.diverged {
        let mut d = Npy::new("diverged", &[RUNS], vec![0.0, 3.0, 0.0]);
        d.descr = "<i8".into();
        out.push(d);
    }
    // Valid variations: another dtype for every array, Fortran order.
    let descr = *rng.pick(&["<f8", "<f8", "<f4", ">f8", "<i8"]);
    let fortran = rng.chance(0.3);
    for a in &mut out {
        if a.name != "diverged" {
            a.descr = descr.into();
        }
        a.fortran = fortran;
    }
    out
}

/// Dimensions a shape tuple's entry may become.
const DIMS: &[&str] = &[
    "0",
    "1",
    "2",
    "3",
    "4",
    "5",
    "-1",
    "1000000",
    "1000001",
    "4294967296",
    "2147483648",
    "9223372036854775807",
    "18446744073709551615",
    "18446744073709551616",
    "3.0",
    "None",
];

/// Mutate a set of `.npy` files structurally: a shape entry, the shape, the dtype, the
/// order, a number, an array's name or presence, the data's length.
fn mutate_npy(files: &mut Vec<Npy>, rng: &mut Rng) {
    if files.is_empty() {
        files.push(Npy::new("e", &[1, 1, 1], vec![1.0]));
    }
    let i = rng.below(files.len());
    let a = &mut files[i];
    match rng.below(12) {
        0 | 1 => {
            if a.shape.is_empty() {
                a.shape.push(rng.pick(DIMS).to_string());
            } else {
                let j = rng.below(a.shape.len());
                a.shape[j] = rng.pick(DIMS).to_string();
            }
        }
        2 => match rng.below(4) {
            0 => {
                if !a.shape.is_empty() {
                    a.shape.remove(rng.below(a.shape.len()));
                }
            }
            1 => {
                let at = rng.below(a.shape.len() + 1);
                a.shape.insert(at, rng.pick(DIMS).to_string());
            }
            2 => a.shape = vec!["4294967296".into(), "4294967296".into()],
            _ => {
                a.shape = vec![
                    "4294967296".into(),
                    "4294967296".into(),
                    "0".into(),
                    "2".into(),
                ]
            }
        },
        3 => {
            a.descr = rng
                .pick(&[
                    "<f8", "<f4", ">f8", "<i8", "<i4", "|u1", "<c16", "|b1", "<U3", "O", "<f2",
                    "V8", "<M8[s]", "xx",
                ])
                .to_string()
        }
        4 => a.fortran = !a.fortran,
        5 | 6 => {
            if !a.values.is_empty() {
                let j = rng.below(a.values.len());
                a.values[j] = *rng.pick(&[
                    f64::NAN,
                    f64::INFINITY,
                    f64::NEG_INFINITY,
                    1e308,
                    -1e308,
                    -0.0,
                    0.0,
                    -1.0,
                    9e15,
                    1e-320,
                    5.0,
                    4.5,
                ]);
            }
        }
        7 => {
            files.remove(i);
        }
        8 => {
            let mut b = a.clone();
            b.name = rng.pick(NAMES).to_string();
            files.push(b);
        }
        9 => a.name = rng.pick(NAMES).to_string(),
        10 => {
            let keep = rng.below(a.values.len() + 1);
            a.values.truncate(keep);
        }
        _ => {
            let n = 1 + rng.below(8);
            a.values.extend(std::iter::repeat_n(1.0, n));
        }
    }
}

/// Byte ranges of the `"…"` strings in `text`.
fn string_spans(text: &str) -> Vec<(usize, usize)> {
    let mut spans = Vec::new();
    let mut start = None;
    for (i, c) in text.char_indices() {
        if c == '"' {
            match start.take() {
                None => start = Some(i),
                Some(s) => spans.push((s, i + 1)),
            }
        }
    }
    spans
}

/// Mutate CSV or JSON Lines text: a cell or value replaced, a column or key renamed, rows
/// deleted, duplicated or moved, bytes changed, the text cut short.
fn mutate_records_text(text: &str, csv: bool, rng: &mut Rng) -> Vec<u8> {
    let mut lines: Vec<String> = text.lines().map(String::from).collect();
    if lines.is_empty() {
        return mutate_text(text, rng);
    }
    match rng.below(10) {
        0..=2 if csv => {
            let i = rng.below(lines.len());
            let mut cells: Vec<String> = lines[i].split(',').map(String::from).collect();
            let j = rng.below(cells.len());
            cells[j] = if i == 0 {
                rng.pick(NAMES).to_string()
            } else {
                rng.pick(CELLS).to_string()
            };
            lines[i] = cells.join(",");
        }
        0 | 1 => {
            // A number replaced by a value of another kind.
            let i = rng.below(lines.len());
            let spans = number_spans(&lines[i]);
            if !spans.is_empty() {
                let (s, e) = *rng.pick(&spans);
                let v = *rng.pick(&[
                    "null",
                    "NaN",
                    "-Infinity",
                    "\"x\"",
                    "[]",
                    "[[1]]",
                    "[[1,2],[3]]",
                    "{}",
                    "true",
                    "1e400",
                    "18446744073709551616",
                    "1000001",
                    "9e15",
                    "-0",
                    "1e308",
                ]);
                lines[i].replace_range(s..e, v);
            }
        }
        2 => {
            let i = rng.below(lines.len());
            let spans = string_spans(&lines[i]);
            if !spans.is_empty() {
                let (s, e) = *rng.pick(&spans);
                let name = format!("\"{}\"", rng.pick(NAMES));
                lines[i].replace_range(s..e, &name);
            }
        }
        3 => {
            let i = rng.below(lines.len());
            let j = rng.below(lines.len());
            lines.swap(i, j);
        }
        4 => {
            let i = rng.below(lines.len());
            let l = lines[i].clone();
            lines.insert(rng.below(lines.len() + 1), l);
        }
        5 => {
            lines.remove(rng.below(lines.len()));
        }
        6 => {
            let mut b = text.as_bytes().to_vec();
            b.truncate(rng.below(b.len() + 1));
            return b;
        }
        _ => return mutate_text(text, rng),
    }
    let mut out = lines.join("\n");
    if rng.chance(0.8) {
        out.push('\n');
    }
    out.into_bytes()
}

/// The format of a records fuzz input.
#[derive(Clone, Copy, Debug)]
enum RecFormat {
    Csv,
    Jsonl,
    Npy,
    /// CSV and JSON Lines together, the runs split between them.
    Mixed,
}

/// Write one mutated records input into `dir` (emptied first); the files to pass.
fn write_records_input(dir: &Path, format: RecFormat, rng: &mut Rng) -> Vec<PathBuf> {
    let _ = std::fs::remove_dir_all(dir);
    std::fs::create_dir_all(dir).unwrap();
    let s = seed_records(rng);
    let mutations = rng.below(3);
    let text_file = |name: &str, text: String, csv: bool, rng: &mut Rng| {
        let mut bytes = text.clone().into_bytes();
        for _ in 0..mutations {
            let cur = String::from_utf8_lossy(&bytes).into_owned();
            bytes = mutate_records_text(&cur, csv, rng);
        }
        let p = dir.join(name);
        std::fs::write(&p, &bytes).unwrap();
        p
    };
    match format {
        RecFormat::Csv => vec![text_file("rec.csv", records_csv(&s, rng), true, rng)],
        RecFormat::Jsonl => vec![text_file("rec.jsonl", records_jsonl(&s, rng), false, rng)],
        RecFormat::Mixed => {
            let csv = records_csv(&s, rng);
            let jsonl = records_jsonl(&s, rng);
            // Runs 0 and 1 from the CSV, run 2 from the JSON Lines.
            let csv: Vec<&str> = csv
                .lines()
                .enumerate()
                .filter(|(i, l)| *i == 0 || !l.starts_with("2,"))
                .map(|(_, l)| l)
                .collect();
            let jsonl: Vec<&str> = jsonl
                .lines()
                .filter(|l| l.starts_with("{\"run\":2,"))
                .collect();
            vec![
                text_file("a.csv", csv.join("\n") + "\n", true, rng),
                text_file("b.jsonl", jsonl.join("\n") + "\n", false, rng),
            ]
        }
        RecFormat::Npy => {
            let mut arrays = records_npy(&s, rng);
            for _ in 0..mutations {
                mutate_npy(&mut arrays, rng);
            }
            let mut paths = Vec::new();
            for a in &arrays {
                let mut bytes = a.bytes();
                if rng.chance(0.1) {
                    mutate_bytes(&mut bytes, rng);
                }
                let p = dir.join(format!("{}.npy", a.name));
                std::fs::write(&p, &bytes).unwrap();
                paths.push(p);
            }
            if rng.chance(0.05) && !paths.is_empty() {
                // The same file twice.
                paths.push(paths[0].clone());
            }
            paths
        }
    }
}

/// An `[external]` problem whose worker never gives records: missing, exiting at once,
/// silent, printing an endless line, flooding its stderr, or answering wrongly.
fn external_problem(rng: &mut Rng) -> String {
    let command = *rng.pick(&[
        r#"["/nonexistent/autotune-worker"]"#,
        r#"["python3", "-c", "import sys"]"#,
        r#"["sh", "-c", "cat > /dev/null"]"#,
        r#"["sh", "-c", "yes | tr -d '\\n'"]"#,
        r#"["sh", "-c", "yes autotune >&2"]"#,
        r#"["sh", "-c", "read l; echo '{\"id\": 1, \"done\": true}'"]"#,
        r#"["sh", "-c", "read l; echo not json"]"#,
        r#"["sh", "-c", "read l; echo '{\"run\": 0, \"step\": 99999999999}'"]"#,
        r#"["sh", "-c", "read l; echo '{\"id\": 1, \"file\": \"nothing.npz\"}'"]"#,
        r#"["sh", "-c", "read l; printf '\\377\\376\\n'"]"#,
    ]);
    format!(
        r#"name = "fz_external"
state_names = ["a", "b"]

[montecarlo]
runs = 2
steps = 3
seed = 1

[external]
command = {command}
sensors = {{ r = ["u"] }}
workers = {}
timeout = 1.0
truth = {{ q = 1.0 }}
drives = {{ q = ["a"] }}

[params.q]
value = 1.0
lower = 0.1
upper = 10.0
"#,
        1 + rng.below(2)
    )
}

/// Keep a mutated external problem quick: a timeout or a worker count the mutation made
/// large (or removed, which means 300 s and every core) is set back.
fn bound_external(bytes: Vec<u8>) -> Vec<u8> {
    let Ok(mut t) = String::from_utf8_lossy(&bytes).parse::<toml::Table>() else {
        return bytes;
    };
    if let Some(toml::Value::Table(e)) = t.get_mut("external") {
        let slow = match e.get("timeout") {
            None => true,
            Some(toml::Value::Float(x)) => *x > 2.0,
            Some(toml::Value::Integer(x)) => *x > 2,
            Some(_) => false,
        };
        if slow {
            e.insert("timeout".into(), toml::Value::Float(1.0));
        }
        let many = match e.get("workers") {
            None => true,
            Some(toml::Value::Integer(x)) => *x > 4,
            Some(_) => false,
        };
        if many {
            e.insert("workers".into(), toml::Value::Integer(2));
        }
    }
    toml::to_string(&t).map_or(bytes, String::into_bytes)
}

#[test]
fn fuzz_records_and_external_problems_through_the_binary() {
    let (seconds, seed, failures_dir) = settings("fuzz-failures-records");

    let dir = tempfile::tempdir().unwrap();
    let input_dir = dir.path().join("in");
    let mut rng = Rng(seed);
    let deadline = Instant::now() + Duration::from_secs_f64(seconds);
    let start = Instant::now();
    let mut inputs = 0usize;
    let mut external = 0usize;
    let mut exits = [0usize; 3];
    let mut failures: Vec<String> = Vec::new();
    while Instant::now() < deadline && failures.len() < 10 {
        inputs += 1;
        let mut args: Vec<std::ffi::OsString> = vec!["check".into()];
        // One in twenty inputs is an external problem: those cost a second of timeout.
        if rng.chance(0.05) {
            external += 1;
            let _ = std::fs::remove_dir_all(&input_dir);
            std::fs::create_dir_all(&input_dir).unwrap();
            let base = external_problem(&mut rng);
            let bytes = if rng.chance(0.7) {
                bound_external(mutant(&base, &mut rng))
            } else {
                base.into_bytes()
            };
            let p = input_dir.join("ext.toml");
            std::fs::write(&p, &bytes).unwrap();
            args.push(p.into());
            args.extend(["--runs", "2", "--steps", "3"].map(Into::into));
        } else {
            let format = *rng.pick(&[
                RecFormat::Csv,
                RecFormat::Jsonl,
                RecFormat::Npy,
                RecFormat::Npy,
                RecFormat::Mixed,
            ]);
            if rng.chance(0.3) {
                args.push("--json".into());
            }
            args.push("--records".into());
            args.extend(
                write_records_input(&input_dir, format, &mut rng)
                    .into_iter()
                    .map(Into::into),
            );
        }
        let refs: Vec<&std::ffi::OsStr> = args.iter().map(|a| a.as_os_str()).collect();
        match run_binary(dir.path(), &refs) {
            Ok(code) => exits[code] += 1,
            Err(e) => {
                // Keep the input directory as it was, and say how to rerun it.
                let saved = failures_dir.join(format!("{:04}", failures.len()));
                std::fs::create_dir_all(&saved).unwrap();
                let mut shown = Vec::new();
                for a in &args {
                    let p = Path::new(a);
                    if p.starts_with(&input_dir) {
                        let to = saved.join(p.file_name().unwrap());
                        let _ = std::fs::copy(p, &to);
                        shown.push(to.display().to_string());
                    } else {
                        shown.push(a.to_string_lossy().into_owned());
                    }
                }
                failures.push(format!("autotune {}: {e}", shown.join(" ")));
            }
        }
    }
    let elapsed = start.elapsed().as_secs_f64();
    eprintln!(
        "fuzz records (seed {seed}, {seconds} s): {inputs} inputs in {elapsed:.1} s ({:.0}/s), {external} external problems; exit 0/1/2: {}/{}/{}; {} failures",
        inputs as f64 / elapsed,
        exits[0],
        exits[1],
        exits[2],
        failures.len()
    );
    assert!(
        failures.is_empty(),
        "{} inputs failed:\n{}",
        failures.len(),
        failures.join("\n")
    );
}
