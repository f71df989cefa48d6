//! Speed of light (issue #25): each catalog model's Monte Carlo evaluation by the generic
//! engine against a hand-written loop of the same truth and filter.
//!
//! The hand-written loop is what a numerical engineer would write for one model and one
//! statistic: fixed-size nalgebra matrices end to end, the filter's own fixed-size predict
//! and update (the same functions the `Filter` impl wraps, so both compute the same
//! numbers), no allocation per step, runs in chunks of 64 across rayon's threads. It keeps
//! exactly what the textbook gate (`GateMode::Mean`) reads: per-step NEES and NIS sums and
//! sums of squares, each run's NEES total, and the predicted variance of the NEES sum on
//! every [`NULL_VAR_STRIDE`]-th run. Before timing, each loop's ANEES, ANIS and null variance
//! are checked against the engine's (to 1e-9 relative: the two factor P in different
//! storage, so the last bits may differ), so the comparison is of the same work.
//!
//! Two settings per model: `sim` simulates the truth as `autotune check` does (the truth
//! model's own code in both loops); `tape` replays a recorded truth as a tune's later
//! evaluations do (`TruthCache`), which leaves the filter and the statistics alone. The
//! engine is timed in the mean gate (the hand loop's statistics) and in the full gate
//! (every component's spread and mean, whiteness: more statistics than the hand loop keeps).
//!
//! `cargo bench --bench speed_of_light`; the ratios are in docs/src/performance.md.

#![allow(non_snake_case)]

use std::hint::black_box;

use autotune::SimRng;
use autotune::internals::catalog::ctrv::{CtrvModel, LIDAR};
use autotune::internals::catalog::ins_gnss::InsGnss;
use autotune::internals::catalog::ins_gnss::truth::truth_nominal;
use autotune::internals::catalog::orbit2d::Orbit2d;
use autotune::internals::catalog::{CatalogModel, ModelContext, ModelError};
use autotune::internals::linalg::{mahalanobis_sq, wrap_angle};
use autotune::internals::measurement::Measurement;
use autotune::internals::model::TruthModel;
use autotune::internals::montecarlo::{
    McConfig, NULL_VAR_STRIDE, TruthCache, run_generic, run_generic_cached, run_rng,
};
use autotune::internals::stats::{Accumulator, GateMode};
use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use nalgebra::{Cholesky, Const, DVector, SMatrix, SVector, Vector2, Vector3, Vector4, Vector5};
use rayon::prelude::*;

/// Runs per evaluation: two chunks of 64, one per core of the project's 2-core machine.
const RUNS: usize = 128;
const CHUNK: usize = 64;

/// The shipped problem's `[model]` table (without `name`) and its context.
fn shipped(name: &str) -> (toml::Table, ModelContext) {
    let path = format!("{}/problems/{name}.toml", env!("CARGO_MANIFEST_DIR"));
    let file: toml::Table =
        toml::from_str(&std::fs::read_to_string(&path).expect("problem")).expect("valid TOML");
    let mut table = file["model"].as_table().expect("[model]").clone();
    table.remove("name");
    let steps = file["montecarlo"]["steps"].as_integer().expect("steps") as usize;
    let dt = file["dt"].as_float().expect("dt");
    (table, ModelContext { dt, steps })
}

/// What the mean gate reads, summed by hand.
#[derive(Clone)]
struct Sums {
    nees: Vec<f64>,
    nees_sq: Vec<f64>,
    nis: Vec<f64>,
    nis_sq: Vec<f64>,
    nis_dof: Vec<f64>,
    run_total: f64,
    run_total_sq: f64,
    null_var: f64,
    null_runs: usize,
}

impl Sums {
    fn new(steps: usize) -> Self {
        let z = vec![0.0; steps];
        Sums {
            nees: z.clone(),
            nees_sq: z.clone(),
            nis: z.clone(),
            nis_sq: z.clone(),
            nis_dof: z,
            run_total: 0.0,
            run_total_sq: 0.0,
            null_var: 0.0,
            null_runs: 0,
        }
    }

    fn merge(&mut self, o: &Sums) {
        for (a, b) in [
            (&mut self.nees, &o.nees),
            (&mut self.nees_sq, &o.nees_sq),
            (&mut self.nis, &o.nis),
            (&mut self.nis_sq, &o.nis_sq),
            (&mut self.nis_dof, &o.nis_dof),
        ] {
            a.iter_mut().zip(b).for_each(|(a, b)| *a += b);
        }
        self.run_total += o.run_total;
        self.run_total_sq += o.run_total_sq;
        self.null_var += o.null_var;
        self.null_runs += o.null_runs;
    }

