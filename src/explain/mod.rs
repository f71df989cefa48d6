//! Why no Q and R fit: candidate explanations of a misfit, each with the evidence the
//! statistics give for it and, where the experiment can express the change, a trial.
//!
//! A tuning run that ends [`TuneStatus::Inconsistent`] has shown that no value of the free
//! parameters makes the filter consistent; it has not shown why. The statistics narrow it
//! down, but several causes leave the same marks (a filter built for the wrong time step and
//! one that lacks an acceleration state both leave correlated innovations), so a cause is
//! named first only when changing it was *tried* and reached consistency:
//! - a constant sensor bias: a zero-mean test fails (the errors or the innovations average
//!   away from 0). Trial: the filter takes a constant offset off each measurement
//!   component; the offsets come from a least-squares fit of the first-moment sums, which
//!   are linear in the offsets (common random numbers, a linear filter), and the noise
//!   parameters are then searched with them;
//! - a fixed parameter that is wrong: the components it drives stay off at the best fit.
//!   Trial: free it;
//! - the filter's time step: innovations correlated in time, or state errors with a shape no
//!   Q of the family gives. Trial: the time step as a parameter (`F ← F^s`);
//! - a missing state (an acceleration, a Gauss–Markov term): the same marks; autotune cannot
//!   add a state, so this is never tried and is named first only when the expressible
//!   changes were tried and failed;
//! - the search bounds: a parameter that stopped at a bound, which the tuner widens once
//!   (its result is the trial).
//!
//! Trials run in that order (the first consistent one ends the trials: a cheaper explanation
//! that fits is the one to act on), each a search through the same [`tune`] from the
//! designer's values. The list is then ranked: explanations whose trial reached
//! consistency, then those that could not be tried, then those whose trial failed.

use serde::Serialize;

use crate::experiment::{Alteration, DT_SCALE, Experiment};
use crate::montecarlo::McConfig;
use crate::params::NoiseKind;
use crate::stats::{Accumulator, ComponentStat, ConsistencyReport, Verdict};
use crate::tune::{LocalSearch, Silent, TuneError, TuneResult, TuneSettings, TuneStatus, tune};

mod offsets;

/// Runs of the offset fit, in multiples of the gate's N.
const FIT_RUNS: usize = 16;

pub use offsets::fit_offsets;

/// What an explanation blames.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Cause {
    /// A constant offset on a sensor that the filter does not model.
    SensorBias,
    /// A parameter held fixed at a wrong value.
    FixedParameter,
    /// The filter's time step (or the time scale of its dynamics).
    TimeStep,
    /// A state the truth has and the filter lacks.
    MissingState,
    /// A parameter's search bound.
    SearchBounds,
    /// The shape of Q or R (which states the noise drives, their correlations).
    NoiseShape,
}

impl Cause {
    /// The cause in a few words.
    pub fn words(self) -> &'static str {
        match self {
            Cause::SensorBias => "a constant sensor bias",
            Cause::FixedParameter => "a fixed parameter that is wrong",
            Cause::TimeStep => "the filter's time step",
            Cause::MissingState => "a state the filter lacks",
            Cause::SearchBounds => "a search bound",
            Cause::NoiseShape => "the shape of the noise model",
        }
    }
}

/// A change tried and what the search found with it.
#[derive(Debug, Clone, Serialize)]
pub struct Trial {
    /// The change, in words ("freeing r_pos").
    pub change: String,
    /// How the search with the change ended.
    pub status: TuneStatus,
    /// Fresh seeds passed by the tuned filter with the change.
    pub passed: usize,
    /// Fresh seeds tried.
    pub seeds: usize,
    /// The fewest passes a consistent filter gives with probability 99%.
    pub band_low: usize,
    /// The values found, by name (the trial's own parameters, such as [`DT_SCALE`], and the
    /// offsets `offset_<component>` in measurement units, included).
    pub values: Vec<(String, f64)>,
    /// Evaluations the trial spent.
    pub evaluations: usize,
}

impl Trial {
    /// Whether the change made the filter consistent.
    pub fn consistent(&self) -> bool {
        self.status == TuneStatus::Consistent
    }

    fn value(&self, name: &str) -> Option<f64> {
        self.values.iter().find(|(n, _)| n == name).map(|(_, v)| *v)
    }

