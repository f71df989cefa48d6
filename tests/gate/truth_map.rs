//! Issue 11, item 13: a truth with more states than the filter.
//!
//! The classic truth-model test gives the truth what the filter omits (here an
//! acceleration) and takes the NEES on the filter's states: `filter.map` (n_f × n_t) with
//! `e = map · x_true − x̂`, and the filter's own F, H, x0 and P0 of its own dimension. Before,
//! such a filter had to be padded with a decoupled dummy state, which changed the NEES it was
//! judged by.

#![allow(non_snake_case)]

use autotune::Structure;
use std::path::{Path, PathBuf};

use assert_cmd::Command;
use autotune::internals::check::accumulate;
use autotune::internals::experiment::Experiment;
use autotune::internals::montecarlo::{Engine, models_match};
use autotune::internals::problem::Problem;
use autotune::internals::tune::{Scoring, Silent, TuneSettings, tune};
use nalgebra::{DMatrix, DVector};

fn data(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data")
        .join(name)
}

/// Expected per-step values from the joint recursion of truth and filter.
struct Exact {
    nees: Vec<f64>,
    nis: Vec<f64>,
    /// `comp[k][j] = E[e_j²] / P_jj` at step k.
    comp: Vec<Vec<f64>>,
}

/// E[NEES_k], E[NIS_k] and E[e_j²]/P_jj of a Kalman filter with its own (F, H) on a truth
/// with other states, from the mean and covariance of the joint state ξ = [x_true; x̂]:
/// ξ⁻ = blkdiag(F_t, F_f) ξ + [w; 0], ν = [H_t, −H_f] ξ⁻ + v, ξ = ξ⁻ + [0; K] ν, and
/// e = [M, −I] ξ. Written here independently of the library's engines (plain textbook KF
/// covariance, explicit inverses), so that it can check them.
fn joint_expectation(p: &Problem, theta: &[f64]) -> Exact {
    let lin = p.linear().unwrap();
    let (t, kf) = (&lin.truth, lin.filter_at(theta));
    let M = lin.filter.map.clone().expect("a mapped filter");
    let (nt, nf, m) = (t.F.nrows(), kf.F.nrows(), kf.H.nrows());
    let n = nt + nf;
    let mut Phi = DMatrix::zeros(n, n);
    Phi.view_mut((0, 0), (nt, nt)).copy_from(&t.F);
    Phi.view_mut((nt, nt), (nf, nf)).copy_from(&kf.F);
    let mut W = DMatrix::zeros(n, n);
    W.view_mut((0, 0), (nt, nt)).copy_from(&t.Q);
    let mut Hx = DMatrix::zeros(m, n);
    Hx.view_mut((0, 0), (m, nt)).copy_from(&t.H);
    Hx.view_mut((0, nt), (m, nf)).copy_from(&(-&kf.H));
    let mut G = DMatrix::zeros(nf, n);
    G.view_mut((0, 0), (nf, nt)).copy_from(&M);
    G.view_mut((0, nt), (nf, nf))
        .copy_from(&(-DMatrix::<f64>::identity(nf, nf)));

    let mut mu = DVector::zeros(n);
    mu.rows_mut(0, nt).copy_from(&t.x0);
    mu.rows_mut(nt, nf).copy_from(&kf.x0);
    let mut C = DMatrix::zeros(n, n);
    C.view_mut((0, 0), (nt, nt)).copy_from(&t.P0);
    let mut P = kf.P0.clone();
    let mut out = Exact {
        nees: vec![],
        nis: vec![],
        comp: vec![],
    };
    for _ in 0..p.mc().steps() {
        let Pp = &kf.F * &P * kf.F.transpose() + &kf.Q;
        let S = &kf.H * &Pp * kf.H.transpose() + &kf.R;
        let Si = S.clone().try_inverse().unwrap();
        let K = &Pp * kf.H.transpose() * &Si;
        P = (DMatrix::identity(nf, nf) - &K * &kf.H) * &Pp;
        P = (&P + P.transpose()) * 0.5;

        let mu_p = &Phi * &mu;
        let C_p = &Phi * &C * Phi.transpose() + &W;
        let nu_m2 = &Hx * (&C_p + &mu_p * mu_p.transpose()) * Hx.transpose() + &t.R;
        out.nis.push((&Si * nu_m2).trace());

        let mut B = DMatrix::zeros(n, m);
        B.view_mut((nt, 0), (nf, m)).copy_from(&K);
        let A = DMatrix::identity(n, n) + &B * &Hx;
        mu = &A * &mu_p;
        C = &A * &C_p * A.transpose() + &B * &t.R * B.transpose();
        let e_m2 = &G * (&C + &mu * mu.transpose()) * G.transpose();
        let Pi = P.clone().try_inverse().unwrap();
        out.nees.push((&Pi * &e_m2).trace());
        out.comp
            .push((0..nf).map(|j| e_m2[(j, j)] / P[(j, j)]).collect());
    }
    out
}

