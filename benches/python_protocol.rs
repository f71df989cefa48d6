//! Issue #25: the protocol's share of an evaluation for a Python worker answering with sums
//! through the Python package (`examples/python/cv2d_numpy.py --sums`, numpy, one worker,
//! 256 runs × 200 steps), against the same worker answering with `.npz` records files.
//!
//! Needs a Python with the package installed: `AUTOTUNE_PYTHON=/path/to/venv/bin/python`
//! (python/ci.sh makes one; or `pip install` the wheel of python/build_wheel.sh); skipped
//! otherwise. The worker reports its own seconds (`AUTOTUNE_WORKER_STATS`): in `simulate`
//! (its filter and truth), and in summing and answering (the statistics, autotune's own
//! work done in the worker) or in writing records; the rest of the wall time is the
//! protocol's: requests, pipes, files, waiting.

use std::path::Path;
use std::time::Instant;

use autotune::internals::experiment::Experiment;
use autotune::internals::problem::Problem;
use criterion::{Criterion, criterion_group, criterion_main};

const RUNS: usize = 256;
const STEPS: usize = 200;

fn problem(dir: &Path, python: &str, sums: bool) -> Problem {
    let example = Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/python/cv2d_numpy.py");
    let flag = if sums { ", \"--sums\"" } else { "" };
    let text = format!(
        r#"name = "cv2d_numpy"
state_names = ["x", "vx", "y", "vy"]
[montecarlo]
runs = {RUNS}
steps = {STEPS}
seed = 2
[external]
command = ["{python}", "{}"{flag}]
sensors = {{ pos = ["x", "y"] }}
workers = 1
check_seed_contract = false
[params.q_accel_x]
value = 0.5
[params.q_accel_y]
value = 0.1
[params.r_pos_x]
value = 1.0
[params.r_pos_y]
value = 4.0
"#,
        example.display()
    );
    let path = dir.join(format!("cv2d_{sums}.toml"));
    std::fs::write(&path, text).expect("a temporary file");
    Problem::load(&path).expect("a valid problem")
}

/// The worker's own seconds in `simulate` and in its answers (summing or writing), and its
/// requests, from its stats line.
fn worker_seconds(stats: &Path) -> (f64, f64, f64) {
    let text = std::fs::read_to_string(stats).expect("the worker's stats");
    let v: serde_json::Value =
        serde_json::from_str(text.lines().last().expect("a line")).expect("JSON");
    let answer = v
        .get("sums_s")
        .or_else(|| v.get("write_s"))
        .expect("answer time");
    (
        v["simulate_s"].as_f64().expect("simulate_s"),
        answer.as_f64().expect("seconds"),
        v["requests"].as_f64().expect("requests"),
    )
}

fn python_protocol(c: &mut Criterion) {
    let Ok(python) = std::env::var("AUTOTUNE_PYTHON") else {
        eprintln!(
            "python_protocol bench skipped: set AUTOTUNE_PYTHON to a python with the autotune package"
        );
        return;
    };
    let dir = tempfile::tempdir().expect("a temporary directory");
    let mut g = c.benchmark_group("python_protocol");
    g.sample_size(20);
    for sums in [true, false] {
        let name = if sums { "sums" } else { "npz" };
        // A separate measurement first: the worker's own seconds over a fixed number of
        // evaluations, from its stats line when its stdin closes.
        let stats = dir.path().join(format!("stats_{name}.jsonl"));
        // SAFETY: the bench is single-threaded here; the worker inherits the variable.
        unsafe { std::env::set_var("AUTOTUNE_WORKER_STATS", &stats) };
        let evaluations = 20;
        let wall = {
            let p = problem(dir.path(), &python, sums);
            let theta = p.params().values();
            p.monte_carlo(&theta, p.mc()).expect("the worker answers");
            let t0 = Instant::now();
            for _ in 0..evaluations {
                p.monte_carlo(&theta, p.mc()).expect("the worker answers");
            }
            t0.elapsed().as_secs_f64()
            // The worker exits here, writing its stats.
        };
        unsafe { std::env::remove_var("AUTOTUNE_WORKER_STATS") };
        std::thread::sleep(std::time::Duration::from_millis(300));
        let (simulate, answer, requests) = worker_seconds(&stats);
        let per = requests / (evaluations + 1) as f64;
        let n = (evaluations + 1) as f64;
        let (sim_ms, ans_ms) = (simulate / n * 1e3, answer / n * 1e3);
        let eval_ms = wall / evaluations as f64 * 1e3;
        println!(
            "python_protocol {name}: evaluation {eval_ms:.1} ms ({per:.0} requests); worker: simulate {sim_ms:.1} ms, {} {ans_ms:.1} ms; protocol {:.1} ms = {:.1}% of the evaluation",
            if sums { "sums" } else { "np.savez" },
            eval_ms - sim_ms - ans_ms,
            100.0 * (eval_ms - sim_ms - ans_ms) / eval_ms,
        );
        let p = problem(dir.path(), &python, sums);
        let theta = p.params().values();
        p.monte_carlo(&theta, p.mc()).expect("the worker answers");
        g.bench_function(format!("{name}/N={RUNS},T={STEPS},workers=1"), |b| {
            b.iter(|| p.monte_carlo(&theta, p.mc()).expect("the worker answers"))
        });
    }
    g.finish();
}

criterion_group!(benches, python_protocol);
criterion_main!(benches);
