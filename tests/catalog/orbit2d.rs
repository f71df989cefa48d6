//! The `orbit2d` catalog model: analytic Jacobians, the consistency check on the shipped
//! problem at the truth's noise and with Q far too small, the station schedule, angle
//! wrapping, the truth's noise structure against the filter's Q, and refused settings.
//!
//! Run with `cargo test --release --test catalog -- orbit2d::`.

#![allow(non_snake_case)] // paper notation (Q, C) for the filter matrices

use autotune::SimRng;
use autotune::internals::catalog::orbit2d::{self, EARTH_RADIUS, MU, Orbit2d};
use autotune::internals::catalog::{CatalogModel, ModelContext, find};
use autotune::internals::filter::{Ekf, Filter, FilterError, SystemModel, numerical_jacobian};
use autotune::internals::measurement::Measurement;
use autotune::internals::montecarlo::{McConfig, run_generic};
use autotune::internals::stats::{ConsistencyReport, Verdict};
use nalgebra::{DMatrix, DVector, Matrix2, Vector2, Vector4};
use rand::{RngExt, SeedableRng};
use rand_distr::StandardNormal;

/// The shipped problem file: its `[model]` table (without `name`), dt and Monte Carlo
/// settings.
struct Shipped {
    table: toml::Table,
    ctx: ModelContext,
    settings: McConfig,
    alpha: f64,
}

fn shipped() -> Shipped {
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/problems/orbit2d.toml");
    let text = std::fs::read_to_string(path).expect("shipped problem");
    let file: toml::Table = toml::from_str(&text).expect("valid TOML");
    let dt = file["dt"].as_float().expect("dt");
    let mc = file["montecarlo"].as_table().expect("[montecarlo]");
    let int = |k: &str| mc[k].as_integer().expect("integer");
    let mut table = file["model"].as_table().expect("[model]").clone();
    assert_eq!(
        table
            .remove("name")
            .and_then(|v| v.as_str().map(String::from))
            .as_deref(),
        Some("orbit2d")
    );
    let steps = int("steps") as usize;
    Shipped {
        table,
        ctx: ModelContext { dt, steps },
        settings: McConfig::new(int("runs") as usize, steps)
            .unwrap()
            .with_seed(int("seed") as u64)
            .with_lags(3)
            .unwrap(),
        alpha: mc["alpha"].as_float().expect("alpha"),
    }
}

fn model(s: &Shipped) -> Orbit2d {
    Orbit2d::from_table(&s.table, &s.ctx).expect("shipped [model] is valid")
}

fn check(m: &Orbit2d, theta: &[f64], s: &Shipped) -> ConsistencyReport {
    let acc = run_generic(m.truth(), &m.filter(theta), &s.settings);
    ConsistencyReport::from_accumulator(
        &acc,
        &autotune::internals::stats::GateSpec::full(s.alpha, true),
        &m.state_names(),
        &m.measurement_names(),
    )
}

/// Compare an analytic Jacobian with `numerical_jacobian(g, x)` row by row:
/// `|A_ij − N_ij| ≤ rtol · max_j |N_ij| + 8 ε |g_i(x)| / h_j`.
///
/// Row scaling, because rows mix entries of very different sizes (∂v/∂r ~ G dt ~ 1e-5 next
/// to ∂v/∂v ~ 1). The second term is the rounding floor of the central difference itself
/// (step `h_j = 1e-6·max(1, |x_j|)`, as `numerical_jacobian` takes it): a coordinate that
/// passes near 0 (y = 0 on the x axis) gets a 1e-6 km step, and differences of values of
/// ~7000 km over that step carry ~1e-6 relative rounding error that says nothing about the
/// analytic derivative.
fn assert_jacobian(
    analytic: &DMatrix<f64>,
    g: impl Fn(&DVector<f64>) -> DVector<f64>,
    x: &DVector<f64>,
    rtol: f64,
    what: &str,
) {
    let numeric = numerical_jacobian(&g, x);
    let gx = g(x);
    assert_eq!(analytic.shape(), numeric.shape(), "{what}: shape");
    for i in 0..numeric.nrows() {
        let scale = numeric.row(i).iter().fold(0.0_f64, |a, v| a.max(v.abs()));
        for j in 0..numeric.ncols() {
            let h = 1e-6 * x[j].abs().max(1.0);
            let floor = 8.0 * f64::EPSILON * gx[i].abs() / h;
            let d = (analytic[(i, j)] - numeric[(i, j)]).abs();
            assert!(
                d <= rtol * scale + floor,
                "{what}: ({i},{j}) analytic {:e} numeric {:e} (row scale {scale:e}, floor {floor:e})",
                analytic[(i, j)],
                numeric[(i, j)]
            );
        }
    }
}