    fn outcome(&self) -> String {
        if self.consistent() {
            format!(
                "makes the filter consistent ({} of {} fresh seeds pass)",
                self.passed, self.seeds
            )
        } else if self.status == TuneStatus::Inconsistent {
            format!(
                "does not make it consistent ({} of {} fresh seeds pass; a consistent filter passes at least {})",
                self.passed, self.seeds, self.band_low
            )
        } else {
            format!(
                "was inconclusive (the search ended {})",
                format!("{:?}", self.status).to_lowercase()
            )
        }
    }
}

/// One candidate explanation of a misfit.
#[derive(Debug, Clone, Serialize)]
pub struct Explanation {
    /// What it blames.
    pub cause: Cause,
    /// What it is about: components, a parameter, the time step.
    pub subject: String,
    /// The statistics that point to it, in words and numbers.
    pub evidence: String,
    /// What to change, in words.
    pub remedy: String,
    /// The trial of the change, when one ran.
    pub trial: Option<Trial>,
    /// Why no trial ran, when none did.
    pub untried: Option<String>,
    /// How strongly the evidence points here (a z-score or log-ratio; larger is stronger),
    /// for ordering among explanations of the same rank.
    pub strength: f64,
}

impl Explanation {
    /// 0: its trial reached consistency; 1: not tried; 2: its trial failed.
    fn rank(&self) -> u8 {
        match &self.trial {
            Some(t) if t.consistent() => 0,
            None => 1,
            Some(_) => 2,
        }
    }

    /// The explanation in one line: cause and subject, evidence, and the trial or why none
    /// ran.
    pub fn line(&self) -> String {
        let tried = match (&self.trial, &self.untried) {
            (Some(t), _) => format!("tried: {} {}", t.change, t.outcome()),
            (None, Some(why)) => format!("not tried: {why}"),
            (None, None) => String::new(),
        };
        format!(
            "{} ({}): {}; {}; so: {}",
            self.cause.words(),
            self.subject,
            self.evidence,
            tried,
            self.remedy
        )
    }
}

/// Whether a tuning run needs explaining: it found no consistent filter, or it had to widen
/// a search bound to find one.
pub fn needed(result: &TuneResult) -> bool {
    result.status == TuneStatus::Inconsistent || !result.widened.is_empty()
}

/// The explanations of `result` (a run of [`tune`] on `experiment` under `mc` and
/// `settings`), ranked: first those whose trial made the filter consistent, then those
/// that could not be tried, then those whose trial failed. Empty when the run needs no
/// explaining ([`needed`]).
pub fn explain(
    experiment: &dyn Experiment,
    result: &TuneResult,
    mc: &McConfig,
    settings: &TuneSettings,
) -> Result<Vec<Explanation>, TuneError> {
    if !needed(result) {
        return Ok(Vec::new());
    }
    let mut out = bounds(experiment, result);
    let trials = Trials {
        experiment,
        result,
        mc,
        settings,
    };
    let mut fitted = out.iter().any(|e| e.trial.as_ref().is_some_and(Trial::consistent));
    let mut candidates: Vec<Candidate> = Vec::new();
    candidates.extend(bias(result));
    candidates.extend(fixed(experiment, result));
    candidates.extend(dynamics(result));
    for c in candidates {
        let mut e = c.explanation;
        match c.trial {
            Some(_) if fitted => {
                e.untried = Some("an explanation above already makes the filter consistent".into())
            }
            Some(kind) => match trials.run(&kind)? {
                Some(t) => {
                    fitted |= t.consistent();
                    e.remedy = kind.remedy(&t, &e.remedy, experiment, result);
                    e.trial = Some(t);
                }
                None => e.untried = Some(kind.inexpressible().into()),
            },
            None => {}
        }
        out.push(e);
    }
    if out.is_empty() {
        out.push(Explanation {
            cause: Cause::NoiseShape,
            subject: "Q and R".into(),
            evidence: "no single component, bias or correlation stands out at the best fit".into(),
            remedy: "free more entries of Q or R (which states the noise drives, their correlations), or add states".into(),
            trial: None,
            untried: Some("autotune cannot change which entries a term drives".into()),
            strength: 0.0,
        });
    }
    // Stable: within a rank, the order of the trials (bounds, bias, fixed, dynamics).
    out.sort_by_key(Explanation::rank);
    Ok(out)
}

