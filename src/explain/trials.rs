//! The trials: each candidate change run as a search through [`tune`].

use super::{Explanation, FIT_RUNS, Trial, fit_offsets};
use crate::experiment::{Alteration, DT_SCALE, Experiment};
use crate::montecarlo::McConfig;
use crate::tune::{LocalSearch, Silent, TuneError, TuneResult, TuneSettings, tune};

/// An explanation before its trial, and the trial it calls for.
pub(super) struct Candidate {
    pub(super) explanation: Explanation,
    pub(super) trial: Option<TrialKind>,
}

pub(super) enum TrialKind {
    Offsets,
    Free(usize),
    TimeScale,
}

impl TrialKind {
    pub(super) fn inexpressible(&self) -> &'static str {
        match self {
            TrialKind::Offsets | TrialKind::TimeScale => {
                "this filter's model is not one autotune can change (only a problem file's linear [truth]/[filter] can be)"
            }
            TrialKind::Free(_) => "the search could not run with it freed",
        }
    }

    /// The remedy once the trial has run: specific numbers where it fit, the generic
    /// remedy otherwise.
    pub(super) fn remedy(
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

pub(super) fn fmt_value(v: f64) -> String {
    if v.abs() >= 100.0 || (v != 0.0 && v.abs() < 0.01) {
        format!("{v:.3e}")
    } else {
        format!("{v:.3}")
    }
}

/// The trials' shared settings: every trial is a [`tune`] of the (altered) experiment from
/// the designer's values, with the run's own settings and Monte Carlo test.
pub(super) struct Trials<'a> {
    pub(super) experiment: &'a dyn Experiment,
    pub(super) result: &'a TuneResult,
    pub(super) mc: &'a McConfig,
    pub(super) settings: &'a TuneSettings,
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
    pub(super) fn run(&self, kind: &TrialKind) -> Result<Option<Trial>, TuneError> {
        let r = self.result;
        match kind {
            TrialKind::Free(i) => {
                let mut fixed = r.fixed.clone();
                fixed[*i] = false;
                let name = &self.experiment.params().params[*i].name;
                let quiet = self.settings_for(self.experiment, &fixed);
                let t = tune(
                    self.experiment,
                    &r.initial,
                    &fixed,
                    self.mc,
                    &quiet,
                    &Silent,
                )?;
                Ok(Some(trial(
                    format!("freeing {name}"),
                    self.experiment,
                    &t,
                    &[],
                )))
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