/// Representative states: circular orbits at several phases, an eccentric one, and
/// random perturbations of the nominal orbit (seeded).
fn states() -> Vec<DVector<f64>> {
    let mut out = Vec::new();
    for (r, phase, vscale) in [
        (6678.0, 0.0, 1.0),
        (6678.0, 1.3, 1.0),
        (6678.0, -2.5, 1.0),
        (7000.0, 0.7, 1.08),
        (6600.0, 3.0, 0.97),
    ] {
        let v = (MU / r).sqrt() * vscale;
        let (s, c) = f64::sin_cos(phase);
        out.push(DVector::from_column_slice(&[r * c, r * s, -v * s, v * c]));
    }
    let mut rng = SimRng::seed_from_u64(11);
    for _ in 0..5 {
        let mut x = out[0].clone();
        for i in 0..4 {
            let sd = if i < 2 { 50.0 } else { 0.05 };
            x[i] += sd * rng.sample::<f64, _>(StandardNormal);
        }
        out.push(x);
    }
    out
}

#[test]
fn transition_jacobian_matches_finite_differences() {
    let s = shipped();
    let m = model(&s);
    for x in states() {
        let a = m.system.transition_jacobian(1, &x).expect("analytic");
        // Φ is the exact derivative of the RK4 map, so only difference error remains.
        assert_jacobian(&a, |v| m.system.transition(1, v), &x, 1e-6, "transition");
    }
}

#[test]
fn measurement_jacobians_match_finite_differences_for_every_station() {
    let s = shipped();
    let m = model(&s);
    let dims = m.system.sensor_dims();
    assert_eq!(dims, vec![3; 12]);
    for x in states() {
        for k in [1, 137, 455] {
            for st in 0..dims.len() {
                let a = m.system.measurement_jacobian(k, st, &x).expect("analytic");
                // Valid wherever the range is non-zero, visible or not.
                let what = format!("station {st} at step {k}");
                assert_jacobian(&a, |v| m.system.measurement(k, st, v), &x, 1e-6, &what);
            }
        }
    }
}

#[test]
fn shipped_problem_is_consistent_at_the_truth_noise() {
    // One fixed seed: a correct filter passes the NEES+NIS gate with probability ~1 − α
    // (α = 0.05), and this seed is one where it does; a wrong Q or R of even a few percent
    // moves ANIS out of its ±0.9% interval (see the next test for 100x).
    let s = shipped();
    let m = model(&s);
    let rep = check(&m, &m.truth_values(), &s);
    let nees = rep.nees.as_ref().expect("NEES");
    assert_eq!(rep.diverged_runs, 0);
    assert!(
        rep.verdict == Verdict::Consistent,
        "verdict {:?}: ANEES {} in {:?}, ANIS {} in {:?}",
        rep.verdict,
        nees.time_average,
        nees.interval,
        rep.nis.time_average,
        rep.nis.interval
    );
    // The schedule gives measurements at a majority of steps but not all.
    assert!(rep.nis.steps_with_data > 300 && rep.nis.steps_with_data < 550);
}

#[test]
fn process_noise_scaled_by_0_01_is_overconfident() {
    let s = shipped();
    let m = model(&s);
    let mut theta = m.truth_values();
    theta[0] *= 0.01;
    theta[1] *= 0.01;
    let rep = check(&m, &theta, &s);
    let nees = rep.nees.as_ref().expect("NEES");
    assert_eq!(rep.verdict, Verdict::Overconfident);
    // Measured ANEES ≈ 300 against an upper bound ≈ 4.1: a margin no seed can bridge.
    assert!(nees.time_average > 10.0 * nees.interval.upper, "{nees:?}");
    assert!(rep.nis.time_average > rep.nis.interval.upper);
}