#[test]
fn a_truth_with_more_states_than_the_filter_runs_on_both_engines_alike() {
    let p = Problem::load(&data("singer_vs_cv.toml")).unwrap();
    let lin = p.linear().unwrap();
    assert_eq!(lin.truth.F.nrows(), 3);
    assert_eq!(p.state_names().len(), 2);
    assert_eq!(lin.filter.map.as_ref().unwrap().shape(), (2, 3));
    // The filter's x0 and P0 default to the truth's through the map.
    assert_eq!(lin.filter.x0.as_slice(), &[0.0, 10.0]);
    assert_eq!(
        lin.filter.P0,
        DMatrix::from_diagonal(&DVector::from_vec(vec![4.0, 1.0]))
    );

    // Same random draws, reordered arithmetic: agreement to rounding, as for a filter with
    // the truth's states (tests/gate/consistency.rs).
    let theta = [2.0, 1.0];
    let mc = p.mc().with_runs(150).unwrap().with_steps(80).unwrap();
    let a = accumulate(&p, &theta, &mc, Engine::Linear).unwrap();
    let b = accumulate(&p, &theta, &mc, Engine::Generic).unwrap();
    let close = |x: &[f64], y: &[f64], what: &str| {
        assert_eq!(x.len(), y.len());
        for (i, (u, v)) in x.iter().zip(y).enumerate() {
            assert!(
                (u - v).abs() <= 1e-9 * u.abs().max(v.abs()).max(1e-300),
                "{what}[{i}]: {u} vs {v}"
            );
        }
    };
    close(a.nees_sum(), b.nees_sum(), "nees_sum");
    close(a.nis_sum(), b.nis_sum(), "nis_sum");
    close(
        a.state_comp_total(),
        b.state_comp_total(),
        "state_comp_total",
    );
    close(a.white_ab(), b.white_ab(), "white_ab");
    close(
        &[a.nees_null_variance()],
        &[b.nees_null_variance()],
        "nees_null_variance",
    );
    // The NEES is taken on the filter's two states.
    assert!(a.nees_dof().iter().all(|&d| d == 2.0 * 150.0));
    assert_eq!(a.state_comp_total().len(), 2);
    assert_eq!((a.diverged_runs(), b.diverged_runs()), (0, 0));
}

#[test]
fn mapped_nees_nis_and_components_match_the_joint_closed_form() {
    // 4000 runs of the fast path against the joint recursion of truth and filter, at every
    // step. Each per-step average is a mean of 4000 independent runs, so it is normal to
    // within the CLT; the band is 4.5 of its standard errors (two-sided 7e-6 per step, so
    // about 3e-3 over the 2 × 200 steps with fixed seeds) — a wrong map, a wrong dimension
    // or a wrong initial mean is off by far more.
    for (file, theta) in [
        ("singer_vs_cv.toml", [2.0, 1.0]),
        ("ca_vs_cv.toml", [0.5, 1.5]),
    ] {
        let p = Problem::load(&data(file)).unwrap();
        let exact = joint_expectation(&p, &theta);
        let mc = p.mc().with_runs(4000).unwrap();
        let acc = accumulate(&p, &theta, &mc, Engine::Linear).unwrap();
        let runs = mc.runs() as f64;
        for (what, sum, sq, want) in [
            ("NEES", &acc.nees_sum(), &acc.nees_sq(), &exact.nees),
            ("NIS", &acc.nis_sum(), &acc.nis_sq(), &exact.nis),
        ] {
            for k in 0..mc.steps() {
                let mean = sum[k] / runs;
                let se = ((sq[k] / runs - mean * mean) / runs).sqrt();
                assert!(
                    (mean - want[k]).abs() <= 4.5 * se,
                    "{file} {what} step {}: {mean} vs {} (se {se})",
                    k + 1,
                    want[k]
                );
            }
        }
        // Per-component time averages, with the spread of the per-run averages.
        for j in 0..2 {
            let mean = acc.state_comp_total()[j] / acc.state_comp_samples()[j];
            let want = exact.comp.iter().map(|c| c[j]).sum::<f64>() / mc.steps() as f64;
            let m1 = acc.state_comp_run_sum()[j] / runs;
            let se = ((acc.state_comp_run_sq()[j] / runs - m1 * m1) / runs).sqrt();
            assert!(
                (mean - want).abs() <= 4.5 * se,
                "{file} component {j}: {mean} vs {want} (se {se})"
            );
        }
    }
}

