//! The worker protocol's own cost (issue #12, item 5): one evaluation of an external
//! experiment whose worker answers every request with ready-made records
//! (`benches/data/echo_worker.py`, which needs python3 and numpy). Throughput is in run-steps
//! per second, so its inverse is the protocol's overhead per run-step: the request, numpy's
//! `np.savez`, reading the archive and summing it into the statistics.

use std::path::Path;

use autotune::internals::experiment::Experiment;
use autotune::internals::problem::Problem;
use criterion::{Criterion, Throughput, criterion_group, criterion_main};

fn problem(dir: &Path, workers: usize, runs: usize, steps: usize) -> Problem {
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("benches/data/echo_worker.py");
    let text = format!(
        r#"name = "echo"
state_names = ["x", "vx", "y", "vy"]
[montecarlo]
runs = {runs}
steps = {steps}
[external]
command = ["python3", "{}"]
sensors = {{ pos = ["x", "y"] }}
workers = {workers}
check_seed_contract = false
[params.q]
value = 1.0
"#,
        script.display()
    );
    let path = dir.join(format!("echo{workers}.toml"));
    std::fs::write(&path, text).expect("a temporary file");
    Problem::load(&path).expect("a valid problem")
}

fn external(c: &mut Criterion) {
    let numpy = std::process::Command::new("python3")
        .args(["-c", "import numpy"])
        .status()
        .is_ok_and(|s| s.success());
    if !numpy {
        eprintln!("external bench skipped: it needs python3 with numpy");
        return;
    }
    let dir = tempfile::tempdir().expect("a temporary directory");
    let mut g = c.benchmark_group("external");
    g.sample_size(20);
    let (runs, steps) = (256, 200);
    g.throughput(Throughput::Elements((runs * steps) as u64));
    for workers in [1, 2] {
        let p = problem(dir.path(), workers, runs, steps);
        let theta = p.params().values();
        // Start the workers outside the timing.
        p.monte_carlo(&theta, p.mc())
            .expect("the echo worker answers");
        g.bench_function(format!("echo/N={runs},T={steps},workers={workers}"), |b| {
            b.iter(|| {
                p.monte_carlo(&theta, p.mc())
                    .expect("the echo worker answers")
            })
        });
    }
    g.finish();
}

criterion_group!(benches, external);
criterion_main!(benches);
