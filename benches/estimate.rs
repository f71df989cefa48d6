//! Q and R from measurements on cv2d records simulated from the problem's truth: maximum
//! likelihood (L-BFGS from all parameters = 1.0) on 5 000 and 20 000 steps, ALS (two
//! passes, 15 lags) on 20 000, and with the `sdp` feature ALS with a full Q and R; ML and
//! single likelihood evaluations on records with 1% of the cells empty.

use autotune::internals::estimate::als::{self, AlsModel};
use autotune::internals::estimate::{MeasurementRecord, ml, simulate};
use autotune::internals::experiment::Experiment as _;
use autotune::internals::problem::Problem;
use criterion::{Criterion, criterion_group, criterion_main};

fn estimate(c: &mut Criterion) {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("problems/cv2d.toml");
    let p = Problem::load(&path).expect("the shipped problem loads");
    let lin = p.linear().expect("cv2d is linear");
    let build = |theta: &[f64]| lin.filter_at(theta);
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
    // With 1% of the cells empty, the ML search, and one evaluation of the likelihood at
    // the truth beside one on the complete record: the cost of gaps per evaluation.
    let gaps = with_gaps(simulate(&lin.truth, 2, 1, 5_000, 7).measurements);
    g.bench_function("ml_gaps1pct_5000_steps", |b| {
        b.iter(|| ml::estimate(&build, &gaps, &start, &fixed, 200).expect("converges"))
    });
    let model = build(&[0.5, 0.1, 1.0, 4.0]);
    for steps in [5_000, 20_000] {
        let full = simulate(&lin.truth, 2, 1, steps, 7).measurements;
        let gaps = with_gaps(full.clone());
        for (name, d) in [("complete", &full), ("gaps1pct", &gaps)] {
            g.bench_function(format!("nll_{name}_{steps}_steps"), |b| {
                b.iter(|| model.neg_log_likelihood(d).expect("definite"))
            });
        }
    }
    let data = simulate(&lin.truth, 2, 1, 20_000, 7).measurements;
    let model = AlsModel::of(lin);
    g.bench_function("als_20000_steps", |b| {
        b.iter(|| als::estimate_passes(&model, &data, &start, &fixed, 15, 2).expect("solves"))
    });
    #[cfg(feature = "sdp")]
    g.bench_function("als_full_qr_20000_steps", |b| {
        b.iter(|| {
            autotune::internals::estimate::als_full::estimate_full(
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

/// `data` with 1% of its cells empty, drawn independently by a fixed linear congruential
/// stream.
fn with_gaps(mut data: MeasurementRecord) -> MeasurementRecord {
    let mut s: u64 = 7;
    for v in data.sequences.iter_mut().flat_map(|q| q.z.iter_mut()) {
        s = s
            .wrapping_mul(6_364_136_223_846_793_005)
            .wrapping_add(1_442_695_040_888_963_407);
        if s >> 33 < (1 << 31) / 100 {
            *v = f64::NAN;
        }
    }
    data
}

criterion_group!(benches, estimate);
criterion_main!(benches);
