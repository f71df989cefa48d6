//! Issue 22, zero-mean tests: consistency is zero-mean errors *and* the stated covariance.
//! The full gate tests each component's first moment beside its second, inside the
//! family-wise α; the diagnosis names a bias first; a wrong R alone no longer hedges
//! "Q may be off as well"; field logs test each sensor component's mean with an
//! effective-sample-size correction.

use crate::common;
use autotune::Structure;

use std::path::PathBuf;

use autotune::SimRng;
use autotune::internals::check::check;
use autotune::internals::experiment::Experiment;
use autotune::internals::fieldlog::{NisAnalyzer, NisSettings, SensorInfo, Update};
use autotune::internals::params::NoiseKind;
use autotune::internals::problem::Problem;
use autotune::internals::stats::{ConsistencyReport, Suspect, Verdict, gate_alpha};
use common::{load, scaled, truth_values};
use rand::SeedableRng;
use rand_distr::{Distribution, StandardNormal};
use rayon::prelude::*;
use statrs::distribution::{Binomial, DiscreteCDF};

const SHIPPED: [&str; 6] = ["cv1d", "cv2d", "dcmotor", "ctrv", "orbit2d", "ins_gnss"];

fn data(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data")
        .join(name)
}

/// The truth's noise values of a shipped (linear or catalog) problem.
fn truth_of(p: &Problem) -> Vec<f64> {
    p.truth_values().unwrap_or_else(|| truth_values(p))
}

/// How many zero-mean tests `r` applies (components with a statistic).
fn mean_tests(r: &ConsistencyReport) -> usize {
    r.state_components
        .iter()
        .chain(&r.measurement_components)
        .filter(|c| c.mean_z.is_finite())
        .count()
}

fn any_mean_fails(r: &ConsistencyReport) -> bool {
    r.state_components
        .iter()
        .chain(&r.measurement_components)
        .any(|c| c.mean_verdict == Verdict::Biased)
}

/// At the truth, on every shipped problem, over 100 fresh seeds at the problem's N and T
/// (the catalog problems at N = 50 to keep the cost near 30 s on two cores; their own
/// 100-seed tests at the shipped N are in tests/catalog/shipped.rs): the zero-mean tests fire on
/// no more seeds than their share of the family-wise α allows, and the whole gate (now
/// with them) stays inside Bin(100, 0.05)'s upper 99.5% quantile, 11.
///
/// The zero-mean tests of a consistent filter fail together with probability at most
/// `1 − (1 − ℓ)^m` (ℓ the Šidák level, m the number of mean tests), e.g. 0.019 for cv2d's 6
/// of 16; the bound is the upper 99.5% binomial quantile of that rate. A mean test with
/// the wrong null variance fails it: with the naive variance (the sample count, ignoring
/// the state errors' correlation over time) cv1d's fail on 7 of these 100 seeds (bound 6).
/// Measured on seeds 220000–220099 (gate, mean tests): cv1d 3, 2; cv2d 3, 1; dcmotor 3, 2;
/// ctrv 5, 0; orbit2d 8, 2; ins_gnss 6, 3. About 50 s on two shared cores.
#[test]
fn issue22_zero_mean_tests_keep_false_alarms_in_the_binomial_band_on_every_shipped_problem() {
    let seeds = 100u64;
    let gate_hi = Binomial::new(0.05, seeds).unwrap().inverse_cdf(0.995);
    for name in SHIPPED {
        let p = load(name);
        let truth = truth_of(&p);
        let catalog = !matches!(name, "cv1d" | "cv2d" | "dcmotor");
        let (mut gate_fails, mut mean_fails, mut rate) = (0u64, 0u64, 0.0);
        // Seeds side by side: a catalog problem's 50 runs are one chunk, one core.
        let reports: Vec<ConsistencyReport> = (0..seeds)
            .into_par_iter()
            .map(|s| {
                let mut mc = p.mc().with_seed(220_000 + s);
                if catalog {
                    mc = mc.with_runs(50).unwrap();
                }
                check(&p, &truth, &mc, autotune::Truth::Known).unwrap()
            })
            .collect();
        for r in &reports {
            gate_fails += u64::from(!r.verdict.passes());
            mean_fails += u64::from(any_mean_fails(r));
            let m = mean_tests(r);
            assert!(m > 0, "{name}: no zero-mean test applied");
            rate = 1.0 - (1.0 - gate_alpha(r.alpha, r.tests)).powi(m as i32);
        }
        let mean_hi = Binomial::new(rate, seeds).unwrap().inverse_cdf(0.995);
        eprintln!(
            "{name}: gate fails {gate_fails}, mean tests fail {mean_fails} of {seeds} (bounds {gate_hi}, {mean_hi})"
        );
        assert!(
            gate_fails <= gate_hi,
            "{name}: {gate_fails} of {seeds} seeds fail the gate at the truth (bound {gate_hi})"
        );
        assert!(
            mean_fails <= mean_hi,
            "{name}: the zero-mean tests fail on {mean_fails} of {seeds} seeds at the truth (bound {mean_hi})"
        );
    }
}

