//! Q and R from measurements on cv2d records simulated from the problem's truth: maximum
//! likelihood (L-BFGS from all parameters = 1.0) on 5 000 and 20 000 steps, ALS (two
//! passes, 15 lags) on 20 000, and with the `sdp` feature ALS with a full Q and R.

use autotune::estimate::als::{self, AlsModel};
use autotune::estimate::{LinearFilterModel, ml, simulate};
use autotune::problem::Problem;
use criterion::{Criterion, criterion_group, criterion_main};

fn estimate(c: &mut Criterion) {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("problems/cv2d.toml");
    let p = Problem::load(&path).expect("the shipped problem loads");
    let lin = p.linear().expect("cv2d is linear");
    let build = |theta: &[f64]| LinearFilterModel::of(lin, theta);
    let start = [1.0; 4];
    let fixed = [false; 4];
    let mut g = c.benchmark_group("estimate_cv2d");
    g.sample_size(10);
    for steps in [5_000, 20_000] {
        let data = simulate(&lin.truth, 2, 1, steps, 7).measurements;
        g.bench_function(format!("ml_{steps}_steps"), |b| {
            b.iter(|| ml::estimate(&build, &data, &start, &fixed, 200).expect("converges"))
        });
    }
    let data = simulate(&lin.truth, 2, 1, 20_000, 7).measurements;
    let model = AlsModel::of(lin);
    g.bench_function("als_20000_steps", |b| {
        b.iter(|| als::estimate_passes(&model, &data, &start, &fixed, 15, 2).expect("solves"))
    });
    #[cfg(feature = "sdp")]
    g.bench_function("als_full_qr_20000_steps", |b| {
        b.iter(|| {
            autotune::estimate::als_full::estimate_full(
                &model,
                &data,
                &start,
                &fixed,
                als::FullMatrix::Both,
                15,
                2,
            )
            .expect("solves")
        })
    });
    g.finish();
}

criterion_group!(benches, estimate);
criterion_main!(benches);
