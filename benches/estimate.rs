//! Q and R from measurements on cv2d records simulated from the problem's truth: maximum
//! likelihood (L-BFGS from all parameters = 1.0) on 5 000 and 20 000 steps, ALS (two
//! passes, 15 lags) on 20 000, and with the `sdp` feature ALS with a full Q and R; ML and
//! single likelihood evaluations on records with 1% of the cells empty. A catalog filter (the
//! ctrv UKF) replayed over a 10 000-reading record: one likelihood evaluation against a
//! hand-written predict/update loop of the same filter over the same readings (issue 39's
//! bound: at most 1.5× as long), and the maximum-likelihood estimate on that record (in
//! under 100 evaluations' time).

use autotune::internals::estimate::als::{self, AlsModel};
use autotune::internals::estimate::{
    FilterReplay, MeasurementRecord, ml, simulate, simulate_sensors,
};
use autotune::internals::experiment::Experiment as _;
use autotune::internals::filter::Filter;
use autotune::internals::measurement::Measurement;
use autotune::internals::problem::Problem;
use autotune::{HeldAsCode, Structure};
use criterion::{Criterion, criterion_group, criterion_main};
use nalgebra::DVector;

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

/// The ctrv UKF over a record of 10 000 steps of alternating lidar and radar (one reading a
/// step), at the truth's noise: the replay's `−log L`, the same filter's predict/update loop
/// written by hand over readings built beforehand (the floor any replay has), and the
/// maximum-likelihood estimate from the problem's start (process noise 10× too small).
fn replayed(c: &mut Criterion) {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("problems/ctrv.toml");
    let p = Problem::load(&path).expect("the shipped problem loads");
    let params = p.params();
    let start = params.values();
    let fixed: Vec<bool> = params.params.iter().map(|d| d.fixed).collect();
    let truth: Vec<f64> = start
        .iter()
        .zip(&params.params)
        .map(|(v, d)| {
            if d.name.starts_with("q_") {
                10.0 * v
            } else {
                *v
            }
        })
        .collect();
    let dims = p.replay_filter(&truth).expect("held as code").sensor_dims();
    let truth_model = p.simulation_truth().expect("held as code");
    let data = simulate_sensors(truth_model, &dims, 1, 10_000, 11).measurements;
    let readings = hand_readings(&data, &dims);
    assert_eq!(readings.len(), 10_000, "one reading a step");
    let replay = FilterReplay::new(&p, data).expect("the record fits");
    let mut g = c.benchmark_group("replay_ctrv");
    g.sample_size(20);
    g.bench_function("nll_10000_readings", |b| {
        b.iter(|| replay.neg_log_likelihood(&truth).expect("runs"))
    });
    g.bench_function("hand_loop_10000_readings", |b| {
        b.iter(|| {
            let filter = p.replay_filter(&truth).expect("held as code");
            by_hand(&*filter, &readings)
        })
    });
    let nll = |t: &[f64]| replay.neg_log_likelihood(t).ok();
    let values = replay.data().values();
    let est = ml::estimate_by(&nll, values, &start, &fixed, 200).expect("converges");
    eprintln!(
        "replay_ctrv: the estimate takes {} likelihood evaluations ({} L-BFGS iterations)",
        est.evaluations, est.iterations
    );
    g.sample_size(10);
    g.bench_function("ml_10000_readings", |b| {
        b.iter(|| ml::estimate_by(&nll, values, &start, &fixed, 200).expect("converges"))
    });
    g.finish();
}

/// Each step's readings as the filter takes them (sensor, values), built once.
fn hand_readings(data: &MeasurementRecord, dims: &[usize]) -> Vec<(usize, Measurement)> {
    let mut out = Vec::new();
    for (k, z) in data.sequences[0].z.chunks(data.dim).enumerate() {
        let mut o = 0;
        for (sensor, &d) in dims.iter().enumerate() {
            if z[o].is_finite() {
                let z = DVector::from_column_slice(&z[o..o + d]);
                out.push((k + 1, Measurement { sensor, z }));
            }
            o += d;
        }
    }
    out
}

/// `−log L` by the filter's own loop: predict to each reading's step, update, and add
/// `½ (log det S + NIS + m log 2π)`.
fn by_hand(filter: &dyn Filter, readings: &[(usize, Measurement)]) -> f64 {
    let mut est = filter.initial();
    let mut at = 0;
    let mut nll = 0.0;
    for (step, meas) in readings {
        while at < *step {
            at += 1;
            filter.predict(at, &mut est).expect("predicts");
        }
        let inn = filter.update(at, &mut est, meas).expect("updates");
        let m = inn.nu.len() as f64;
        nll += 0.5 * (inn.S.determinant().ln() + inn.nis + m * (2.0 * std::f64::consts::PI).ln());
    }
    nll
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

criterion_group!(benches, estimate, replayed);
criterion_main!(benches);