/// `theta` with every parameter of kind `kind` multiplied by `factor`.
fn scaled_kind(p: &Problem, theta: &[f64], kind: NoiseKind, factor: f64) -> Vec<f64> {
    theta
        .iter()
        .enumerate()
        .map(|(i, &v)| match p.target(i) {
            Some(t) if t.kind == kind => v * factor,
            _ => v,
        })
        .collect()
}

/// With the zero-mean tests in the family, the gate still rejects Q or R off by 10% either
/// way as often as it did without them: on all 10 seeds of every case where it did before
/// (a power of 0.95 would pass 10 of 10 only 60% of the time).
///
/// Three cases had less than full power at the shipped N and T before issue 22 (measured
/// on these seeds with the mean tests left out of the family: ctrv Q × 1.1 rejected on 9
/// of 10, ins_gnss R × 0.9 on 9, R × 1.1 on 6). The zero-mean tests share one Šidák slot
/// among them, so the second-moment tests keep nearly their old level and these counts are
/// unchanged (9, 9, 6; with an equal Šidák share per mean test they fell to 8, 8, 6): the
/// bounds are those counts.
#[test]
fn issue22_power_at_ten_percent_q_or_r_stays_full_with_the_zero_mean_tests() {
    for name in SHIPPED {
        let p = load(name);
        let truth = truth_of(&p);
        for kind in [NoiseKind::Process, NoiseKind::Measurement] {
            for factor in [0.9, 1.1] {
                let theta = scaled_kind(&p, &truth, kind, factor);
                let need = match (name, kind, factor > 1.0) {
                    ("ctrv", NoiseKind::Process, true) => 9,
                    ("ins_gnss", NoiseKind::Measurement, false) => 9,
                    ("ins_gnss", NoiseKind::Measurement, true) => 6,
                    _ => 10,
                };
                let rejected = (0..10)
                    .filter(|s| {
                        let mc = p.mc().with_seed(221_000 + s);
                        !check(&p, &theta, &mc, autotune::Truth::Known)
                            .unwrap()
                            .verdict
                            .passes()
                    })
                    .count();
                eprintln!("{name}: {kind:?} × {factor} rejected on {rejected} of 10");
                assert!(
                    rejected >= need,
                    "{name}: {kind:?} × {factor} rejected on only {rejected} of 10 seeds (need {need})"
                );
            }
        }
    }
}

