//! Per-parameter recommendations in the words filter designers use.

use serde::Serialize;

use crate::experiment::Experiment;
use crate::params::{NoiseKind, Target};
use crate::stats::ConsistencyReport;
use crate::tune::TuneResult;

/// A change smaller than this factor (either way) is "about right".
const NEGLIGIBLE: f64 = 1.1;

/// One row of the recommendation table.
#[derive(Debug, Clone, Serialize)]
pub struct Recommendation {
    /// Parameter name.
    pub param: String,
    /// Its unit.
    pub unit: String,
    /// What it models.
    pub about: String,
    /// Starting value.
    pub initial: f64,
    /// Tuned value.
    pub tuned: f64,
    /// tuned / initial.
    pub factor: f64,
    /// Held fixed during tuning.
    pub fixed: bool,
    /// Whether the data pin the parameter down (see [`crate::tune::Resolution`]); `None`
    /// when not assessed because the search stopped on its budget.
    pub identifiable: Option<bool>,
    /// Factor within which the tuned value is determined, if known.
    pub resolution: Option<f64>,
    /// The tuned value sits on a search bound (false when not assessed).
    pub at_bound: bool,
    /// The components the parameter acts on, with their normalized errors in the starting
    /// filter (target 1): `(name, value)`.
    pub evidence: Vec<(String, f64)>,
    /// The recommendation in words.
    pub advice: String,
}

/// A component's normalized error as evidence, 2 decimals; `no data` for a component that
/// was never measured (its average is 0/0).
pub(crate) fn fmt_evidence(v: f64) -> String {
    if v.is_nan() {
        "no data".into()
    } else {
        super::fmt_fixed(v, 2)
    }
}

/// A change factor: whole numbers from 10 on, scientific notation from 10⁶ on (a search
/// that ran to a far bound), 2 decimals below 10.
fn fmt_factor(f: f64) -> String {
    if f >= 10.0 {
        super::fmt_fixed(f, 0)
    } else {
        format!("{f:.2}")
    }
}

/// The recommendation table of a tuning run: one row per parameter.
pub fn recommendations(
    experiment: &dyn Experiment,
    result: &TuneResult,
    before: &ConsistencyReport,
) -> Vec<Recommendation> {
    let mut rows = Vec::new();
    for (i, p) in experiment.params().params.iter().enumerate() {
        let Target {
            kind,
            components: indices,
        } = experiment
            .target(i)
            .unwrap_or_else(|| Target::measurement(&[]));
        let is_q = kind == NoiseKind::Process;
        let (comps, names) = if is_q {
            (&before.state_components, experiment.state_names())
        } else {
            (
                &before.measurement_components,
                experiment.measurement_names(),
            )
        };
        let mut evidence: Vec<(String, f64)> = indices
            .iter()
            .filter_map(|&j| comps.get(j).map(|c| (names[j].clone(), c.value)))
            .collect();
        if is_q && evidence.is_empty() {
            // NIS-only runs have no state components; fall back to the measurements.
            evidence = before
                .measurement_components
                .iter()
                .map(|c| (c.name.clone(), c.value))
                .collect();
        }
        let initial = result.initial[i];
        let tuned = result.tuned[i];
        let factor = tuned / initial;
        let res = result.resolution.as_ref().map(|r| r[i]);
        let what = if evidence.is_empty() {
            p.name.clone()
        } else {
            let stat = if is_q && !before.state_components.is_empty() {
                "e²/P"
            } else {
                "ν²/S"
            };
            let names: Vec<&str> = evidence.iter().map(|(n, _)| n.as_str()).collect();
            let values: Vec<String> = evidence.iter().map(|(_, v)| fmt_evidence(*v)).collect();
            format!("{} ({stat} = {})", names.join(", "), values.join(", "))
        };
        let advice = if result.fixed[i] {
            format!(
                "{}: held fixed at {}",
                p.name,
                crate::report::fmt_g(initial)
            )
        } else if res.is_some_and(|r| r.at_bound) {
            format!(
                "{}: stopped at its search bound [{}, {}]; the data may want it beyond, widen the bounds",
                p.name,
                crate::report::fmt_g(p.lower),
                crate::report::fmt_g(p.upper)
            )
        } else if res.is_some_and(|r| !r.identifiable) {
            format!(
                "{}: not identifiable from this data (the objective is flat over more than a factor of 2); keep a prior value such as a datasheet's",
                p.name
            )
        } else if factor > NEGLIGIBLE {
            if is_q {
                format!(
                    "{}: {what} overconfident, increase ×{}",
                    p.name,
                    fmt_factor(factor)
                )
            } else {
                format!(
                    "{}: {what} sensor noise underestimated, increase ×{}",
                    p.name,
                    fmt_factor(factor)
                )
            }
        } else if factor < 1.0 / NEGLIGIBLE {
            if is_q {
                format!(
                    "{}: {what} underconfident, decrease ×{} (÷{})",
                    p.name,
                    fmt_factor(factor),
                    fmt_factor(1.0 / factor)
                )
            } else {
                format!(
                    "{}: {what} sensor noise overestimated, decrease ×{} (÷{})",
                    p.name,
                    fmt_factor(factor),
                    fmt_factor(1.0 / factor)
                )
            }
        } else {
            format!("{}: about right (×{})", p.name, fmt_factor(factor))
        };
        let advice = if res.is_none() && !result.fixed[i] {
            format!("{advice} (resolution not assessed: the search stopped on its budget)")
        } else {
            advice
        };
        rows.push(Recommendation {
            param: p.name.clone(),
            unit: p.unit.clone(),
            about: p.about.clone(),
            initial,
            tuned,
            factor,
            fixed: result.fixed[i],
            identifiable: res.map(|r| r.identifiable),
            resolution: res.and_then(|r| r.factor),
            at_bound: res.is_some_and(|r| r.at_bound),
            evidence,
            advice,
        });
    }
    rows
}

impl Recommendation {
    /// How precisely the value is determined, in a few words for tables.
    pub fn resolution_text(&self) -> String {
        match (
            self.fixed,
            self.at_bound,
            self.identifiable,
            self.resolution,
        ) {
            (true, ..) => "fixed".to_string(),
            (false, true, ..) => "at a search bound".to_string(),
            (false, false, None, _) => "not assessed".to_string(),
            (false, false, Some(false), _) => "not identifiable".to_string(),
            (false, false, Some(true), Some(f)) => format!("±{:.1}%", 100.0 * (f - 1.0)),
            _ => "–".to_string(),
        }
    }
}
