//! A filter that does not supply its error map (issue #10): the NEES gate falls back to the
//! spread of the per-run NEES sums and still rejects a wrong Q.
//!
//! Before the fallback, a filter that left the map at its default (the identity) made the
//! engine predict NEES correlated over the whole run: on cv2d the ANEES interval widened from
//! [3.946, 4.054] to [3.556, 4.471], and Q ×0.8 and ×1.3 both read "consistent".

use crate::common;
use autotune::Structure;
use common::NoMap;

use autotune::internals::experiment::Experiment;
use autotune::internals::montecarlo::run_generic;
use autotune::internals::stats::{ConsistencyReport, Verdict};
use common::{load, scaled, truth_values};
use statrs::distribution::{Binomial, DiscreteCDF};

/// The consistency report of cv2d's filter at `theta`, with or without its error map, at
/// seed `seed` (N = 200, T = 200 as shipped).
fn report(theta: &[f64], with_map: bool, seed: u64) -> ConsistencyReport {
    let p = load("cv2d");
    let l = p.linear().unwrap();
    let mc = p.mc().with_seed(seed);
    let kf = l.filter_at(theta);
    let acc = if with_map {
        run_generic(&l.truth, &kf, &mc)
    } else {
        run_generic(&l.truth, &NoMap(kf), &mc)
    };
    ConsistencyReport::from_accumulator(
        &acc,
        &autotune::internals::stats::GateSpec::full(mc.alpha(), true),
        p.state_names(),
        p.measurement_names(),
    )
}

#[test]
fn regression_issue_10_a_wrong_q_fails_the_nees_gate_without_an_error_map() {
    let p = load("cv2d");
    let truth = truth_values(&p);
    for factor in [0.8, 1.3] {
        let theta = scaled(&p, &truth, "q_", factor);
        let r = report(&theta, false, p.mc().seed());
        let nees = r.nees.as_ref().unwrap();
        assert_eq!(nees.run_spread_runs, Some(200), "the fallback is in use");
        // Measured ANEES 4.44 (×0.8) and 3.59 (×1.3) against an interval of about ±1.5%
        // around 4: inside the old identity-map interval [3.556, 4.471], far outside this one.
        let want = if factor < 1.0 {
            Verdict::Overconfident
        } else {
            Verdict::Underconfident
        };
        assert_eq!(
            nees.verdict, want,
            "Q x{factor}: ANEES {} in [{}, {}]",
            nees.time_average, nees.interval.lower, nees.interval.upper
        );
        assert!(!r.verdict.passes());
    }
}

#[test]
fn without_an_error_map_the_interval_is_about_as_wide_as_the_filters_prediction() {
    // The run-spread interval estimates the same variance the filter predicts, from 200
    // runs: its half-width has a relative standard error of about 1/√(2·199) = 5%, plus the
    // t quantile's 0.4% over the normal one. Measured ratios over these seeds: 0.96–1.05;
    // 0.85–1.2 is three standard errors each way.
    let p = load("cv2d");
    let theta = truth_values(&p);
    for seed in [1, 2, 3, 4] {
        let model = report(&theta, true, seed);
        let spread = report(&theta, false, seed);
        let (m, s) = (model.nees.unwrap(), spread.nees.unwrap());
        assert_eq!(m.run_spread_runs, None);
        assert!((m.time_average - s.time_average).abs() < 1e-12, "same runs");
        let ratio = (s.interval.upper - s.interval.lower) / (m.interval.upper - m.interval.lower);
        assert!(
            (0.85..=1.2).contains(&ratio),
            "seed {seed}: width ratio {ratio}: model [{}, {}], spread [{}, {}]",
            m.interval.lower,
            m.interval.upper,
            s.interval.lower,
            s.interval.upper
        );
        assert!(
            s.interval.lower <= s.naive_interval.lower
                && s.interval.upper >= s.naive_interval.upper,
            "never narrower than the textbook interval"
        );
    }
}

#[test]
fn without_an_error_map_false_alarms_stay_at_the_statistics_level() {
    // At the truth's noise the NEES test alone rejects with probability α_s = 1 − √0.95
    // (Šidák share of α = 0.05). Over 100 seeds the count must lie in the 99% binomial band
    // around α_s: at most 7 (measured: 3). A fallback that ignored the correlation over time
    // (the textbook interval) rejects 16 of these 100 seeds.
    let p = load("cv2d");
    let theta = truth_values(&p);
    let seeds = 100u64;
    let alpha_s = autotune::internals::stats::gate_alpha(p.mc().alpha(), 2);
    let mut rejected = 0u64;
    for seed in 0..seeds {
        let r = report(&theta, false, 1000 + seed);
        if r.nees.unwrap().verdict != Verdict::Consistent {
            rejected += 1;
        }
    }
    let band = Binomial::new(alpha_s, seeds).unwrap();
    let hi = band.inverse_cdf(0.995);
    assert!(
        rejected <= hi,
        "{rejected} of {seeds} false alarms (99% band 0..={hi})"
    );
}