/// cv2d whose x position sensor reads 0.5 m (0.5 σ) high, a constant the filter does not
/// model (tests/data/cv2d_offset_issue22.toml), at the truth's noise values: the zero-mean
/// test of the x state component catches it, and the gate's verdict is Biased, on at least
/// 99 of 100 seeds (measured: 100, with |z| around 88: the test is far from its threshold
/// of about 2.9). The diagnosis names the bias first, never Q. Without the zero-mean tests
/// the second-moment test of x also fails (1.37 against [0.97, 1.03]) and the diagnosis
/// blamed Q.
#[test]
fn issue22_a_half_sigma_sensor_offset_is_caught_by_the_zero_mean_test() {
    let p = Problem::load(&data("cv2d_offset_issue22.toml")).unwrap();
    let theta: Vec<f64> = p.params().params.iter().map(|d| d.value).collect();
    let mut caught = 0;
    for s in 0..100 {
        let mc = p.mc().with_seed(222_000 + s);
        let r = check(&p, &theta, &mc, autotune::Truth::Known).unwrap();
        let x = r
            .state_components
            .iter()
            .find(|c| c.name == "x")
            .expect("state x");
        if x.mean_verdict == Verdict::Biased && x.mean < 0.0 && r.verdict == Verdict::Biased {
            caught += 1;
        }
        // The y axis is right: its zero-mean tests pass (a slack bound on 100 seeds; each
        // is at a family level far below 1%).
        if s < 10 {
            let y = r.state_components.iter().find(|c| c.name == "y").unwrap();
            assert_eq!(y.mean_verdict, Verdict::Consistent, "seed {s}: {y:?}");
        }
    }
    assert!(
        caught >= 99,
        "the offset is caught on only {caught} of 100 seeds"
    );
    let r = check(&p, &theta, p.mc(), autotune::Truth::Known).unwrap();
    assert_eq!(
        r.diagnosis.suspect,
        Some(Suspect::Bias),
        "{:?}",
        r.diagnosis
    );
    let first = &r.diagnosis.findings[0];
    assert_eq!(first.suspect, Some(Suspect::Bias));
    assert_eq!(first.component, "x");
    assert!(first.action.contains("sensor offset"), "{}", first.action);
    let text = autotune::report::summary_text("cv2d_offset", &[], &r);
    assert!(text.contains("not zero-mean"), "{text}");
    assert!(text.contains("constant bias"), "{text}");
    assert!(!text.contains("increase Q"), "{text}");
}

/// Issue 22 item 6: cv2d with R alone wrong (× 4 or ÷ 4) and Q exactly right: the states
/// are off the way R's blame explains (a too-small R makes P too small as well), so the
/// diagnosis must not hedge "Q may be off as well", on at least 19 of 20 seeds each. With
/// Q and R off in opposite directions the hedge is still reachable (a state component off
/// against R's direction): it appears on most seeds there.
#[test]
fn issue22_a_wrong_r_alone_does_not_say_q_may_be_off_as_well() {
    let p = load("cv2d");
    let truth = truth_values(&p);
    for factor in [4.0, 0.25] {
        let theta = scaled(&p, &truth, "r_", factor);
        let mut clean = 0;
        for s in 0..20 {
            let r = check(
                &p,
                &theta,
                &p.mc().with_seed(223_000 + s),
                autotune::Truth::Known,
            )
            .unwrap();
            assert!(!r.verdict.passes());
            let head = r.diagnosis.headline().unwrap_or_default();
            clean += usize::from(!head.contains("Q may be off"));
        }
        assert!(
            clean >= 19,
            "R × {factor}: 'Q may be off as well' on {} of 20 seeds",
            20 - clean
        );
    }
    // Q ÷ 4 with R × 4: the innovations blame R (too large: decrease R), while the
    // velocity errors are larger than P says (Q too small): off against R's direction.
    let theta = scaled(&p, &scaled(&p, &truth, "r_", 4.0), "q_", 0.25);
    let mut hedged = 0;
    for s in 0..20 {
        let r = check(
            &p,
            &theta,
            &p.mc().with_seed(223_100 + s),
            autotune::Truth::Known,
        )
        .unwrap();
        hedged += usize::from(
            r.diagnosis
                .headline()
                .is_some_and(|h| h.contains("may be off as well") || h.contains("off too")),
        );
    }
    assert!(
        hedged >= 15,
        "Q and R both off: hedged on only {hedged} of 20"
    );
}

/// One synthetic log of `n` one-component updates whose normalized innovations are an
/// AR(1) sequence of unit variance, lag-1 correlation `rho` and mean `mean`.
fn ar1_log(seed: u64, n: usize, rho: f64, mean: f64, settings: NisSettings) -> NisAnalyzer {
    let mut rng = SimRng::seed_from_u64(seed);
    let mut a = NisAnalyzer::new(settings);
    let i = a
        .sensor(SensorInfo {
            name: "pos".into(),
            components: vec!["pos".into()],
            group: String::new(),
        })
        .unwrap();
    let w = (1.0 - rho * rho).sqrt();
    let mut x: f64 = StandardNormal.sample(&mut rng);
    for k in 0..n {
        let e: f64 = StandardNormal.sample(&mut rng);
        x = rho * x + w * e;
        let u = x + mean;
        a.push(
            i,
            Update {
                time: k as f64,
                nis: u * u,
                dof: 1,
                u: Some(vec![u]),
                sd: None,
            },
        )
        .unwrap();
    }
    a
}

