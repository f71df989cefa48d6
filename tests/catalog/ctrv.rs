//! The `ctrv_radar_lidar` catalog model (`problems/ctrv.toml`): analytic Jacobians, the
//! fixed-size UKF against the generic one, bearing wrap at ±π, the sensor schedule, input
//! validation, and the Monte Carlo verdicts at the truth's noise and at Q × 0.01.

#![allow(non_snake_case)]

use crate::common;
use common::NoMap;

use std::f64::consts::PI;

use autotune::SimRng;
use autotune::internals::catalog::ctrv::{CtrvModel, CtrvSystem, ENTRY, LIDAR, RADAR, wrap_angle};
use autotune::internals::catalog::{CatalogModel, ModelContext};
use autotune::internals::filter::{Filter, SystemModel, numerical_jacobian};
use autotune::internals::measurement::Measurement;
use autotune::internals::model::TruthModel;
use autotune::internals::montecarlo::{McConfig, run_generic, run_rng};
use autotune::internals::stats::{ConsistencyReport, Verdict};
use nalgebra::{DMatrix, DVector};
use rand::{RngExt, SeedableRng};

/// The shipped problem: its `[model]` table (without `name`), dt, and Monte Carlo settings.
struct Shipped {
    table: toml::Table,
    dt: f64,
    runs: usize,
    steps: usize,
    seed: u64,
    alpha: f64,
}

fn shipped() -> Shipped {
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/problems/ctrv.toml");
    let file: toml::Table = toml::from_str(&std::fs::read_to_string(path).unwrap()).unwrap();
    let mc = file["montecarlo"].as_table().unwrap();
    let int = |k: &str| mc[k].as_integer().unwrap();
    let mut table = file["model"].as_table().unwrap().clone();
    assert_eq!(table.remove("name").unwrap().as_str(), Some(ENTRY.name));
    Shipped {
        table,
        dt: file["dt"].as_float().unwrap(),
        runs: int("runs") as usize,
        steps: int("steps") as usize,
        seed: int("seed") as u64,
        alpha: mc["alpha"].as_float().unwrap(),
    }
}

fn build(s: &Shipped) -> Box<dyn CatalogModel> {
    (ENTRY.build)(
        &s.table,
        &ModelContext {
            dt: s.dt,
            steps: s.steps,
        },
    )
    .unwrap()
}

/// The concrete model (for the fixed-size and reference filters).
fn concrete(s: &Shipped) -> CtrvModel {
    // The entry's build path, returning the concrete type.
    CtrvModel::from_table(
        &s.table,
        &ModelContext {
            dt: s.dt,
            steps: s.steps,
        },
    )
    .unwrap()
}

fn max_rel(a: &DMatrix<f64>, b: &DMatrix<f64>) -> f64 {
    let scale = a.abs().max().max(b.abs().max()).max(1e-300);
    (a - b).abs().max() / scale
}

/// Representative states: random around the scenario, plus the edge cases of the
/// transition (ω = 0 and inside the Taylor branch, fast turns, reversing, yaw beyond ±π).
fn states() -> Vec<DVector<f64>> {
    let mut rng = SimRng::seed_from_u64(7);
    let mut xs: Vec<DVector<f64>> = (0..20)
        .map(|_| {
            DVector::from_column_slice(&[
                rng.random_range(-60.0..20.0),
                rng.random_range(-40.0..40.0),
                rng.random_range(0.5..10.0),
                rng.random_range(-7.0..7.0),
                rng.random_range(-1.0..1.0),
            ])
        })
        .collect();
    for x in [
        [-30.0, -20.0, 5.0, 0.0, 0.25],
        [-10.0, 0.3, 5.0, 1.6, 0.0],
        [5.0, -3.0, 4.0, -2.5, 2e-3],
        [2.0, 1.0, 3.0, 0.7, -3e-4],
        [-40.0, 0.1, 6.0, 3.1, 2.5],
        [12.0, 7.0, -1.5, -0.4, -0.8],
    ] {
        xs.push(DVector::from_column_slice(&x));
    }
    xs
}

