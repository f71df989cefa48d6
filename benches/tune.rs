//! One whole tuning run (search and confirmation) of each shipped problem, as
//! `autotune tune` does it with default settings: the linear problems (`tune/…`) and the
//! catalog's nonlinear ones with their files' `[tune]` (`catalog/…`, issue 25's target:
//! each under 10 s on a 2-core machine).

use std::hint::black_box;
use std::path::Path;

use autotune::internals::experiment::Experiment;
use autotune::internals::problem::Problem;
use autotune::internals::tune::{Silent, TuneSettings, tune};
use criterion::{Criterion, criterion_group, criterion_main};

fn load(name: &str) -> Problem {
    let path = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("problems")
        .join(format!("{name}.toml"));
    Problem::load(&path).expect("shipped problem")
}

fn tuning(c: &mut Criterion) {
    let mut g = c.benchmark_group("tune");
    g.sample_size(10);
    for name in ["cv1d", "cv2d", "dcmotor"] {
        let p = load(name);
        let start = p.params().values();
        let fixed: Vec<bool> = p.params().params.iter().map(|q| q.fixed).collect();
        let settings = TuneSettings::default();
        g.bench_function(name, |b| {
            b.iter(|| {
                tune(
                    black_box(&p),
                    black_box(&start),
                    &fixed,
                    p.mc(),
                    &settings,
                    &Silent,
                )
                .expect("valid settings")
            })
        });
    }
    g.finish();
}

/// The catalog problems as `autotune tune problems/<name>.toml` runs them: loaded afresh in
/// every iteration, so no iteration finds the truth tapes of the one before (a process
/// starts without them), and tuned with the file's `[tune]` settings.
fn catalog(c: &mut Criterion) {
    let mut g = c.benchmark_group("catalog");
    g.sample_size(10);
    for name in ["ctrv", "orbit2d", "ins_gnss"] {
        g.bench_function(name, |b| {
            b.iter(|| {
                let p = load(name);
                let start = p.params().values();
                let fixed: Vec<bool> = p.params().params.iter().map(|q| q.fixed).collect();
                tune(black_box(&p), &start, &fixed, p.mc(), &p.tune, &Silent)
                    .expect("valid settings")
            })
        });
    }
    g.finish();
}

criterion_group!(benches, tuning, catalog);
criterion_main!(benches);