/// Field logs (issue 22): 200 logs of 2 000 updates whose innovations are zero-mean but
/// AR(1) with ρ = 0.8 (a mistuned filter's innovations are correlated; the mean test must
/// not call that a bias). α = 0.2 family-wise over the sensor's 4 tests puts the mean test
/// at ℓ = 0.054, so a count of Bin(200, 0.054) must fall in its central 99% band [3, 20];
/// 20 lags cover the correlation (Σ_{l ≤ 20} 0.8^l is 99% of the infinite sum). Without the
/// effective-sample-size correction the mean's variance is 1 + 2 Σ ρ_l ≈ 9 times what the
/// naive test assumes: the uncorrected statistic (z √(n / n_eff)) fails about half the
/// logs, far outside the band. A mean of 0.3 σ is caught on at least 19 of 20 logs at
/// α = 0.05 (its z is about 0.3 √(2000/9) ≈ 4.5 against a threshold near 2.5).
#[test]
fn issue22_field_log_zero_mean_test_corrects_for_autocorrelation() {
    let settings = NisSettings::default()
        .with_alpha(0.2)
        .unwrap()
        .with_lags(20)
        .unwrap();
    let (logs, n) = (200u64, 2000usize);
    let (mut corrected, mut uncorrected) = (0u64, 0u64);
    let mut level = 0.0;
    for seed in 0..logs {
        let r = ar1_log(224_000 + seed, n, 0.8, 0.0, settings).report();
        level = r.test_alpha;
        let t = &r.sensors[0].mean_tests[0];
        // n / 9 = 222 with the true ρ_l; the estimated sum over 20 lags is noisy.
        assert!(t.n_eff > 100.0 && t.n_eff < 600.0, "n_eff {}", t.n_eff);
        corrected += u64::from(t.verdict == Verdict::Biased);
        let naive = t.z * (t.samples / t.n_eff).sqrt();
        uncorrected += u64::from(naive.abs() > t.threshold);
    }
    let b = Binomial::new(level, logs).unwrap();
    let (lo, hi) = (b.inverse_cdf(0.005), b.inverse_cdf(0.995));
    eprintln!(
        "level {level:.4}: corrected {corrected}, uncorrected {uncorrected} of {logs} (band [{lo}, {hi}])"
    );
    assert!(
        (lo..=hi).contains(&corrected),
        "{corrected} of {logs} zero-mean AR(1) logs called biased (band [{lo}, {hi}])"
    );
    assert!(
        uncorrected > hi,
        "the uncorrected test would pass too: {uncorrected} of {logs}"
    );

    let settings = NisSettings::default().with_lags(20).unwrap();
    let mut caught = 0;
    for seed in 0..20 {
        let r = ar1_log(225_000 + seed, n, 0.8, 0.3, settings).report();
        let s = &r.sensors[0];
        if s.mean_tests[0].verdict == Verdict::Biased && !s.verdict.passes() {
            caught += 1;
        }
        if seed == 0 {
            let text = autotune::report::nis::nis_summary_text(&r);
            assert!(text.contains("mean ν/√S"), "{text}");
            assert!(text.contains("+0.") && text.contains('✗'), "{text}");
        }
    }
    assert!(
        caught >= 19,
        "a 0.3σ mean is caught on only {caught} of 20 logs"
    );
}

/// A white log with a 0.3 σ offset and an S that is otherwise right: the finding names the
/// bias, not Q or R, and the JSON carries the test.
#[test]
fn issue22_field_log_bias_is_the_finding() {
    let r = ar1_log(226_000, 2000, 0.0, 0.3, NisSettings::default()).report();
    assert_eq!(r.suspect, Some(Suspect::Bias), "{:?}", r.sensors[0].finding);
    let f = r.sensors[0].finding.as_ref().unwrap();
    assert!(f.action.contains("offset"), "{}", f.action);
    let json = serde_json::to_value(&r).unwrap();
    let t = &json["sensors"][0]["mean_tests"][0];
    assert_eq!(t["verdict"], "biased");
    assert!(t["mean"].as_f64().unwrap() > 0.2);
}