/// Elevation of the satellite above station `i` at step k, from the geometry directly.
fn elevation(m: &Orbit2d, k: usize, i: usize, x: &DVector<f64>) -> f64 {
    let t = k as f64 * m.system.dt;
    let lon = m.system.stations.phase
        + 2.0 * std::f64::consts::PI * i as f64 / m.system.stations.count as f64
        + orbit2d::EARTH_RATE * t;
    let up = Vector2::new(lon.cos(), lon.sin());
    let rho = Vector2::new(x[0], x[1]) - up * EARTH_RADIUS;
    (rho.dot(&up) / rho.norm()).asin()
}

#[test]
fn stations_report_exactly_when_above_the_mask() {
    let s = shipped();
    let m = model(&s);
    let truth = m.truth();
    let mask = 10f64.to_radians();
    let mut rng = SimRng::seed_from_u64(5);
    let mut x = truth.initial_state(&mut rng);
    let mut out = Vec::new();
    let mut counts = Vec::new();
    for k in 1..=s.ctx.steps {
        x = truth.propagate(k, &x, &mut rng);
        out.clear();
        truth.measure(k, &x, &mut rng, &mut out);
        let reporting: Vec<usize> = out.iter().map(|m| m.sensor).collect();
        for meas in &out {
            assert_eq!(meas.z.len(), 3);
            // Range is within 3σ (30 m) of the geometric range; angle in (mask, π − mask).
            assert!(meas.z[2] > mask - 0.01 && meas.z[2] < std::f64::consts::PI - mask + 0.01);
        }
        for i in 0..12 {
            let el = elevation(&m, k, i, &x);
            assert_eq!(
                reporting.contains(&i),
                el >= mask,
                "station {i} at step {k}: elevation {:.3}°",
                el.to_degrees()
            );
        }
        counts.push(out.len());
    }
    // Passes and gaps: steps with no station, and changes of the measurement dimension.
    let empty = counts.iter().filter(|&&c| c == 0).count();
    let changes = counts.windows(2).filter(|w| w[0] != w[1]).count();
    assert!(
        empty > 100 && empty < 300,
        "{empty} steps without measurement"
    );
    assert!(changes >= 20, "{changes} changes of the measurement count");
}

#[test]
fn angle_residual_wraps() {
    let s = shipped();
    let m = model(&s);
    let z = DVector::from_column_slice(&[1000.0, 1.0, 3.1]);
    let z_hat = DVector::from_column_slice(&[1000.0, 1.0, -3.1]);
    let d = m.system.residual(0, &z, &z_hat);
    assert!((d[2] - (6.2 - 2.0 * std::f64::consts::PI)).abs() < 1e-12);

    // The filter's innovation is the same whether the angle arrives as θ or θ + 2π.
    let f = m.filter(&m.truth_values());
    let mut rng = SimRng::seed_from_u64(3);
    let truth = m.truth();
    let mut x = truth.initial_state(&mut rng);
    let mut est = f.initial();
    let mut out = Vec::new();
    let mut k = 0;
    while out.is_empty() {
        k += 1;
        x = truth.propagate(k, &x, &mut rng);
        truth.measure(k, &x, &mut rng, &mut out);
        f.predict(k, &mut est).expect("predict");
    }
    let meas = out[0].clone();
    let mut shifted = meas.clone();
    shifted.z[2] += 2.0 * std::f64::consts::PI;
    let a = f.update(k, &mut est.clone(), &meas).expect("update");
    let b = f.update(k, &mut est, &shifted).expect("update");
    assert!((a.nis - b.nis).abs() < 1e-9 * a.nis.max(1.0));
    assert!((a.nu[2] - b.nu[2]).abs() < 1e-9);
}

