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
//! It runs for `AUTOTUNE_FUZZ_SECONDS` (default 8 s; `.ci/run` gives it 60 s) from seed
//! `AUTOTUNE_FUZZ_SEED` (default 1, so a failure reproduces), and reports how many inputs
//! it tried per second. Failing inputs are saved under the cargo target's temporary
//! directory (`fuzz-failures/`) and printed. To fuzz longer, e.g. for an hour from a new seed:
//!
//! ```text
//! AUTOTUNE_FUZZ_SECONDS=3600 AUTOTUNE_FUZZ_SEED=7 cargo test --release --test fuzz -- --nocapture
//! ```

use std::panic::AssertUnwindSafe;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use autotune::problem::Problem;
use autotune::report::tuned::TunedConfig;

/// How long a binary run may take: with two runs of ten steps every shipped problem checks
/// in milliseconds, so a run this long is a hang the input caused.
const PROCESS_LIMIT: Duration = Duration::from_secs(30);

/// splitmix64: small, fast, and the same on every platform.
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }
    fn below(&mut self, n: usize) -> usize {
        (self.next() % n.max(1) as u64) as usize
    }
    fn chance(&mut self, p: f64) -> bool {
        (self.next() >> 11) as f64 / (1u64 << 53) as f64 <= p
    }
    fn pick<'a, T>(&mut self, v: &'a [T]) -> &'a T {
        &v[self.below(v.len())]
    }
}

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

/// Byte ranges of the numbers in `text`.
fn number_spans(text: &str) -> Vec<(usize, usize)> {
    let b = text.as_bytes();
    let mut spans = Vec::new();
    let mut i = 0;
    while i < b.len() {
        let starts = b[i].is_ascii_digit()
            && (i == 0 || !(b[i - 1].is_ascii_alphanumeric() || b[i - 1] == b'_'));
        if starts {
            let s = if i > 0 && b[i - 1] == b'-' { i - 1 } else { i };
            let mut e = i;
            while e < b.len() && (b[e].is_ascii_alphanumeric() || b"._+-".contains(&b[e])) {
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
    let seconds: f64 = std::env::var("AUTOTUNE_FUZZ_SECONDS")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(8.0);
    let seed: u64 = std::env::var("AUTOTUNE_FUZZ_SEED")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(1);
    let failures_dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join("fuzz-failures");
    let _ = std::fs::remove_dir_all(&failures_dir);
    std::fs::create_dir_all(&failures_dir).unwrap();

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