    #[inline]
    fn step(&mut self, i: usize, nees: f64, nis: f64, dof: usize) {
        self.nees[i] += nees;
        self.nees_sq[i] += nees * nees;
        if dof > 0 {
            self.nis[i] += nis;
            self.nis_sq[i] += nis * nis;
            self.nis_dof[i] += dof as f64;
        }
    }

    fn end_run(&mut self, total: f64, null_var: Option<f64>) {
        self.run_total += total;
        self.run_total_sq += total * total;
        if let Some(v) = null_var {
            self.null_var += v;
            self.null_runs += 1;
        }
    }

    /// ANEES (per state), ANIS (per measurement component), mean null variance per run.
    fn summary(&self, n_x: usize, runs: usize) -> [f64; 3] {
        let steps = self.nees.len() as f64;
        [
            self.nees.iter().sum::<f64>() / (runs as f64 * steps * n_x as f64),
            self.nis.iter().sum::<f64>() / self.nis_dof.iter().sum::<f64>(),
            self.null_var / self.null_runs as f64,
        ]
    }
}

/// The engine's counterpart of [`Sums::summary`].
fn engine_summary(acc: &Accumulator, n_x: usize) -> [f64; 3] {
    let s = |v: &[f64]| v.iter().sum::<f64>();
    [
        s(acc.nees_sum()) / (s(acc.nees_count()) * n_x as f64),
        s(acc.nis_sum()) / s(acc.nis_dof()),
        acc.nees_null_var() / acc.null_var_runs() as f64,
    ]
}

/// The predicted variance of one run's NEES sum, on fixed-size matrices: the recursion of
/// `stats::NeesNullVariance` (`G ← A (G + P_prev) A'`, `2 n + 4 tr(P⁻¹ G)` a step).
struct NullVar<const N: usize> {
    g: SMatrix<f64, N, N>,
    p_prev: Option<SMatrix<f64, N, N>>,
    var: f64,
}

impl<const N: usize> NullVar<N> {
    fn new() -> Self {
        NullVar {
            g: SMatrix::zeros(),
            p_prev: None,
            var: 0.0,
        }
    }

    #[inline]
    fn step(
        &mut self,
        a: &SMatrix<f64, N, N>,
        p: &SMatrix<f64, N, N>,
        chol: &Cholesky<f64, Const<N>>,
    ) {
        if let Some(pp) = &self.p_prev {
            self.g = a * (self.g + pp) * a.transpose();
        }
        self.var += 2.0 * N as f64 + 4.0 * chol.solve(&self.g).trace();
        self.p_prev = Some(*p);
    }
}

/// One run's truth, simulated as the engine's `Live` source does or replayed from a record.
enum Truth<'a> {
    Live {
        model: &'a dyn TruthModel,
        rng: SimRng,
        x: DVector<f64>,
        u: Option<DVector<f64>>,
        meas: Vec<Measurement>,
    },
    Tape {
        tape: &'a RunTape,
        k: usize,
    },
}

/// A recorded run: states, inputs and measurements of steps 1..=T.
struct RunTape {
    x: Vec<DVector<f64>>,
    u: Vec<Option<DVector<f64>>>,
    meas: Vec<Vec<Measurement>>,
}

impl<'a> Truth<'a> {
    fn live(model: &'a dyn TruthModel, seed: u64, run: usize) -> Self {
        let mut rng = run_rng(seed, run);
        let x = model.initial_state(&mut rng);
        Truth::Live {
            model,
            rng,
            x,
            u: None,
            meas: Vec::new(),
        }
    }

    #[inline]
    fn advance(&mut self, k: usize) {
        match self {
            Truth::Live {
                model,
                rng,
                x,
                u,
                meas,
            } => {
                *x = model.propagate(k, x, rng);
                *u = model.input(k, x, rng);
                meas.clear();
                model.measure(k, x, rng, meas);
            }
            Truth::Tape { k: at, .. } => *at = k - 1,
        }
    }

    fn state(&self) -> &DVector<f64> {
        match self {
            Truth::Live { x, .. } => x,
            Truth::Tape { tape, k } => &tape.x[*k],
        }
    }

    fn input(&self) -> Option<&DVector<f64>> {
        match self {
            Truth::Live { u, .. } => u.as_ref(),
            Truth::Tape { tape, k } => tape.u[*k].as_ref(),
        }
    }

    fn measurements(&self) -> &[Measurement] {
        match self {
            Truth::Live { meas, .. } => meas,
            Truth::Tape { tape, k } => &tape.meas[*k],
        }
    }
}

fn record(model: &dyn TruthModel, seed: u64, run: usize, steps: usize) -> RunTape {
    let mut t = Truth::live(model, seed, run);
    let mut tape = RunTape {
        x: Vec::new(),
        u: Vec::new(),
        meas: Vec::new(),
    };
    for k in 1..=steps {
        t.advance(k);
        tape.x.push(t.state().clone());
        tape.u.push(t.input().cloned());
        tape.meas.push(t.measurements().to_vec());
    }
    tape
}

