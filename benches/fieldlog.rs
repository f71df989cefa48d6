//! `autotune nis` throughput: a generic CSV field log (a 2-D position sensor every step and
//! a scalar sensor every fifth, 120 000 updates) and the shipped PX4 fixtures, read and
//! judged end to end. Throughput is in updates per second.

use std::fmt::Write as _;
use std::path::PathBuf;

use autotune::internals::fieldlog::{NisSettings, ReadOptions, analyze};
use criterion::{Criterion, Throughput, criterion_group, criterion_main};

/// splitmix64 → two uniforms → one Box–Muller normal: enough for a bench's numbers.
fn normals(seed: u64) -> impl FnMut() -> f64 {
    let mut s = seed;
    move || {
        let mut next = || {
            s = s.wrapping_add(0x9e37_79b9_7f4a_7c15);
            let mut z = s;
            z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
            z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
            ((z ^ (z >> 31)) >> 11) as f64 / (1u64 << 53) as f64
        };
        let (u, v) = (next().max(1e-300), next());
        (-2.0 * u.ln()).sqrt() * (std::f64::consts::TAU * v).cos()
    }
}

fn fieldlog(c: &mut Criterion) {
    let dir = tempfile::tempdir().expect("a temporary directory");
    let csv = dir.path().join("log.csv");
    let mut n = normals(7);
    let mut text = String::from("time,sensor,nu_1,nu_2,S_1_1,S_2_1,S_2_2\n");
    let steps = 100_000;
    for k in 0..steps {
        let t = k as f64 * 0.01;
        let _ = writeln!(text, "{t:.2},pos,{:.6},{:.6},1,0,4", n(), 2.0 * n());
        if k % 5 == 0 {
            let _ = writeln!(text, "{t:.2},baro,{:.6},,2,,", 2f64.sqrt() * n());
        }
    }
    std::fs::write(&csv, text).expect("written");
    let mut g = c.benchmark_group("fieldlog");
    g.sample_size(10);
    g.throughput(Throughput::Elements((steps + steps / 5) as u64));
    g.bench_function("csv_120k_updates", |b| {
        b.iter(|| {
            analyze(
                std::slice::from_ref(&csv),
                &ReadOptions::default(),
                NisSettings::default(),
            )
            .expect("a valid log")
        })
    });
    let ulog = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/data/px4/white_new.ulg");
    let updates = analyze(
        std::slice::from_ref(&ulog),
        &ReadOptions::default(),
        NisSettings::default(),
    )
    .expect("the fixture reads")
    .overall
    .updates;
    g.throughput(Throughput::Elements(updates as u64));
    g.bench_function("px4_white_new", |b| {
        b.iter(|| {
            analyze(
                std::slice::from_ref(&ulog),
                &ReadOptions::default(),
                NisSettings::default(),
            )
            .expect("the fixture reads")
        })
    });
    g.finish();
}

criterion_group!(benches, fieldlog);
criterion_main!(benches);
