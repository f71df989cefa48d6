//! One whole tuning run (search and confirmation) of each shipped problem, as
//! `autotune tune` does it with default settings.

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

criterion_group!(benches, tuning);
criterion_main!(benches);