/// The runs of `mc` in chunks of 64 across rayon's threads, merged in chunk order (as the
/// engine does), each run by `one_run(truth, run, sums)`.
fn by_hand<R>(mc: &McConfig, tapes: Option<&[RunTape]>, truth: &dyn TruthModel, one_run: R) -> Sums
where
    R: Fn(Truth<'_>, usize, &mut Sums) + Sync,
{
    let (runs, steps) = (mc.runs(), mc.steps());
    let parts: Vec<Sums> = (0..runs.div_ceil(CHUNK))
        .into_par_iter()
        .map(|c| {
            let mut sums = Sums::new(steps);
            for run in c * CHUNK..((c + 1) * CHUNK).min(runs) {
                let src = match tapes {
                    Some(t) => Truth::Tape {
                        tape: &t[run],
                        k: 0,
                    },
                    None => Truth::live(truth, mc.seed(), run),
                };
                one_run(src, run, &mut sums);
            }
            sums
        })
        .collect();
    let mut total = Sums::new(steps);
    parts.iter().for_each(|p| total.merge(p));
    total
}

/// The end of a step common to every model: NEES from the fixed-size factor, the sums,
/// and the null-variance recursion on sampled runs.
#[inline]
#[allow(clippy::too_many_arguments)]
fn close_step<const N: usize>(
    sums: &mut Sums,
    k: usize,
    e: &SVector<f64, N>,
    P: &SMatrix<f64, N, N>,
    A: &SMatrix<f64, N, N>,
    nis: f64,
    dof: usize,
    nv: &mut Option<NullVar<N>>,
) -> f64 {
    let chol = Cholesky::new(*P).expect("P positive definite at the truth's noise");
    let nees = mahalanobis_sq(&chol, e);
    sums.step(k - 1, nees, nis, dof);
    if let Some(nv) = nv {
        nv.step(A, P, &chol);
    }
    nees
}

fn sampled<const N: usize>(run: usize) -> Option<NullVar<N>> {
    run.is_multiple_of(NULL_VAR_STRIDE).then(NullVar::new)
}

fn ctrv_by_hand(
    model: &CtrvModel,
    theta: &[f64],
    mc: &McConfig,
    tapes: Option<&[RunTape]>,
) -> Sums {
    let f = model.ukf(theta);
    by_hand(mc, tapes, &model.truth, |mut truth, run, sums| {
        let (mut x, mut P) = (f.x0, f.P0);
        let (mut nv, mut total) = (sampled::<5>(run), 0.0);
        for k in 1..=mc.steps() {
            truth.advance(k);
            let (x1, P1, mut A) = f.predict_fixed(k, &x, &P).expect("predict");
            (x, P) = (x1, P1);
            let (mut nis, mut dof) = (0.0, 0);
            for m in truth.measurements() {
                let (x1, P1, IKH, s) = if m.sensor == LIDAR {
                    let u = f
                        .update_lidar(k, &x, &P, &Vector2::from_column_slice(m.z.as_slice()))
                        .expect("update");
                    (u.x, u.P, u.IKH, u.nis)
                } else {
                    let u = f
                        .update_radar(k, &x, &P, &Vector3::from_column_slice(m.z.as_slice()))
                        .expect("update");
                    (u.x, u.P, u.IKH, u.nis)
                };
                (x, P, A) = (x1, P1, IKH * A);
                nis += s;
                dof += m.z.len();
            }
            let mut e = Vector5::from_column_slice(truth.state().as_slice()) - x;
            e[3] = wrap_angle(e[3]);
            total += close_step(sums, k, &e, &P, &A, nis, dof, &mut nv);
        }
        sums.end_run(total, nv.map(|v| v.var));
    })
}

fn orbit2d_by_hand(
    model: &Orbit2d,
    theta: &[f64],
    mc: &McConfig,
    tapes: Option<&[RunTape]>,
) -> Sums {
    let f = model.ekf(theta);
    by_hand(mc, tapes, &model.truth, |mut truth, run, sums| {
        let (mut x, mut P) = (f.x0, f.P0);
        let (mut nv, mut total) = (sampled::<4>(run), 0.0);
        for k in 1..=mc.steps() {
            truth.advance(k);
            let (x1, P1, mut A) = f.predict_fixed(k, &x, &P).expect("predict");
            (x, P) = (x1, P1);
            let (mut nis, mut dof) = (0.0, 0);
            for m in truth.measurements() {
                let z = Vector3::from_column_slice(m.z.as_slice());
                let (x1, cu, _, s) = f.update_fixed(k, m.sensor, &x, &P, &z).expect("update");
                (x, P, A) = (x1, cu.P, cu.IKH * A);
                nis += s;
                dof += 3;
            }
            let e = Vector4::from_column_slice(truth.state().as_slice()) - x;
            total += close_step(sums, k, &e, &P, &A, nis, dof, &mut nv);
        }
        sums.end_run(total, nv.map(|v| v.var));
    })
}

fn ins_gnss_by_hand(
    model: &InsGnss,
    theta: &[f64],
    mc: &McConfig,
    tapes: Option<&[RunTape]>,
) -> Sums {
    let f = model.eskf(theta);
    by_hand(mc, tapes, &model.truth, |mut truth, run, sums| {
        let (mut nom, mut P) = (f.x0, f.P0);
        let (mut nv, mut total) = (sampled::<15>(run), 0.0);
        for k in 1..=mc.steps() {
            truth.advance(k);
            let u = truth.input().expect("IMU input");
            let mut A = f.propagate(&mut nom, &mut P, u.as_slice());
            let (mut nis, mut dof) = (0.0, 0);
            for m in truth.measurements() {
                let z = Vector3::from_column_slice(m.z.as_slice());
                let (n1, cu, _, s) = f.update_fixed(k, &nom, &P, &z).expect("update");
                (nom, P, A) = (n1, cu.P, cu.IKH * A);
                nis += s;
                dof += 3;
            }
            let t = truth_nominal(truth.state()).expect("truth state");
            let e = nom.error_to(&t);
            total += close_step(sums, k, &e, &P, &A, nis, dof, &mut nv);
        }
        sums.end_run(total, nv.map(|v| v.var));
    })
}

/// A hand-written loop of one model: the model, θ, the Monte Carlo settings and the
/// recorded truth (or `None` to simulate it).
type ByHand<M> = fn(&M, &[f64], &McConfig, Option<&[RunTape]>) -> Sums;

/// Bench one shipped catalog problem, built by `build`, against its hand-written loop.
fn compare<M: CatalogModel>(
    c: &mut Criterion,
    name: &'static str,
    build: fn(&toml::Table, &ModelContext) -> Result<M, ModelError>,
    hand: ByHand<M>,
) {
    let (table, ctx) = shipped(name);
    let model = build(&table, &ctx).expect("the shipped problem builds");
    let steps = ctx.steps;
    let theta = model.truth_values();
    let by_hand = |mc: &McConfig, t: Option<&[RunTape]>| hand(&model, &theta, mc, t);
    let filter = model.filter(&theta);
    let truth = model.truth();
    let n_x = filter.n_x();
    let mc = McConfig::new(RUNS, steps)
        .expect("settings")
        .with_seed(7)
        .with_gate(GateMode::Mean);
    let full = mc.with_gate(GateMode::Full);
    let tapes: Vec<RunTape> = (0..RUNS)
        .map(|r| record(truth, mc.seed(), r, steps))
        .collect();
    let cache = TruthCache::default();
    for _ in 0..2 {
        // The cache records a seed set on its second request.
        run_generic_cached(truth, &filter, &mc, Default::default(), &cache);
    }

    // The same work: the hand loop's statistics are the engine's.
    let want = engine_summary(&run_generic(truth, &filter, &mc), n_x);
    for (what, got) in [
        ("sim", by_hand(&mc, None)),
        ("tape", by_hand(&mc, Some(&tapes))),
    ] {
        let got = got.summary(n_x, RUNS);
        for (w, g) in want.iter().zip(got) {
            assert!(
                (w - g).abs() <= 1e-9 * w.abs(),
                "{name} {what}: the hand-written loop gives {got:?}, the engine {want:?}"
            );
        }
    }

    let mut g = c.benchmark_group(format!("speed_of_light/{name}"));
    g.sample_size(10);
    g.throughput(Throughput::Elements((RUNS * steps) as u64));
    g.bench_function("sim/by_hand", |b| b.iter(|| by_hand(black_box(&mc), None)));
    g.bench_function("sim/engine_mean", |b| {
        b.iter(|| run_generic(truth, &filter, black_box(&mc)))
    });
    g.bench_function("sim/engine_full", |b| {
        b.iter(|| run_generic(truth, &filter, black_box(&full)))
    });
    g.bench_function("tape/by_hand", |b| {
        b.iter(|| by_hand(black_box(&mc), Some(&tapes)))
    });
    g.bench_function("tape/engine_mean", |b| {
        b.iter(|| run_generic_cached(truth, &filter, black_box(&mc), Default::default(), &cache))
    });
    g.finish();
}

fn speed_of_light(c: &mut Criterion) {
    compare(c, "ctrv", CtrvModel::from_table, ctrv_by_hand);
    compare(c, "orbit2d", Orbit2d::from_table, orbit2d_by_hand);
    compare(c, "ins_gnss", InsGnss::new, ins_gnss_by_hand);
}

criterion_group!(benches, speed_of_light);
criterion_main!(benches);
