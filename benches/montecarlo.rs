//! One Monte Carlo evaluation (truth simulation, filter and statistics) per iteration.
//!
//! `montecarlo/cv2d/N=1000,T=1000` is the throughput target: 1e6 filter steps per
//! evaluation; throughput is reported in filter steps (elements) per second. The `catalog`
//! group times one N = 100, full-horizon evaluation of each named nonlinear model.

use std::hint::black_box;
use std::path::Path;

use autotune::internals::check::accumulate;
use autotune::internals::experiment::Experiment;
use autotune::internals::montecarlo::Engine;
use autotune::internals::problem::Problem;
use criterion::{Criterion, Throughput, criterion_group, criterion_main};

fn load(name: &str) -> Problem {
    let path = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("problems")
        .join(format!("{name}.toml"));
    Problem::load(&path).expect("shipped problem")
}

fn montecarlo(c: &mut Criterion) {
    let mut g = c.benchmark_group("montecarlo");
    g.sample_size(20);
    for (name, runs, steps, engine, label) in [
        ("cv2d", 1000, 1000, Engine::Linear, "cv2d/N=1000,T=1000"),
        (
            "cv2d",
            100,
            1000,
            Engine::Generic,
            "cv2d-generic/N=100,T=1000",
        ),
        ("cv1d", 1000, 1000, Engine::Linear, "cv1d/N=1000,T=1000"),
        (
            "dcmotor",
            1000,
            1000,
            Engine::Linear,
            "dcmotor/N=1000,T=1000",
        ),
    ] {
        let p = load(name);
        let theta = p.params().values();
        let mut mc = *p.mc();
        mc = mc.with_runs(runs).unwrap();
        mc = mc.with_steps(steps).unwrap();
        g.throughput(Throughput::Elements((runs * steps) as u64));
        g.bench_function(label, |b| {
            b.iter(|| accumulate(black_box(&p), black_box(&theta), black_box(&mc), engine).unwrap())
        });
    }
    g.finish();
}

/// One evaluation of each catalog problem as the tuner repeats it: N = 100 runs over the
/// problem's full horizon, at the shipped parameter values.
fn catalog(c: &mut Criterion) {
    let mut g = c.benchmark_group("catalog");
    g.sample_size(10);
    for name in ["ctrv", "orbit2d", "ins_gnss"] {
        let p = load(name);
        let theta = p.params().values();
        let mut mc = *p.mc();
        mc = mc.with_runs(100).unwrap();
        g.throughput(Throughput::Elements((mc.runs() * mc.steps()) as u64));
        g.bench_function(format!("{name}/N=100,T={}", mc.steps()), |b| {
            b.iter(|| {
                accumulate(
                    black_box(&p),
                    black_box(&theta),
                    black_box(&mc),
                    Engine::Auto,
                )
                .unwrap()
            })
        });
    }
    g.finish();
}

criterion_group!(benches, montecarlo, catalog);
criterion_main!(benches);
