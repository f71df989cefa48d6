//! The candidate explanations and their evidence, read from a tuning run's reports.

use super::trials::{Candidate, TrialKind, fmt_value};
use super::{Cause, Explanation, Trial};
use crate::experiment::Experiment;
use crate::params::NoiseKind;
use crate::stats::{ComponentStat, ConsistencyReport, Verdict};
use crate::tune::TuneResult;

/// The bounds the tuner widened: the widening was the trial.
pub(super) fn bounds(experiment: &dyn Experiment, result: &TuneResult) -> Vec<Explanation> {
    let params = &experiment.params().params;
    result
        .widened
        .iter()
        .map(|w| {
            let p = &params[w.param];
            let side = if w.to.0 < w.from.0 { "lower" } else { "upper" };
            let still = result.at_bound.get(w.param).copied().unwrap_or(false);
            let t = Trial {
                change: format!(
                    "widening its {side} bound once, to [{}, {}]",
                    fmt_value(w.to.0),
                    fmt_value(w.to.1)
                ),
                status: result.status,
                passed: result.confirmation.passed,
                seeds: result.confirmation.seeds,
                band_low: result.confirmation.band_low,
                values: vec![(p.name.clone(), result.tuned[w.param])],
                evaluations: 0,
            };
            let remedy = if still {
                format!(
                    "{} is at its bound even after widening: the data want it further still, which usually means the model is wrong elsewhere",
                    p.name
                )
            } else {
                format!(
                    "widen {}'s bounds in the problem file (the fit is {} {})",
                    p.name,
                    fmt_value(result.tuned[w.param]),
                    p.unit
                )
            };
            Explanation {
                cause: Cause::SearchBounds,
                subject: p.name.clone(),
                evidence: format!(
                    "{} stopped at its {side} bound {} of [{}, {}]",
                    p.name,
                    fmt_value(if side == "lower" { w.from.0 } else { w.from.1 }),
                    fmt_value(w.from.0),
                    fmt_value(w.from.1)
                ),
                remedy,
                trial: Some(t),
                untried: None,
                strength: f64::INFINITY,
            }
        })
        .collect()
}

fn off(c: &ComponentStat) -> bool {
    matches!(c.verdict, Verdict::Overconfident | Verdict::Underconfident)
}

fn stat_name(c: &ComponentStat) -> &'static str {
    if c.kind == "state" { "e²/P" } else { "ν²/S" }
}

fn mean_name(c: &ComponentStat) -> &'static str {
    if c.kind == "state" {
        "e/√P"
    } else {
        "ν/√S"
    }
}

/// A failed zero-mean test, at the best fit or at the start.
pub(super) fn bias(result: &TuneResult) -> Option<Candidate> {
    let pick = |r: &ConsistencyReport| -> Vec<ComponentStat> {
        let mut v: Vec<ComponentStat> = r
            .state_components
            .iter()
            .chain(&r.measurement_components)
            .filter(|c| c.mean_verdict == Verdict::Biased)
            .cloned()
            .collect();
        v.sort_by(|a, b| b.mean_z.abs().total_cmp(&a.mean_z.abs()));
        v
    };
    // The best fit's evidence first; a bias the search hid is still a bias at the start.
    [
        (&result.after, "at the best fit"),
        (&result.before, "at the start"),
    ]
    .into_iter()
    .map(|(r, when)| (pick(r), when))
    .find(|(biased, _)| !biased.is_empty())
    .map(|(biased, when)| bias_candidate(biased, when))
}

fn bias_candidate(biased: Vec<ComponentStat>, when: &str) -> Candidate {
    let ev: Vec<String> = biased
        .iter()
        .take(3)
        .map(|c| {
            format!(
                "{} mean {} = {:+.3} (z = {:+.1})",
                c.name,
                mean_name(c),
                c.mean,
                c.mean_z
            )
        })
        .collect();
    let names: Vec<&str> = biased.iter().map(|c| c.name.as_str()).collect();
    Candidate {
        explanation: Explanation {
            cause: Cause::SensorBias,
            subject: names.join(", "),
            evidence: format!("errors that do not average to zero {when}: {}", ev.join("; ")),
            remedy: "find the sensor whose readings carry a constant offset and model it (a bias state) or calibrate it out".into(),
            trial: None,
            untried: None,
            strength: biased.first().map_or(0.0, |c| c.mean_z.abs()),
        },
        trial: Some(TrialKind::Offsets),
    }
}