/// A mapped filter has exact sums too (issue 38: the joint moments of truth and estimate,
/// checked against Monte Carlo in tests/gate/expected.rs), so `auto` scores it exactly.
#[test]
fn the_exact_path_takes_a_mapped_filter() {
    let p = Problem::load(&data("ca_vs_cv.toml")).unwrap();
    let theta = p.params().values();
    assert!(p.expected(&theta, p.mc()).is_some());
    let fixed = vec![false; theta.len()];
    let s = TuneSettings::default().with_certify(false);
    let r = tune(&p, &theta, &fixed, p.mc(), &s, &Silent).unwrap();
    assert_eq!(r.scoring, Scoring::Exact);
    let _ = Command::cargo_bin("autotune");
}

#[test]
fn a_problem_without_a_map_is_unchanged_by_an_identity_map() {
    // map = I is the same problem: bit-identical sums.
    let text = include_str!("../../problems/cv1d.toml");
    let mapped = text.replacen(
        "[filter]\n",
        "[filter]\nmap = [[1.0, 0.0], [0.0, 1.0]]\n",
        1,
    );
    assert_ne!(mapped, text);
    let a = Problem::from_toml(text, Path::new("cv1d.toml")).unwrap();
    let b = Problem::from_toml(&mapped, Path::new("cv1d_mapped.toml")).unwrap();
    assert!(b.linear().unwrap().filter.map.is_none());
    let theta = a.params().values();
    for engine in [Engine::Linear, Engine::Generic] {
        assert_eq!(
            accumulate(&a, &theta, a.mc(), engine).unwrap(),
            accumulate(&b, &theta, b.mc(), engine).unwrap()
        );
    }
}

/// The library's exact sums on a mapped filter equal the textbook joint recursion above
/// (written apart from the library, with explicit inverses) at every step, to rounding.
/// Both take the error as the difference of the truth's and the estimate's moments, which
/// grow with the truth's velocity: the textbook differs from the library by up to 4.8e-8
/// relative on these two problems (3.2e-8 from the block-structured sparse products, 4.8e-8
/// from the dense joint matrix they replaced), so the band is 1e-7.
#[test]
fn the_exact_path_equals_the_textbook_joint_recursion() {
    for name in ["singer_vs_cv.toml", "ca_vs_cv.toml"] {
        let p = Problem::load(&data(name)).unwrap();
        let theta = p.params().values();
        let textbook = joint_expectation(&p, &theta);
        let exact = p.expected(&theta, p.mc()).expect("exact sums");
        let runs = p.mc().runs() as f64;
        let close = |u: f64, v: f64| (u - v).abs() <= 1e-7 * u.abs().max(v.abs());
        for k in 0..p.mc().steps() {
            let (nees, nis) = (exact.nees_sum()[k] / runs, exact.nis_sum()[k] / runs);
            assert!(
                close(nees, textbook.nees[k]),
                "{name} NEES step {k}: {nees} vs {}",
                textbook.nees[k]
            );
            assert!(
                close(nis, textbook.nis[k]),
                "{name} NIS step {k}: {nis} vs {}",
                textbook.nis[k]
            );
        }
        let steps = p.mc().steps() as f64;
        for (j, total) in exact.state_comp_total().iter().enumerate() {
            let want: f64 = textbook.comp.iter().map(|c| c[j]).sum();
            assert!(
                close(total / runs, want),
                "{name} component {j}: {} vs {want}",
                total / runs
            );
            assert!(want / steps > 0.0);
        }
    }
}