/// Analytic Jacobians equal central finite differences. Tolerance 1e-6 relative to the
/// largest entry: the difference step 1e-6·max(1, |x|) leaves a truncation error of order
/// h² ≈ 1e-12 times third derivatives and a rounding error of order ε/h ≈ 1e-10 times the
/// function's scale (tens of metres), both far below 1e-6 of the Jacobian's largest entry.
#[test]
fn analytic_jacobians_match_finite_differences() {
    let s = shipped();
    let sys = CtrvSystem { dt: s.dt };
    for x in states() {
        let F = sys.transition_jacobian(1, &x).unwrap();
        let Fn = numerical_jacobian(|v| sys.transition(1, v), &x);
        assert!(max_rel(&F, &Fn) < 1e-6, "transition at {x}: {F} vs {Fn}");
        for sensor in [LIDAR, RADAR] {
            let H = sys.measurement_jacobian(1, sensor, &x).unwrap();
            let Hn = numerical_jacobian(|v| sys.measurement(1, sensor, v), &x);
            assert!(
                max_rel(&H, &Hn) < 1e-6,
                "sensor {sensor} at {x}: {H} vs {Hn}"
            );
        }
    }
}

/// The Taylor branch for small |ωT| joins the closed form without a jump: on both sides of
/// the switch (|ωT| = 1e-3) the step agrees with the closed form to 1e-10 m, the Taylor
/// remainder (v T (ωT)³/24 ≈ 2e-11 m here).
#[test]
fn small_turn_branch_is_continuous() {
    let sys = CtrvSystem { dt: 0.1 };
    let closed = |x: &[f64]| {
        let (v, yaw, w, t) = (x[2], x[3], x[4], 0.1);
        [
            x[0] + v / w * ((yaw + w * t).sin() - yaw.sin()),
            x[1] + v / w * (yaw.cos() - (yaw + w * t).cos()),
        ]
    };
    for w in [0.0099, 0.00999999, 0.01000001, 0.0101, -0.00999999] {
        let x = [3.0, -4.0, 5.0, 0.7, w];
        let got = sys.step(&x, 0.0, 0.0);
        let want = closed(&x);
        assert!((got[0] - want[0]).abs() < 1e-10 && (got[1] - want[1]).abs() < 1e-10);
    }
    // ω = 0: a straight line.
    let got = sys.step(&[1.0, 2.0, 5.0, 0.3, 0.0], 0.0, 0.0);
    assert!((got[0] - (1.0 + 0.5 * 0.3f64.cos())).abs() < 1e-15);
    assert!((got[1] - (2.0 + 0.5 * 0.3f64.sin())).abs() < 1e-15);
}

#[test]
fn angles_wrap_to_minus_pi_exclusive_pi_inclusive() {
    for (a, want) in [
        (0.0, 0.0),
        (PI, PI),
        (-PI, PI),
        (3.0 * PI, PI),
        (2.0 * PI + 0.1, 0.1),
        (-2.0 * PI - 0.1, -0.1),
        (7.0, 7.0 - 2.0 * PI),
    ] {
        assert!((wrap_angle(a) - want).abs() < 1e-12, "wrap({a})");
    }
    let sys = CtrvSystem { dt: 0.1 };
    let z = DVector::from_column_slice(&[10.0, 3.1, 0.0]);
    let z_hat = DVector::from_column_slice(&[10.0, -3.1, 0.0]);
    let d = sys.residual(RADAR, &z, &z_hat);
    assert!((d[1] - (6.2 - 2.0 * PI)).abs() < 1e-12);
    // Lidar components are not angles.
    let d = sys.residual(
        LIDAR,
        &DVector::from_column_slice(&[4.0, 0.0]),
        &DVector::from_column_slice(&[-4.0, 0.0]),
    );
    assert!((d[0] - 8.0).abs() < 1e-12);
}

