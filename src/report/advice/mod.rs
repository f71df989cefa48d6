//! Per-parameter recommendations in the words filter designers use.

mod finding;

pub use finding::family_finding;

use serde::Serialize;

use crate::experiment::Experiment;
use crate::explain::Explanation;
use crate::params::{NoiseKind, Target};
use crate::stats::ConsistencyReport;
use crate::tune::{TuneResult, TuneStatus};

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
    /// Whether the data pin the parameter down (see `crate::tune::Resolution`); `None`
    /// when not assessed because the search stopped on its budget.
    pub identifiable: Option<bool>,
    /// Factor within which the tuned value is determined, if known.
    pub resolution: Option<f64>,
    /// The tuned value sits on a search bound (assessed at any status).
    pub at_bound: bool,
    /// On one record: the range over which the record passes the gate, the other
    /// parameters at their tuned values (its unit).
    pub supported: Option<crate::estimate::Range>,
    /// The components the parameter acts on, with their normalized errors in the starting
    /// filter (target 1): `(name, value)`.
    pub evidence: Vec<(String, f64)>,
    /// The recommendation in words.
    pub advice: String,
}

/// A component further than this factor from 1 counts as off in a label.
const OFF: f64 = 1.05;

/// What the evidence says, in one word: "overconfident" when every component the parameter
/// acts on is at or above 1 and some above [`OFF`], "underconfident" likewise below,
/// "mixed" when some are above and some below, and "" when all are near 1. The label
/// follows the numbers shown; the action beside it follows the change the search made.
fn evidence_label(evidence: &[(String, f64)]) -> &'static str {
    let above = evidence.iter().any(|(_, v)| *v > OFF);
    let below = evidence.iter().any(|(_, v)| *v < 1.0 / OFF);
    match (above, below) {
        (true, true) => "mixed",
        (true, false) => "overconfident",
        (false, true) => "underconfident",
        (false, false) => "",
    }
}

/// A component's normalized error as evidence, 2 decimals; `no data` for a component that
/// was never measured (its average is 0/0).
pub(crate) fn fmt_evidence(v: f64) -> String {
    if v.is_nan() {
        "no data".into()
    } else {
        crate::report::format::fmt_fixed(v, 2)
    }
}

/// Search bounds as `[lower, upper]`.
fn fmt_bounds((lower, upper): (f64, f64)) -> String {
    format!(
        "[{}, {}]",
        crate::report::fmt_g(lower),
        crate::report::fmt_g(upper)
    )
}

/// A change factor: whole numbers from 10 on, scientific notation from 10⁶ on (a search
/// that ran to a far bound), 2 decimals below 10.
fn fmt_factor(f: f64) -> String {
    if f >= 10.0 {
        crate::report::format::fmt_fixed(f, 0)
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
        let evidence = start_evidence(experiment, i, before);
        let initial = result.initial[i];
        let tuned = result.tuned[i];
        let factor = tuned / initial;
        let res = result.resolution.as_ref().map(|r| r[i]);
        let unsearched = result.status == TuneStatus::BudgetExhausted && tuned == initial;
        // Flagged from the run's own flags, at any status: a run that stopped on its
        // budget has no resolution, but its value can still sit on a bound.
        let at_bound = result.at_bound.get(i).copied().unwrap_or(false);
        let what = evidence_text(experiment, i, before, &evidence);
        let advice = advice_line(result, i, p, &what, factor, unsearched, at_bound);
        // On one record the reports say once why there is no resolution.
        let advice =
            if res.is_none() && !result.fixed[i] && !unsearched && !result.confirmation.recorded {
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
            at_bound,
            supported: result
                .supported
                .as_ref()
                .and_then(|g| g.ranges.get(i).copied().flatten()),
            evidence,
            advice,
        });
    }
    rows
}

/// Whether parameter `i` is a process-noise (Q) parameter, and the components it drives.
fn target_of(experiment: &dyn Experiment, i: usize) -> (bool, Vec<usize>) {
    let Target { kind, components } = experiment
        .target(i)
        .unwrap_or_else(|| Target::measurement(&[]));
    (kind == NoiseKind::Process, components)
}

/// The start's statistics of the components parameter `i` drives, by name: e²/P of the
/// states a Q parameter drives (the measurements' ν²/S where the run has no states), ν²/S
/// of the measurements an R parameter drives.
fn start_evidence(
    experiment: &dyn Experiment,
    i: usize,
    before: &ConsistencyReport,
) -> Vec<(String, f64)> {
    let (is_q, indices) = target_of(experiment, i);
    let (comps, names) = if is_q {
        (&before.state_components, experiment.state_names())
    } else {
        (
            &before.measurement_components,
            experiment.measurement_names(),
        )
    };
    let evidence: Vec<(String, f64)> = indices
        .iter()
        .filter_map(|&j| comps.get(j).map(|c| (names[j].clone(), c.value)))
        .collect();
    if is_q && evidence.is_empty() {
        // NIS-only runs have no state components; fall back to the measurements.
        return before
            .measurement_components
            .iter()
            .map(|c| (c.name.clone(), c.value))
            .collect();
    }
    evidence
}