/// Each fixed parameter whose components stay off at the best fit (or, without known
/// targets, every fixed parameter when the gate fails), strongest first.
pub(super) fn fixed(experiment: &dyn Experiment, result: &TuneResult) -> Vec<Candidate> {
    let a = &result.after;
    let mut out: Vec<Candidate> = Vec::new();
    for (i, p) in experiment.params().params.iter().enumerate() {
        if !result.fixed[i] {
            continue;
        }
        let comps: Vec<&ComponentStat> = match experiment.target(i) {
            Some(t) if t.kind == NoiseKind::Process && !a.state_components.is_empty() => t
                .components
                .iter()
                .filter_map(|&j| a.state_components.get(j))
                .collect(),
            Some(t) if t.kind == NoiseKind::Measurement => t
                .components
                .iter()
                .filter_map(|&j| a.measurement_components.get(j))
                .collect(),
            _ => a
                .state_components
                .iter()
                .chain(&a.measurement_components)
                .collect(),
        };
        let bad: Vec<&&ComponentStat> = comps.iter().filter(|c| off(c)).collect();
        if bad.is_empty() {
            continue;
        }
        let ev: Vec<String> = bad
            .iter()
            .map(|c| format!("{} {} = {:.3}", c.name, stat_name(c), c.value))
            .collect();
        let strength = bad
            .iter()
            .map(|c| c.value.ln().abs())
            .fold(0.0_f64, f64::max);
        out.push(Candidate {
            explanation: Explanation {
                cause: Cause::FixedParameter,
                subject: p.name.clone(),
                evidence: format!(
                    "{} is held at {} while what it drives stays off at the best fit: {}",
                    p.name,
                    fmt_value(result.initial[i]),
                    ev.join(", ")
                ),
                remedy: format!("check the value {} is fixed at", p.name),
                trial: None,
                untried: None,
                strength,
            },
            trial: Some(TrialKind::Free(i)),
        });
    }
    out.sort_by(|a, b| b.explanation.strength.total_cmp(&a.explanation.strength));
    out
}

/// Innovations correlated in time, or state errors in a shape no Q of the family gives:
/// the marks of a wrong time step and of a missing state alike.
pub(super) fn dynamics(result: &TuneResult) -> Vec<Candidate> {
    let a = &result.after;
    let white: Vec<String> = a
        .whiteness_tests
        .iter()
        .filter(|w| w.verdict == Verdict::NotWhite)
        .map(|w| format!("{} ρ₁ = {:+.3}", w.component, w.rho1))
        .collect();
    let high = a
        .state_components
        .iter()
        .any(|c| c.verdict == Verdict::Overconfident);
    let low = a
        .state_components
        .iter()
        .any(|c| c.verdict == Verdict::Underconfident);
    let mut ev = Vec::new();
    if !white.is_empty() {
        ev.push(format!(
            "innovations stay correlated in time at the best fit ({})",
            white.join(", ")
        ));
    }
    if high && low {
        let shape: Vec<String> = a
            .state_components
            .iter()
            .filter(|c| off(c))
            .map(|c| format!("{} e²/P = {:.3}", c.name, c.value))
            .collect();
        ev.push(format!(
            "state errors keep a shape no Q of this family gives ({})",
            shape.join(", ")
        ));
    }
    if ev.is_empty() {
        return Vec::new();
    }
    let strength = a
        .whiteness_tests
        .iter()
        .map(|w| w.rho1.abs())
        .fold(0.0_f64, f64::max);
    let evidence = ev.join("; ");
    // The components that carry the marks: in a problem of decoupled axes, the axis at fault.
    let mut marked: Vec<&str> = a
        .whiteness_tests
        .iter()
        .filter(|w| w.verdict == Verdict::NotWhite)
        .map(|w| w.component.as_str())
        .collect();
    if high && low {
        marked.extend(
            a.state_components
                .iter()
                .filter(|c| off(c))
                .map(|c| c.name.as_str()),
        );
    }
    marked.dedup();
    let around = format!("around {}", marked.join(", "));
    vec![
        Candidate {
            explanation: Explanation {
                cause: Cause::TimeStep,
                subject: format!("the filter's F, {around}"),
                evidence: evidence.clone(),
                remedy: "check the time step the filter's F (and Q) are built for against the data's sample period".into(),
                trial: None,
                untried: None,
                strength,
            },
            trial: Some(TrialKind::TimeScale),
        },
        Candidate {
            explanation: Explanation {
                cause: Cause::MissingState,
                subject: format!("the motion model, {around}"),
                evidence,
                remedy: "add the state the truth has and the filter lacks: an acceleration state for a manoeuvring target, a Gauss–Markov state for a slowly varying disturbance, or a bias state for a sensor offset that changes from run to run (a constant one shows as a bias above)".into(),
                trial: None,
                untried: Some("autotune cannot add a state to a filter".into()),
                strength,
            },
            trial: None,
        },
    ]
}