/// The check report's JSON carries each component's mean, its z and its verdict.
#[test]
fn issue22_check_json_has_component_means() {
    let p = load("cv2d");
    let truth = truth_values(&p);
    let r = check(&p, &truth, p.mc(), autotune::Truth::Known).unwrap();
    let json = serde_json::to_value(&r).unwrap();
    for c in json["state_components"]
        .as_array()
        .unwrap()
        .iter()
        .chain(json["measurement_components"].as_array().unwrap())
    {
        assert!(c["mean"].as_f64().unwrap().abs() < 0.2, "{c}");
        assert!(c["mean_z"].as_f64().is_some(), "{c}");
        assert_eq!(c["mean_verdict"], "consistent", "{c}");
    }
}

/// The first-moment sums agree across the engines: the exact path's expectations with a
/// large Monte Carlo run (a mis-tuned filter whose x0 is off the truth's mean, so the errors
/// and innovations have a mean that decays), and the generic engine with the linear fast
/// path on the same draws (to rounding), including the predicted null variance per run.
#[test]
fn issue22_first_moment_sums_agree_across_engines() {
    use autotune::internals::check::accumulate;
    use autotune::internals::montecarlo::{Engine, expected_accumulator};
    for name in ["cv1d", "cv2d"] {
        let p = load(name);
        let theta = scaled(&p, &scaled(&p, &truth_values(&p), "q_", 3.0), "r_", 0.5);
        let mut l = p.linear().unwrap().clone();
        l.filter.x0 = &l.filter.x0 + l.filter.P0.diagonal().map(|v| 2.0 * v.sqrt());
        let mc = p
            .mc()
            .with_runs(4_000)
            .unwrap()
            .with_steps(40)
            .unwrap()
            .with_lags(3)
            .unwrap();
        let kf = l.filter_at(&theta);
        let exp = expected_accumulator(&l.truth, &kf, &mc).unwrap();
        let sim = accumulate(&l, &theta, &mc, Engine::Linear).unwrap();
        let generic = accumulate(&l, &theta, &mc, Engine::Generic).unwrap();
        let nn = mc.runs() as f64;
        for j in 0..exp.state_mean_total().len() {
            // The mean of N per-run sums: 5 standard errors from their own spread.
            let (s, e) = (
                sim.state_mean_total()[j] / nn,
                exp.state_mean_total()[j] / nn,
            );
            let var = sim.state_mean_run_sq()[j] / nn - s * s;
            let se = (var / nn).sqrt();
            assert!(
                (s - e).abs() < 5.0 * se,
                "{name} state {j}: MC {s} vs exact {e} (se {se})"
            );
            assert!(
                e.abs() > 2.0 * se,
                "{name} state {j}: the mean {e} is too small to test"
            );
            assert_eq!(sim.state_mean_samples()[j], exp.state_mean_samples()[j]);
            let g = generic.state_mean_total()[j] / nn;
            assert!(
                (g - s).abs() <= 1e-9 * (1.0 + s.abs()),
                "{name} state {j}: generic {g} vs linear {s}"
            );
            let per_run = |a: &autotune::internals::stats::Accumulator| {
                a.state_mean_null_var()[j] / a.comp_null_var_runs() as f64
            };
            for (what, v) in [("exact", per_run(&exp)), ("generic", per_run(&generic))] {
                let r = v / per_run(&sim);
                assert!(
                    (r - 1.0).abs() < 1e-6,
                    "{name} state {j}: {what} null variance ratio {r}"
                );
            }
        }
        for j in 0..exp.meas_mean_total().len() {
            // White innovations of a mis-tuned filter are not white, so bound by the
            // per-sample spread times the steps (a loose, conservative standard error).
            let (s, e) = (sim.meas_mean_total()[j] / nn, exp.meas_mean_total()[j] / nn);
            let se = (sim.meas_comp_total()[j] / nn * mc.steps() as f64 / nn).sqrt();
            assert!(
                (s - e).abs() < 5.0 * se,
                "{name} meas {j}: MC {s} vs exact {e} (se {se})"
            );
            let g = generic.meas_mean_total()[j] / nn;
            assert!(
                (g - s).abs() <= 1e-9 * (1.0 + s.abs()),
                "{name} meas {j}: generic {g} vs linear {s}"
            );
        }
    }
}
