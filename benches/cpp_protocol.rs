//! The protocol's share of an evaluation for the C++ worker (`examples/cpp/pendulum_ekf.cpp`)
//! answering sums: one evaluation of the pendulum through autotune (256 runs × 200 steps, one
//! worker), with the worker answering sums (it links `target/release/libautotune.so` and sums
//! its own records) and answering npz, against the worker's own cost measured inside it
//! (`--self-time`: the same runs in the same chunks of 64, no protocol) with the library
//! (`sums`: filter, summing and the answer lines) and without (`none`: the filter alone).
//!
//! The summary line per format gives the evaluation, the worker's own time and the protocol's
//! share, 1 − own/evaluation; for sums also the share of everything but the filter,
//! (evaluation − filter)/evaluation, which counts the statistics the library computes in the
//! worker (autotune's own work, not protocol). Needs `c++` or `g++` and the library
//! (`cargo build --release -p autotune-cdylib`); skipped, saying why, without them.

use std::cell::RefCell;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Instant;

use autotune::internals::experiment::Experiment;
use autotune::internals::problem::Problem;
use criterion::{Criterion, Throughput, criterion_group, criterion_main};

const RUNS: usize = 256;
const STEPS: usize = 200;
/// Times the worker's `--self-time` runs, for its median.
const SELF_TIMES: usize = 9;

/// The system's C++ compiler, if any.
fn compiler() -> Option<&'static str> {
    ["c++", "g++"].into_iter().find(|cxx| {
        Command::new(cxx)
            .arg("--version")
            .output()
            .is_ok_and(|o| o.status.success())
    })
}

/// Build the worker with sums into `dir`, as examples/cpp/ci.sh does.
fn build_worker(cxx: &str, dir: &Path, lib: &Path) -> Result<PathBuf, String> {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let exe = dir.join("pendulum_ekf");
    let out = Command::new(cxx)
        .args([
            "-O2",
            "-std=c++17",
            "-Wall",
            "-Wextra",
            "-DAUTOTUNE_SUMS",
            "-I",
        ])
        .arg(root.join("include"))
        .arg("-o")
        .arg(&exe)
        .arg(root.join("examples/cpp/pendulum_ekf.cpp"))
        .arg("-L")
        .arg(lib)
        .arg("-lautotune")
        .arg(format!("-Wl,-rpath,{}", lib.display()))
        .output()
        .map_err(|e| format!("{cxx}: {e}"))?;
    if !out.status.success() {
        return Err(format!(
            "{cxx} failed: {}",
            String::from_utf8_lossy(&out.stderr)
        ));
    }
    Ok(exe)
}

/// The pendulum problem (pendulum.toml's start and seed) with one worker answering `format`.
fn problem(dir: &Path, exe: &Path, format: &str) -> Problem {
    let text = format!(
        r#"name = "pendulum_cpp"
state_names = ["theta", "omega"]
[montecarlo]
runs = {RUNS}
steps = {STEPS}
seed = 7
[external]
command = ["{}", "--format", "{format}"]
sensors = {{ bob = ["x", "y"] }}
workers = 1
check_seed_contract = false
[params.q]
value = 2.0
lower = 1e-4
upper = 100.0
[params.r]
value = 0.1
lower = 1e-5
upper = 10.0
"#,
        exe.display()
    );
    let path = dir.join(format!("pendulum_{format}.toml"));
    std::fs::write(&path, text).expect("a temporary file");
    Problem::load(&path).expect("a valid problem")
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    let n = v.len();
    if n % 2 == 1 {
        v[n / 2]
    } else {
        0.5 * (v[n / 2 - 1] + v[n / 2])
    }
}