/// The predicted bearing of sigma points straddling ±π is near π, not near 0 (the naive
/// weighted sum of 3.1 and −3.1 is 0).
#[test]
fn bearing_mean_is_circular_near_pi() {
    let sys = CtrvSystem { dt: 0.1 };
    let zs = vec![
        DVector::from_column_slice(&[10.0, 3.10, 1.0]),
        DVector::from_column_slice(&[10.0, -3.12, 1.0]),
        DVector::from_column_slice(&[10.0, 3.08, 1.0]),
    ];
    let wm = [0.5, 0.25, 0.25];
    let m = sys.measurement_mean(RADAR, &zs, &wm);
    // Offsets from 3.10: 0, +0.0432 (−3.12 + 2π − 3.10), −0.02.
    let want = wrap_angle(3.10 + 0.25 * (-3.12 + 2.0 * PI - 3.10) + 0.25 * (-0.02));
    assert!((m[1] - want).abs() < 1e-12, "{} vs {want}", m[1]);
    assert!(m[1].abs() > 3.0);
    // Far from ±π it is the weighted sum.
    let zs: Vec<DVector<f64>> = zs.iter().map(|z| z * 0.1).collect();
    let m = sys.measurement_mean(RADAR, &zs, &wm);
    let naive: f64 = zs.iter().zip(&wm).map(|(z, w)| z[1] * w).sum();
    assert!((m[1] - naive).abs() < 1e-12);
}

/// The fixed-size UKF computes what the generic `Ukf` with augmented noise computes, on a
/// whole run of the shipped scenario (which crosses bearing ±π twice), at the truth's noise
/// and at a mis-tuned one: estimates, covariances, error maps and NIS agree to 1e-9
/// relative (only summation order differs).
#[test]
fn fixed_size_ukf_matches_the_generic_ukf() {
    let s = shipped();
    let model = concrete(&s);
    let tv = model.truth_values();
    let mut crossed = false;
    for (scale, run) in [(1.0, 0), (7.0, 0), (1.0, 1), (0.3, 2)] {
        let theta: Vec<f64> = tv.iter().map(|v| v * scale).collect();
        let fast = model.ukf(&theta);
        let slow = model.reference_ukf(&theta);
        let mut rng = run_rng(11, run);
        let mut x = model.truth.initial_state(&mut rng);
        let (mut ef, mut es) = (fast.initial(), slow.initial());
        let mut meas = Vec::new();
        for k in 1..=s.steps {
            x = model.truth.propagate(k, &x, &mut rng);
            meas.clear();
            model.truth.measure(k, &x, &mut rng, &mut meas);
            fast.predict(k, &mut ef).unwrap();
            slow.predict(k, &mut es).unwrap();
            for m in &meas {
                let a = fast.update(k, &mut ef, m).unwrap();
                let b = slow.update(k, &mut es, m).unwrap();
                assert!((a.nis - b.nis).abs() <= 1e-9 * a.nis.max(1.0), "step {k}");
                if m.sensor == RADAR && m.z[1].abs() > 3.0 {
                    crossed = true;
                }
            }
            let xa = DMatrix::from_column_slice(5, 1, ef.x.as_slice());
            let xb = DMatrix::from_column_slice(5, 1, es.x.as_slice());
            assert!(max_rel(&xa, &xb) < 1e-9, "x at step {k}");
            assert!(max_rel(&ef.P, &es.P) < 1e-9, "P at step {k}");
            assert!(
                max_rel(
                    ef.error_map.as_ref().unwrap(),
                    es.error_map.as_ref().unwrap()
                ) < 1e-9,
                "map at step {k}"
            );
        }
    }
    assert!(crossed, "the runs should take the radar bearing near ±π");
}

/// Lidar (2 components) at odd steps, radar (3) at even steps while the target is within
/// the radar's range limits; measured bearings lie in (−π, π].
#[test]
fn sensors_alternate_and_radar_respects_its_range_limits() {
    let s = shipped();
    let model = build(&s);
    let truth = model.truth();
    let mut rng = run_rng(11, 0);
    let mut x = truth.initial_state(&mut rng);
    let mut out: Vec<Measurement> = Vec::new();
    let (mut positive, mut negative) = (false, false);
    for k in 1..=s.steps {
        x = truth.propagate(k, &x, &mut rng);
        out.clear();
        truth.measure(k, &x, &mut rng, &mut out);
        assert_eq!(out.len(), 1, "step {k}");
        let m = &out[0];
        if k % 2 == 1 {
            assert_eq!((m.sensor, m.z.len()), (LIDAR, 2));
        } else {
            assert_eq!((m.sensor, m.z.len()), (RADAR, 3));
            assert!(m.z[1] > -PI && m.z[1] <= PI);
            positive |= m.z[1] > 3.0;
            negative |= m.z[1] < -3.0;
        }
    }
    assert!(positive && negative, "bearings on both sides of ±π");

    // A radar that sees only beyond 1 km never reports here; the lidar still does.
    let mut t = s.table.clone();
    t["radar"]
        .as_table_mut()
        .unwrap()
        .insert("min_range".into(), toml::Value::Float(1000.0));
    t["radar"]
        .as_table_mut()
        .unwrap()
        .insert("max_range".into(), toml::Value::Float(2000.0));
    let far = (ENTRY.build)(&t, &ModelContext { dt: 0.1, steps: 10 }).unwrap();
    let mut rng = run_rng(11, 0);
    let mut x = far.truth().initial_state(&mut rng);
    for k in 1..=10 {
        x = far.truth().propagate(k, &x, &mut rng);
        out.clear();
        far.truth().measure(k, &x, &mut rng, &mut out);
        assert_eq!(out.len(), k % 2, "step {k}");
    }
}

