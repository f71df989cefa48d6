//! What an explanation is: the cause it blames ([`Cause`]), the trial of its change
//! ([`Trial`]) and how it reads ([`Explanation`]).

use serde::Serialize;

use crate::experiment::Hypothesis;
use crate::tune::TuneStatus;

/// What an explanation blames.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Cause {
    /// A change of the filter's model.
    Model(Hypothesis),
    /// A parameter held fixed at a wrong value.
    FixedParameter,
    /// A parameter's search bound.
    SearchBounds,
}

impl Cause {
    /// The cause in a few words.
    pub fn words(self) -> String {
        match self {
            Cause::Model(h) => h.words(),
            Cause::FixedParameter => "a fixed parameter that is wrong".into(),
            Cause::SearchBounds => "a search bound".into(),
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
    /// The values found, by name (the change's own parameters included).
    pub values: Vec<(String, f64)>,
    /// Evaluations the trial spent.
    pub evaluations: usize,
    /// The objective at the trial's best fit.
    pub score: f64,
    /// Whether the change's own parameters ended at their neutral values (it changed
    /// nothing, so its fit is no evidence for its cause).
    pub neutral: bool,
    /// Whether the trial was judged by the innovations alone (the run's own NIS-only
    /// scoring; a change that adds states is judged on the filter's own states).
    pub nis_only: bool,
    /// Whether the trial was judged on a recording rather than on fresh seeds (a seed-free
    /// experiment: `passed` of `seeds` = 1 then says whether the record passes).
    #[serde(skip_serializing_if = "std::ops::Not::not")]
    pub recorded: bool,
    /// The simpler hypothesis this fit is a case of, when that one fits too (coloured noise
    /// whose correlation outlasts the run is a bias; a measurement matrix without a
    /// rotation is a gain): not separate evidence.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub same_as: Option<Hypothesis>,
}

impl Trial {
    /// Whether the change made the filter consistent: at the trial's best fit the filter
    /// passes the gate on fresh seeds as often as a consistent filter does (whether or not
    /// its search had converged when it stopped).
    pub fn consistent(&self) -> bool {
        self.seeds > 0 && self.passed >= self.band_low
    }

    /// Whether the trial is evidence for its cause: it fit, and its change changed
    /// something.
    pub fn fits(&self) -> bool {
        self.consistent() && !self.neutral && self.same_as.is_none()
    }

    pub(super) fn value(&self, name: &str) -> Option<f64> {
        self.values.iter().find(|(n, _)| n == name).map(|(_, v)| *v)
    }

    /// What the gate said on the trial's confirmation: on fresh seeds, or on the record.
    fn passes(&self) -> String {
        if !self.recorded {
            format!("{} of {} fresh seeds pass", self.passed, self.seeds)
        } else if self.passed == self.seeds {
            "the record passes".to_string()
        } else {
            "the record fails".to_string()
        }
    }

    pub(super) fn outcome(&self) -> String {
        let by = if self.nis_only {
            " (judged by the innovations alone)"
        } else {
            ""
        };
        let passes = self.passes();
        if let (true, Some(h)) = (self.consistent(), self.same_as) {
            format!(
                "fits, as a case of {} (which fits too): not separate evidence ({passes}){by}",
                h.words(),
            )
        } else if self.consistent() && self.neutral {
            format!(
                "fits, but with its own parameters at their neutral values: it changed nothing ({passes}){by}"
            )
        } else if self.consistent() {
            format!("makes the filter consistent ({passes}){by}")
        } else if self.recorded {
            format!("does not make it consistent ({passes}){by}")
        } else {
            format!(
                "does not make it consistent ({passes}; a consistent filter passes at least {}){by}",
                self.band_low
            )
        }
    }
}

/// One candidate explanation of a misfit.
#[derive(Debug, Clone, Serialize)]
pub struct Explanation {
    /// What it blames.
    pub cause: Cause,
    /// Where the change is: the sensors (which components), the motion model, the start, a
    /// parameter.
    pub subject: String,
    /// What the fit says, in words and numbers (empty before a trial).
    pub evidence: String,
    /// What to change, in words.
    pub remedy: String,
    /// The trial of the change, when one ran.
    pub trial: Option<Trial>,
    /// Why no trial ran, when none did.
    pub untried: Option<String>,
    /// Parameters the change adds.
    pub added: usize,
}

impl Explanation {
    /// 0: its trial fit; 1: its trial ran and did not fit (or changed nothing); 2: not
    /// tried.
    pub(super) fn rank(&self) -> u8 {
        match &self.trial {
            Some(t) if t.fits() => 0,
            Some(_) => 1,
            None => 2,
        }
    }

    /// Whether its trial made the filter consistent with a real change.
    pub fn fits(&self) -> bool {
        self.rank() == 0
    }

    /// The explanation in one line: cause and subject, what the fit says, and the trial or
    /// why none ran.
    pub fn line(&self) -> String {
        let tried = match (&self.trial, &self.untried) {
            (Some(t), _) => format!("tried: {} {}", t.change, t.outcome()),
            (None, Some(why)) => format!("not tried: {why}"),
            (None, None) => String::new(),
        };
        let mut parts = vec![format!("{} ({})", self.cause.words(), self.subject)];
        if !self.evidence.is_empty() {
            parts.push(self.evidence.clone());
        }
        parts.push(tried);
        let line = parts.join(": ");
        if self.fits() {
            format!("{line}; so: {}", self.remedy)
        } else {
            line
        }
    }
}

/// The per-step correlation from which coloured sensor noise outlasts a run of `steps`
/// steps (`1 − 1/steps`), and is a bias drawn per run to the run's statistics. Also at the
/// correlation's upper bound (0.999), which longer runs cannot reach past.
pub(super) fn slow_correlation(steps: usize) -> f64 {
    (1.0 - 1.0 / steps.max(1) as f64).min(0.998)
}