/// An explanation before its trial, and the trial it calls for.
struct Candidate {
    explanation: Explanation,
    trial: Option<TrialKind>,
}

enum TrialKind {
    Offsets,
    Free(usize),
    TimeScale,
}

impl TrialKind {
    fn inexpressible(&self) -> &'static str {
        match self {
            TrialKind::Offsets | TrialKind::TimeScale => {
                "this filter's model is not one autotune can change (only a problem file's linear [truth]/[filter] can be)"
            }
            TrialKind::Free(_) => "the search could not run with it freed",
        }
    }

    /// The remedy once the trial has run: specific numbers where it fit, the generic
    /// remedy otherwise.
    fn remedy(
        &self,
        t: &Trial,
        generic: &str,
        experiment: &dyn Experiment,
        result: &TuneResult,
    ) -> String {
        if !t.consistent() {
            return generic.to_string();
        }
        match self {
            TrialKind::Offsets => {
                let offs: Vec<String> = t
                    .values
                    .iter()
                    .filter(|(n, _)| n.starts_with("offset_"))
                    .map(|(n, v)| format!("{} {:+.3}", &n["offset_".len()..], v))
                    .collect();
                format!(
                    "model the bias (a bias state, or calibrate the sensor): the fitted offsets are {}",
                    offs.join(", ")
                )
            }
            TrialKind::Free(i) => {
                let p = &experiment.params().params[*i];
                format!(
                    "set {} to about {} {} (it was fixed at {})",
                    p.name,
                    fmt_value(t.value(&p.name).unwrap_or(f64::NAN)),
                    p.unit,
                    fmt_value(result.initial[*i])
                )
            }
            TrialKind::TimeScale => {
                let s = t.value(DT_SCALE).unwrap_or(f64::NAN);
                format!(
                    "build the filter's F for the truth's step: it advances {} of it (the trial's F is F^{})",
                    fmt_value(1.0 / s),
                    fmt_value(s)
                )
            }
        }
    }
}

fn fmt_value(v: f64) -> String {
    if v.abs() >= 100.0 || (v != 0.0 && v.abs() < 0.01) {
        format!("{v:.3e}")
    } else {
        format!("{v:.3}")
    }
}

/// The trials' shared settings: every trial is a [`tune`] of the (altered) experiment from
/// the designer's values, with the run's own settings and Monte Carlo test.
struct Trials<'a> {
    experiment: &'a dyn Experiment,
    result: &'a TuneResult,
    mc: &'a McConfig,
    settings: &'a TuneSettings,
}