/// The median over [`SELF_TIMES`] processes of the worker's own wall time in `mode`, in ms
/// (the first number it prints).
fn self_time(exe: &Path, mode: &str, lags: usize) -> f64 {
    let times = (0..SELF_TIMES)
        .map(|_| {
            let out = Command::new(exe)
                .args(["--self-time", mode])
                .args([RUNS, STEPS, lags].map(|v| v.to_string()))
                .output()
                .expect("the worker runs");
            let text = String::from_utf8_lossy(&out.stdout);
            assert!(out.status.success(), "--self-time {mode}: {text}");
            text.split_whitespace()
                .next()
                .and_then(|ms| ms.parse::<f64>().ok())
                .unwrap_or_else(|| panic!("--self-time {mode} printed {text:?}"))
        })
        .collect();
    median(times)
}

fn cpp_protocol(c: &mut Criterion) {
    let Some(cxx) = compiler() else {
        eprintln!("cpp_protocol bench skipped: it needs a C++ compiler (c++ or g++)");
        return;
    };
    let lib = Path::new(env!("CARGO_MANIFEST_DIR")).join("target/release");
    if !lib.join("libautotune.so").is_file() {
        eprintln!(
            "cpp_protocol bench skipped: no {} (build it: cargo build --release -p autotune-cdylib)",
            lib.join("libautotune.so").display()
        );
        return;
    }
    let dir = tempfile::tempdir().expect("a temporary directory");
    let exe = match build_worker(cxx, dir.path(), &lib) {
        Ok(exe) => exe,
        Err(why) => {
            eprintln!("cpp_protocol bench skipped: the worker does not build: {why}");
            return;
        }
    };

    let mut g = c.benchmark_group("cpp_protocol");
    g.sample_size(20);
    g.throughput(Throughput::Elements((RUNS * STEPS) as u64));
    let mut evaluation_ms = Vec::new();
    let mut sums = Vec::new();
    let mut lags = 0;
    for format in ["sums", "npz"] {
        let p = problem(dir.path(), &exe, format);
        lags = p.mc().lags();
        let theta = p.params().values();
        // Start the worker outside the timing.
        let acc = p
            .monte_carlo(&theta, p.mc())
            .expect("the C++ worker answers");
        sums.push(format!("{acc:?}"));
        // Every evaluation's time per iteration, as criterion measures it.
        let times = RefCell::new(Vec::new());
        g.bench_function(format!("{format}/N={RUNS},T={STEPS},workers=1"), |b| {
            b.iter_custom(|iters| {
                let t0 = Instant::now();
                for _ in 0..iters {
                    p.monte_carlo(&theta, p.mc())
                        .expect("the C++ worker answers");
                }
                let took = t0.elapsed();
                times
                    .borrow_mut()
                    .push(took.as_secs_f64() * 1e3 / iters as f64);
                took
            })
        });
        evaluation_ms.push(median(times.into_inner()));
    }
    g.finish();
    assert_eq!(
        sums[0], sums[1],
        "the sums answer's statistics differ from the npz answer's"
    );

    let own_sums = self_time(&exe, "sums", lags);
    let own_none = self_time(&exe, "none", lags);
    let (eval_sums, eval_npz) = (evaluation_ms[0], evaluation_ms[1]);
    println!(
        "cpp_protocol: N={RUNS}, T={STEPS}, one worker; medians (evaluations: every criterion sample; worker's own: {SELF_TIMES} runs of --self-time); statistics of sums and npz identical"
    );
    println!(
        "cpp_protocol: sums: evaluation {eval_sums:.2} ms, worker's own (filter + library's sums + answer lines) {own_sums:.2} ms, protocol share 1 - own/evaluation = {:.1}%; beyond the filter alone ({own_none:.2} ms, the library's statistics included): {:.1}%",
        100.0 * (1.0 - own_sums / eval_sums),
        100.0 * (eval_sums - own_none) / eval_sums,
    );
    println!(
        "cpp_protocol: npz: evaluation {eval_npz:.2} ms, worker's own (filter alone) {own_none:.2} ms, protocol share 1 - own/evaluation = {:.1}% (writing, reading and summing the records)",
        100.0 * (1.0 - own_none / eval_npz),
    );
}

criterion_group!(benches, cpp_protocol);
criterion_main!(benches);