#[test]
fn fixed_size_ekf_agrees_with_the_generic_ekf() {
    // With q_radial = q_along the radial/along-track Q is rotation invariant, so the
    // library's constant-Q EKF over the same SystemModel must give the same estimates.
    let s = shipped();
    let m = model(&s);
    let q = 5e-12;
    let theta = [q, q, 1e-4, 1e-12, 1e-6];
    let ours = m.ekf(&theta);
    let dt = s.ctx.dt;
    let mut Q = DMatrix::zeros(4, 4);
    for i in 0..2 {
        Q[(i, i)] = q * dt.powi(3) / 3.0;
        Q[(i, i + 2)] = q * dt.powi(2) / 2.0;
        Q[(i + 2, i)] = q * dt.powi(2) / 2.0;
        Q[(i + 2, i + 2)] = q * dt;
    }
    let generic = Ekf {
        model: m.system.clone(),
        Q,
        R: vec![DMatrix::from_diagonal(&DVector::from_column_slice(&[1e-4, 1e-12, 1e-6])); 12],
        x0: DVector::from_column_slice(ours.x0.as_slice()),
        P0: DMatrix::from_column_slice(4, 4, ours.P0.as_slice()),
    };
    let truth = m.truth();
    let mut rng = SimRng::seed_from_u64(9);
    let mut x = truth.initial_state(&mut rng);
    let (mut a, mut b) = (ours.initial(), generic.initial());
    let mut out: Vec<Measurement> = Vec::new();
    let mut updates = 0;
    for k in 1..=200 {
        x = truth.propagate(k, &x, &mut rng);
        out.clear();
        truth.measure(k, &x, &mut rng, &mut out);
        ours.predict(k, &mut a).expect("predict");
        generic.predict(k, &mut b).expect("predict");
        for meas in &out {
            let ia = ours.update(k, &mut a, meas).expect("update");
            let ib = generic.update(k, &mut b, meas).expect("update");
            assert!((ia.nis - ib.nis).abs() < 1e-6 * ib.nis.max(1.0), "step {k}");
            updates += 1;
        }
        // Relative to each state's own scale (position ~7000 km, velocity ~8 km/s) and to
        // P's diagonal, 1e-9: both filters do the same arithmetic in a different order.
        for i in 0..4 {
            assert!(
                (a.x[i] - b.x[i]).abs() < 1e-9 * b.x[i].abs().max(1.0),
                "x[{i}] step {k}"
            );
            for j in 0..4 {
                let scale = (b.P[(i, i)] * b.P[(j, j)]).sqrt();
                assert!(
                    (a.P[(i, j)] - b.P[(i, j)]).abs() < 1e-7 * scale,
                    "P[{i},{j}] step {k}"
                );
            }
        }
    }
    assert!(updates > 50);
}

#[test]
fn truth_noise_has_the_filter_q_structure() {
    // From a fixed state, the spread of one truth step around the noise-free step must be
    // the filter's Q (radial/along-track, continuous white noise over dt). With n = 20000
    // draws a sample variance has relative sd √(2/n) = 1%; the piecewise-constant noise
    // has 0.25% less position variance than continuous noise (Σ(j+½)² = 332.5 vs 1000/3)
    // and the gravity gradient changes it by ~(n dt)² ~ 1e-4; 5% is a 4-5σ band.
    let s = shipped();
    let m = model(&s);
    let truth = m.truth();
    let x0 = DVector::from_column_slice(&[4000.0, 5000.0, -6.0, 4.8]);
    let mean = m.system.transition(1, &x0);
    let f = m.ekf(&m.truth_values());
    let x0f = Vector4::from_column_slice(x0.as_slice());
    let x1f = Vector4::from_column_slice(mean.as_slice());
    let Q = f.process_noise(&x0f, &x1f);
    // Project onto the radial/along-track frame at mid-step for positions and velocities.
    let mid = (x0f + x1f) * 0.5;
    let ur = Vector2::new(mid[0], mid[1]).normalize();
    let ut = Vector2::new(-ur[1], ur[0]);
    let C = Matrix2::from_rows(&[ur.transpose(), ut.transpose()]);
    let n = 20_000;
    let mut rng = SimRng::seed_from_u64(21);
    let mut sum = nalgebra::Matrix4::<f64>::zeros();
    for _ in 0..n {
        let d = truth.propagate(1, &x0, &mut rng) - &mean;
        let d = Vector4::from_column_slice(d.as_slice());
        sum += d * d.transpose();
    }
    let sample = sum / n as f64;
    let rotate = |M: &nalgebra::Matrix4<f64>| {
        let mut out = nalgebra::Matrix4::zeros();
        for (bi, bj) in [(0, 0), (0, 2), (2, 0), (2, 2)] {
            let blk = M.fixed_view::<2, 2>(bi, bj).into_owned();
            out.fixed_view_mut::<2, 2>(bi, bj)
                .copy_from(&(C * blk * C.transpose()));
        }
        out
    };
    let (sr, qr) = (rotate(&sample), rotate(&Q));
    // Diagonal: position and velocity, radial and along-track; also the p-v covariances.
    for (i, j) in [(0, 0), (1, 1), (2, 2), (3, 3), (0, 2), (1, 3)] {
        let rel = sr[(i, j)] / qr[(i, j)] - 1.0;
        assert!(
            rel.abs() < 0.05,
            "({i},{j}): sample {:e} vs Q {:e}",
            sr[(i, j)],
            qr[(i, j)]
        );
    }
    // Radial and along-track noise are independent: cross terms near zero relative to
    // √(radial · along).
    let corr = sr[(2, 3)] / (sr[(2, 2)] * sr[(3, 3)]).sqrt();
    assert!(corr.abs() < 0.05, "radial/along correlation {corr}");
    // The shipped truth has 5x more along-track than radial noise.
    assert!((qr[(3, 3)] / qr[(2, 2)] - 5.0).abs() < 1e-9);
}