/// The evidence as the advice quotes it, `x, vx (e²/P = 2.1, 1.9) overconfident at the
/// start; `, or nothing.
fn evidence_text(
    experiment: &dyn Experiment,
    i: usize,
    before: &ConsistencyReport,
    evidence: &[(String, f64)],
) -> String {
    if evidence.is_empty() {
        return String::new();
    }
    let (is_q, _) = target_of(experiment, i);
    let stat = if is_q && !before.state_components.is_empty() {
        "e²/P"
    } else {
        "ν²/S"
    };
    let names: Vec<&str> = evidence.iter().map(|(n, _)| n.as_str()).collect();
    let values: Vec<String> = evidence.iter().map(|(_, v)| fmt_evidence(*v)).collect();
    let what = format!("{} ({stat} = {})", names.join(", "), values.join(", "));
    let label = evidence_label(evidence);
    if label.is_empty() {
        format!("{what}; ")
    } else {
        format!("{what} {label} at the start; ")
    }
}

/// The advice for parameter `i` (`p`) with the start's evidence `what`: held fixed, not
/// searched, at or past its search bound, not identifiable, a best fit of a family that
/// does not fit, or the change to make.
fn advice_line(
    result: &TuneResult,
    i: usize,
    p: &crate::params::ParamDef,
    what: &str,
    factor: f64,
    unsearched: bool,
    at_bound: bool,
) -> String {
    let action = if factor > NEGLIGIBLE {
        format!("increase ×{}", fmt_factor(factor))
    } else if factor < 1.0 / NEGLIGIBLE {
        format!(
            "decrease ×{} (÷{})",
            fmt_factor(factor),
            fmt_factor(1.0 / factor)
        )
    } else {
        format!("about right (×{})", fmt_factor(factor))
    };
    let widening = result.widened.iter().find(|w| w.param == i);
    let res = result.resolution.as_ref().map(|r| r[i]);
    if result.fixed[i] {
        format!(
            "{}: held fixed at {}",
            p.name,
            crate::report::fmt_g(result.initial[i])
        )
    } else if unsearched {
        format!(
            "{}: not searched (the budget ran out before the search moved it); {what}raise the budget",
            p.name
        )
    } else if let (true, Some(w)) = (at_bound, widening) {
        format!(
            "{}: {what}still at its search bound after it was widened once from {} to {}; the data want it further still, a thousand times past the file's bound: check the model and the parameter's units",
            p.name,
            fmt_bounds(w.from),
            fmt_bounds(w.to)
        )
    } else if at_bound {
        format!(
            "{}: stopped at its search bound [{}, {}]; the data may want it beyond, widen the bounds",
            p.name,
            crate::report::fmt_g(p.lower),
            crate::report::fmt_g(p.upper)
        )
    } else if let Some(w) = widening {
        let tail = if result.status == TuneStatus::Inconsistent {
            ", but no value of the free parameters makes the filter consistent (see below)"
        } else {
            ""
        };
        format!(
            "{}: stopped at its search bound {}, widened once to {} and searched again (put the new bounds in the problem file): {what}{action}{tail}",
            p.name,
            fmt_bounds(w.from),
            fmt_bounds(w.to)
        )
    } else if res.is_some_and(|r| !r.identifiable) {
        format!(
            "{}: not identifiable from this data (the gate's runs leave it free by more than a factor of 2); keep a prior value such as a datasheet's",
            p.name
        )
    } else if result.status == TuneStatus::Inconsistent {
        format!(
            "{}: {what}best fit in this family {action}, but no value of the free parameters makes the filter consistent (see below)",
            p.name
        )
    } else {
        format!("{}: {what}{action}", p.name)
    }
}

/// Amend the rows of a misfit run whose first explanation's trial reached consistency: the
/// best fit of the unchanged filter moved parameters to make up for the real cause, so each
/// row also says where the trial (the cause fixed) put the parameter.
pub fn amend_for_explanation(recs: &mut [Recommendation], explanations: &[Explanation]) {
    let Some((e, t)) = explanations
        .first()
        .filter(|e| e.cause != crate::explain::Cause::SearchBounds)
        .filter(|e| e.fits())
        .and_then(|e| e.trial.as_ref().map(|t| (e, t)))
    else {
        // A widened bound is already in the tuned values.
        return;
    };
    for r in recs.iter_mut() {
        let Some((_, v)) = t.values.iter().find(|(n, _)| *n == r.param) else {
            continue;
        };
        let f = v / r.initial;
        let moved = if !(1.0 / NEGLIGIBLE..=NEGLIGIBLE).contains(&f) {
            format!("×{} from the start", fmt_factor(f))
        } else {
            "about right as it was".to_string()
        };
        // A fitted hypothesis's change is its name; other trials say what they did.
        let how = match e.cause {
            crate::explain::Cause::Model(_) => "fitted".to_string(),
            _ => format!("addressed ({})", t.change),
        };
        r.advice = format!(
            "{}; with {} {how}, it is {} ({moved})",
            r.advice,
            e.cause.words(),
            crate::report::fmt_g(*v)
        );
    }
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
            _ if self.supported.is_some() => format!(
                "gate passes {}",
                crate::report::format::range_text(self.supported.as_ref(), "")
            ),
            (false, false, Some(false), _) => "not identifiable".to_string(),
            (false, false, Some(true), Some(f)) => format!("±{:.1}%", 100.0 * (f - 1.0)),
            (false, false, _, _) => "not assessed".to_string(),
        }
    }
}