/// The yaw error is wrapped: a truth one turn ahead of the estimate has zero error.
#[test]
fn yaw_error_is_wrapped() {
    let s = shipped();
    let model = build(&s);
    let f = model.filter(&model.truth_values());
    let t = DVector::from_column_slice(&[1.0, 2.0, 3.0, 0.1 + 2.0 * PI, 0.2]);
    let e = DVector::from_column_slice(&[1.0, 2.0, 3.0, 0.1, 0.2]);
    assert!(f.state_error(&t, &e).norm() < 1e-12);
    let t = DVector::from_column_slice(&[1.0, 2.0, 3.0, 3.1, 0.2]);
    let e = DVector::from_column_slice(&[1.0, 2.0, 3.0, -3.1, 0.2]);
    assert!((f.state_error(&t, &e)[3] - (6.2 - 2.0 * PI)).abs() < 1e-12);
}

/// Bad settings are refused with the field's name; bad parameter values make the filter
/// fail (a divergence), never panic.
#[test]
fn bad_input_is_an_error_naming_the_field() {
    let s = shipped();
    let ctx = ModelContext { dt: 0.1, steps: 10 };
    let edit = |path: &[&str], v: toml::Value| {
        let mut t = s.table.clone();
        let mut cur = &mut t;
        for p in &path[..path.len() - 1] {
            cur = cur[*p].as_table_mut().unwrap();
        }
        cur.insert(path[path.len() - 1].into(), v);
        (ENTRY.build)(&t, &ctx).unwrap_err()
    };
    let f = toml::Value::Float;
    assert_eq!(edit(&["truth", "q_accel"], f(-1.0)).field, "truth.q_accel");
    assert_eq!(
        edit(&["truth", "r_radar_bearing"], f(f64::NAN)).field,
        "truth.r_radar_bearing"
    );
    assert!(
        edit(&["truth", "q_acel"], f(1.0))
            .field
            .starts_with("truth")
    );
    assert_eq!(
        edit(&["substeps"], toml::Value::Integer(0)).field,
        "substeps"
    );
    assert_eq!(
        edit(&["radar", "min_range"], f(-1.0)).field,
        "radar.min_range"
    );
    assert_eq!(
        edit(&["radar", "max_range"], f(0.5)).field,
        "radar.max_range"
    );
    assert_eq!(edit(&["ukf", "alpha"], f(0.0)).field, "ukf.alpha");
    assert_eq!(edit(&["ukf", "kappa"], f(-6.0)).field, "ukf.kappa");
    let short = toml::Value::Array(vec![f(1.0); 4]);
    assert_eq!(edit(&["initial", "std"], short).field, "initial.std");
    assert_eq!(
        edit(&["initial", "std"], toml::Value::Array(vec![f(0.0); 5])).field,
        "initial.std[0]"
    );
    let err = (ENTRY.build)(&s.table, &ModelContext { dt: 0.0, steps: 10 }).unwrap_err();
    assert_eq!(err.field, "dt");

    let model = build(&s);
    let settings = McConfig::new(4, 20)
        .unwrap()
        .with_seed(1)
        .with_lags(1)
        .unwrap();
    for theta in [
        vec![-1.0, 0.1, 0.0225, 0.09, 0.0009, 0.09],
        vec![0.5, 0.1, f64::NAN, 0.09, 0.0009, 0.09],
        vec![0.5],
    ] {
        let acc = run_generic(model.truth(), &model.filter(&theta), &settings);
        assert_eq!(acc.diverged_runs(), 4, "{theta:?}");
    }
}