/// A filter with the truth's model has two exact recursions: the error's own, and the
/// joint one of truth and estimate (taken when an identity map is given). Every sum they
/// produce agrees to 1e-9 of its largest entry on the shipped linear problems, lags
/// included (measured: 1.2e-10 at worst, cv2d's NIS² sums).
#[test]
fn the_error_and_joint_recursions_agree_where_both_apply() {
    use autotune::internals::montecarlo::expected_accumulator_mapped;
    let mut compared = 0;
    for name in ["cv1d.toml", "cv2d.toml", "dcmotor.toml"] {
        let p = Problem::load(
            &Path::new(env!("CARGO_MANIFEST_DIR"))
                .join("problems")
                .join(name),
        )
        .unwrap();
        let Some(lin) = p.linear() else { continue };
        let theta = p.params().values();
        // Off the truth, so that the filter's gains differ from the truth's.
        let theta: Vec<f64> = theta
            .iter()
            .enumerate()
            .map(|(i, v)| v * (1.0 + 0.7 * (i % 3) as f64))
            .collect();
        let kf = lin.filter_at(&theta);
        if !models_match(&lin.truth, &kf) || lin.filter.map.is_some() {
            continue;
        }
        let mc = p.mc().with_lags(3).unwrap();
        let identity = DMatrix::identity(kf.F.nrows(), lin.truth.F.nrows());
        let own = expected_accumulator_mapped(&lin.truth, &kf, None, &mc).unwrap();
        let joint = expected_accumulator_mapped(&lin.truth, &kf, Some(&identity), &mc).unwrap();
        // Relative to the largest entry, or, for the sums of means in standard deviations
        // (0 where the filter starts at the truth's mean, and a difference of the truth's
        // and the estimate's means in the joint recursion), to one per run and step.
        let close = |x: &[f64], y: &[f64], what: &str| {
            assert_eq!(x.len(), y.len());
            let scale = x.iter().fold(0.0f64, |m, v| m.max(v.abs()));
            let scale = if what.contains("mean") {
                (mc.runs() * mc.steps()) as f64
            } else {
                scale
            };
            for (i, (u, v)) in x.iter().zip(y).enumerate() {
                assert!(
                    (u - v).abs() <= 1e-9 * scale,
                    "{name} {what}[{i}]: {u} vs {v}"
                );
            }
        };
        close(own.nees_sum(), joint.nees_sum(), "nees_sum");
        close(own.nees_sq(), joint.nees_sq(), "nees_sq");
        close(own.nis_sum(), joint.nis_sum(), "nis_sum");
        close(own.nis_sq(), joint.nis_sq(), "nis_sq");
        close(
            own.state_comp_total(),
            joint.state_comp_total(),
            "state_comp_total",
        );
        close(
            own.state_mean_total(),
            joint.state_mean_total(),
            "state_mean_total",
        );
        close(
            own.meas_comp_total(),
            joint.meas_comp_total(),
            "meas_comp_total",
        );
        close(own.white_ab(), joint.white_ab(), "white_ab");
        assert!(
            own.white_ab().iter().any(|&w| w != 0.0),
            "{name}: lagged sums were computed"
        );
        compared += 1;
    }
    assert_eq!(compared, 3);
}

/// The truth's moments are built once per search ([`TruthTrack`]) and read by every
/// candidate filter scored against it: each filter's sums equal, bit for bit, those of the
/// path that propagates the truth itself, for filters at other noise levels than the one
/// the track was built with; a track built for fewer steps, another map or another truth
/// is not read (the sums are still the filter's own).
#[test]
fn a_truth_track_serves_every_filter_alike() {
    use autotune::internals::montecarlo::{
        TruthTrack, expected_accumulator_mapped, expected_accumulator_tracked,
    };
    for name in ["singer_vs_cv.toml", "ca_vs_cv.toml"] {
        let p = Problem::load(&data(name)).unwrap();
        let lin = p.linear().expect("a linear problem");
        let theta = p.params().values();
        let mc = p.mc().with_lags(3).unwrap();
        let map = lin.filter.map.as_ref();
        let first = lin.filter_at(&theta);
        let track = TruthTrack::new(&lin.truth, &first, map, mc.steps());
        let short = TruthTrack::new(&lin.truth, &first, map, mc.steps() / 2);
        let other = map.map(|m| m * 2.0);
        let elsewhere = TruthTrack::new(&lin.truth, &first, other.as_ref(), mc.steps());
        let mut noisier = lin.truth.clone();
        noisier.model.Q *= 2.0;
        let foreign = TruthTrack::new(&noisier, &first, map, mc.steps());
        for scale in [1.0, 0.3, 4.0] {
            let at: Vec<f64> = theta.iter().map(|v| v * scale).collect();
            let kf = lin.filter_at(&at);
            let own = expected_accumulator_mapped(&lin.truth, &kf, map, &mc).unwrap();
            for t in [&track, &short, &elsewhere] {
                let read = expected_accumulator_tracked(&lin.truth, &kf, map, &mc, Some(t));
                assert_eq!(read.unwrap(), own, "{name} at ×{scale}");
            }
            let not_read = expected_accumulator_tracked(&lin.truth, &kf, map, &mc, Some(&foreign));
            assert_eq!(
                not_read.unwrap(),
                own,
                "{name} at ×{scale}, another truth's track"
            );
        }
    }
}