impl Trials<'_> {
    /// The settings of a trial on `e` with the parameters `fixed` held: the run's, with its
    /// confirmation seed, and unless the user chose a local search, Gauss–Newton on the
    /// moment equations where every free parameter's components are known. A trial starts
    /// from the designer's values, which the misfit may have left far from the fit, and the
    /// simplex from a global stage of a few points can settle in a compromise valley (it did
    /// for 2 of 20 seeds of a freed r four times off); the moment equations start from the
    /// start itself and are solved by each parameter's own components.
    fn settings_for(&self, e: &dyn Experiment, fixed: &[bool]) -> TuneSettings {
        let s = self
            .settings
            .clone()
            .with_confirm_seed(Some(self.result.confirm_seed));
        let targets = (0..fixed.len())
            .filter(|&i| !fixed[i])
            .all(|i| e.target(i).is_some_and(|t| !t.components.is_empty()));
        if targets && !self.settings.local_is_set() {
            s.with_local(LocalSearch::GaussNewton)
        } else {
            s
        }
    }

    /// Run the trial; `None` when the experiment cannot express it.
    fn run(&self, kind: &TrialKind) -> Result<Option<Trial>, TuneError> {
        let r = self.result;
        match kind {
            TrialKind::Free(i) => {
                let mut fixed = r.fixed.clone();
                fixed[*i] = false;
                let name = &self.experiment.params().params[*i].name;
                let quiet = self.settings_for(self.experiment, &fixed);
                let t = tune(self.experiment, &r.initial, &fixed, self.mc, &quiet, &Silent)?;
                Ok(Some(trial(format!("freeing {name}"), self.experiment, &t, &[])))
            }
            TrialKind::TimeScale => {
                let Some(e) = self.experiment.alter(&Alteration::TimeScale) else {
                    return Ok(None);
                };
                let mut start = r.initial.clone();
                start.push(1.0);
                let mut fixed = r.fixed.clone();
                fixed.push(false);
                let quiet = self.settings_for(e.as_ref(), &fixed);
                let t = tune(e.as_ref(), &start, &fixed, self.mc, &quiet, &Silent)?;
                Ok(Some(trial(
                    format!("making the filter's time step a parameter ({DT_SCALE})"),
                    e.as_ref(),
                    &t,
                    &[],
                )))
            }
            TrialKind::Offsets => {
                let use_states = !r.after.state_components.is_empty();
                // The fitted offsets are then confirmed on fresh seeds, where their own
                // estimation error adds to the fresh noise: fitted on 16 N runs, that error
                // adds 1/16 to the variance of the zero-mean tests instead of doubling it.
                let runs = self.mc.runs().saturating_mul(FIT_RUNS);
                let Some(d) = self
                    .mc
                    .with_runs(runs)
                    .ok()
                    .and_then(|mc| fit_offsets(self.experiment, &r.tuned, &mc, use_states))
                else {
                    return Ok(None);
                };
                let Some(e) = self
                    .experiment
                    .alter(&Alteration::MeasurementOffset(d.clone()))
                else {
                    return Ok(None);
                };
                let quiet = self.settings_for(e.as_ref(), &r.fixed);
                let t = tune(e.as_ref(), &r.initial, &r.fixed, self.mc, &quiet, &Silent)?;
                let extra: Vec<(String, f64)> = self
                    .experiment
                    .measurement_names()
                    .iter()
                    .zip(&d)
                    .map(|(n, v)| (format!("offset_{n}"), *v))
                    .collect();
                Ok(Some(trial(
                    "taking a fitted constant offset off each sensor reading".to_string(),
                    e.as_ref(),
                    &t,
                    &extra,
                )))
            }
        }
    }
}

fn trial(change: String, e: &dyn Experiment, t: &TuneResult, extra: &[(String, f64)]) -> Trial {
    let mut values: Vec<(String, f64)> = e
        .params()
        .params
        .iter()
        .zip(&t.tuned)
        .map(|(p, v)| (p.name.clone(), *v))
        .collect();
    values.extend_from_slice(extra);
    Trial {
        change,
        status: t.status,
        passed: t.confirmation.passed,
        seeds: t.confirmation.seeds,
        band_low: t.confirmation.band_low,
        values,
        evaluations: t.evaluations + t.refine_evaluations,
    }
}

/// The bounds the tuner widened: the widening was the trial.
fn bounds(experiment: &dyn Experiment, result: &TuneResult) -> Vec<Explanation> {
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
    if c.kind == "state" { "e/√P" } else { "ν/√S" }
}

/// A failed zero-mean test, at the best fit or at the start.
fn bias(result: &TuneResult) -> Option<Candidate> {
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
    let (mut biased, when) = (pick(&result.after), "at the best fit");
    if biased.is_empty() {
        biased = pick(&result.before);
        if biased.is_empty() {
            return None;
        }
        return Some(bias_candidate(biased, "at the start"));
    }
    Some(bias_candidate(std::mem::take(&mut biased), when))
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
fn fixed(experiment: &dyn Experiment, result: &TuneResult) -> Vec<Candidate> {
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
fn dynamics(result: &TuneResult) -> Vec<Candidate> {
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
        marked.extend(a.state_components.iter().filter(|c| off(c)).map(|c| c.name.as_str()));
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

/// The first-moment residuals of `acc` that a sensor offset moves: each component's sum of
/// normalized errors over the square root of its sample count (about N(0, 1)-scaled).
fn first_moments(acc: &Accumulator, use_states: bool) -> Vec<f64> {
    let norm = |t: &[f64], s: &[f64]| -> Vec<f64> {
        t.iter()
            .zip(s)
            .map(|(t, s)| if *s > 0.0 { t / s.sqrt() } else { 0.0 })
            .collect()
    };
    let mut r = Vec::new();
    if use_states {
        r.extend(norm(&acc.state_mean_total, &acc.state_comp_samples));
    }
    r.extend(norm(&acc.meas_mean_total, &acc.meas_comp_samples));
    r
}