#[test]
fn truth_step_is_rounded_down_to_divide_dt() {
    let mut s = shipped();
    let truth = s.table["truth"].as_table_mut().expect("[model.truth]");
    truth.insert("step".into(), toml::Value::Float(3.0));
    let m = model(&s);
    assert_eq!(m.truth.substeps, 4);
    assert!((m.truth.h - 2.5).abs() < 1e-12);
}

#[test]
fn bad_settings_are_refused_by_field() {
    let s = shipped();
    let entry = find("orbit2d").expect("in the catalog");
    let cases: &[(&str, &str, toml::Value, &str)] = &[
        ("truth", "step", toml::Value::Float(-1.0), "truth.step"),
        (
            "truth",
            "q_along",
            toml::Value::Float(f64::NAN),
            "truth.q_along",
        ),
        (
            "stations",
            "count",
            toml::Value::Integer(0),
            "stations.count",
        ),
        (
            "stations",
            "mask_deg",
            toml::Value::Float(95.0),
            "stations.mask_deg",
        ),
        (
            "stations",
            "range_std",
            toml::Value::Float(0.0),
            "stations.range_std",
        ),
        ("stations", "bogus", toml::Value::Float(1.0), "stations"),
        (
            "stations",
            "count",
            toml::Value::String("ten".into()),
            "stations.count",
        ),
        (
            "initial",
            "vel_std",
            toml::Value::Float(-1e-3),
            "initial.vel_std",
        ),
        (
            "filter",
            "substeps",
            toml::Value::Integer(0),
            "filter.substeps",
        ),
    ];
    for (sec, key, val, field) in cases {
        let mut t = s.table.clone();
        t[*sec]
            .as_table_mut()
            .expect("section")
            .insert((*key).into(), val.clone());
        let err = (entry.build)(&t, &s.ctx).expect_err("must be refused");
        assert!(err.field.starts_with(field), "{sec}.{key}: got {err}");
    }
    let mut t = s.table.clone();
    t.insert("radius".into(), toml::Value::Float(6000.0));
    assert_eq!(
        (entry.build)(&t, &s.ctx)
            .expect_err("inside the Earth")
            .field,
        "radius"
    );
    let bad_dt = ModelContext { dt: 0.0, steps: 10 };
    assert_eq!(
        (entry.build)(&s.table, &bad_dt).expect_err("dt").field,
        "dt"
    );
}

#[test]
fn bad_inputs_do_not_panic() {
    let s = shipped();
    let m = model(&s);
    // Too few parameters: NaN noise, the filter reports a failure instead of panicking.
    let f = m.filter(&[1e-12]);
    let mut est = f.initial();
    let _ = f.predict(1, &mut est);
    // Unknown station and wrong dimension.
    let f = m.filter(&m.truth_values());
    let mut est = f.initial();
    let bad = Measurement {
        sensor: 12,
        z: DVector::zeros(3),
    };
    assert!(matches!(
        f.update(1, &mut est, &bad),
        Err(FilterError::BadMeasurement { sensor: 12, .. })
    ));
    let short = Measurement {
        sensor: 0,
        z: DVector::zeros(2),
    };
    assert!(matches!(
        f.update(1, &mut est, &short),
        Err(FilterError::BadMeasurement {
            got: 2,
            expected: 3,
            ..
        })
    ));
    // A state at the Earth's centre gives non-finite numbers, not a panic.
    let mut est = f.initial();
    est.x.fill(0.0);
    assert!(f.predict(1, &mut est).is_err());
}