/// With the filter's noise equal to the truth's, the shipped check is consistent; with
/// both Q parameters at 1/100 it is overconfident (ANEES above its interval). The seeds are
/// fixed; a consistent filter fails this gate with probability α = 0.05 for a random seed,
/// and the shipped seed passes with ANEES 5.08 in [4.87, 5.13]. At Q × 0.01 ANEES is about
/// 45 times its target, far outside any interval.
#[test]
fn shipped_check_is_consistent_at_truth_and_overconfident_with_small_q() {
    let s = shipped();
    let model = build(&s);
    let settings = McConfig::new(s.runs, s.steps)
        .unwrap()
        .with_seed(s.seed)
        .with_lags(3)
        .unwrap();
    let (sn, mn) = (model.state_names(), model.measurement_names());
    let tv = model.truth_values();
    let acc = run_generic(model.truth(), &model.filter(&tv), &settings);
    let r = ConsistencyReport::from_accumulator(
        &acc,
        &autotune::internals::stats::GateSpec::full(s.alpha, true),
        &sn,
        &mn,
    );
    assert_eq!(r.verdict, Verdict::Consistent);

    let mut small = tv.clone();
    small[0] *= 0.01;
    small[1] *= 0.01;
    let acc = run_generic(model.truth(), &model.filter(&small), &settings);
    let r = ConsistencyReport::from_accumulator(
        &acc,
        &autotune::internals::stats::GateSpec::full(s.alpha, true),
        &sn,
        &mn,
    );
    assert_eq!(r.verdict, Verdict::Overconfident);
    let nees = r.nees.unwrap();
    assert!(nees.time_average > nees.interval.upper);
}

/// How many of 200 single recordings (seeds 1..=200, one run of 500 steps: lidar and radar
/// taking turns, 250 readings each) the full gate fails, for the UKF at `theta` with its
/// error map hidden (each recording judged as a records file of it would be: ANEES by
/// batch means, the innovations as for many runs, the state components untested).
fn single_recording_failures(theta: &[f64]) -> usize {
    let s = shipped();
    let model = build(&s);
    let (sn, mn) = (model.state_names(), model.measurement_names());
    // The catalog UKF with its error map hidden: what a records file of its runs gives.
    let filter = NoMap(model.filter(theta));
    (1..=200u64)
        .filter(|&seed| {
            let mc = McConfig::new(1, 500).unwrap().with_seed(seed);
            let acc = run_generic(model.truth(), &filter, &mc);
            let r = ConsistencyReport::from_accumulator(
                &acc,
                &autotune::internals::stats::GateSpec::full(s.alpha, true),
                &sn,
                &mn,
            );
            assert!(r.nees.as_ref().unwrap().batch_spread_batches.is_some());
            r.verdict != Verdict::Consistent
        })
        .count()
}

/// Issue 39: one recording with truth. At the truth's noise the gate (α = 0.05) fails a
/// single recording as often as the binomial 99% band of 200 draws at 5% allows (2 to 18
/// of 200; measured 5). Power, measured and stated in docs/src/records.md: 200 of 200 at
/// the process noise ÷ 4 (held at ≥ 196), 182 of 200 at × 4 (held at ≥ 170, three binomial
/// standard deviations below).
#[test]
fn one_ctrv_recording_is_judged_at_the_false_alarm_rate_and_with_power() {
    let s = shipped();
    let tv = build(&s).truth_values();
    let at_truth = single_recording_failures(&tv);
    let scaled = |f: f64| {
        let mut t = tv.clone();
        t[0] *= f;
        t[1] *= f;
        single_recording_failures(&t)
    };
    let (small, large) = (scaled(0.25), scaled(4.0));
    eprintln!(
        "single ctrv recordings failed: {at_truth} of 200 at the truth, {small} at Q ÷ 4, {large} at Q × 4"
    );
    assert!(
        (2..=18).contains(&at_truth),
        "{at_truth} of 200 false alarms"
    );
    assert!(small >= 196, "{small} of 200 caught at Q ÷ 4");
    assert!(large >= 170, "{large} of 200 caught at Q × 4");
}
