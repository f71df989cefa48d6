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
//! that fits is the one to act on), each a search through the same [`crate::tune::tune`] from the
//! designer's values. The list is then ranked: explanations whose trial reached
//! consistency, then those that could not be tried, then those whose trial failed.

use serde::Serialize;

use crate::experiment::Experiment;
use crate::montecarlo::McConfig;
use crate::stats::Accumulator;
use crate::tune::{TuneError, TuneResult, TuneSettings, TuneStatus};

mod candidates;
mod offsets;
mod trials;

use candidates::{bias, bounds, dynamics, fixed};
use trials::{Candidate, Trials};

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
    /// The values found, by name (the trial's own parameters, such as [`crate::experiment::DT_SCALE`], and the
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

/// The explanations of `result` (a run of [`crate::tune::tune`] on `experiment` under `mc` and
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
    let mut fitted = out
        .iter()
        .any(|e| e.trial.as_ref().is_some_and(Trial::consistent));
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
