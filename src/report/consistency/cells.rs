//! A consistency report's numbers as the tables of every command show them: a statistic's
//! cells, a component's, what no data means, what stopped runs.

use crate::report::format::{fmt_fixed, fmt_g, fmt_signed};
use crate::stats::{ComponentStat, ConsistencyReport, StatisticSummary, Verdict};

/// A gate statistic's cells as every table shows them: the time average, the gate
/// interval, the share of steps inside their per-step interval, and the verdict. A
/// statistic no step had data for (no measurement in the whole run, or every run diverged
/// at once) shows `no data` and dashes, not a row of NaN.
pub(crate) struct StatCells {
    /// Time average, 4 decimals ([`fmt_fixed`]).
    pub average: String,
    /// Degrees-of-freedom target, 2 decimals.
    pub target: String,
    /// `[lower, upper]`, 4 decimals ([`fmt_fixed`]).
    pub interval: String,
    /// Percentage of steps in bounds, 1 decimal.
    pub in_bounds: String,
    /// One-word verdict.
    pub verdict: &'static str,
}

impl StatCells {
    pub(crate) fn of(s: &StatisticSummary) -> StatCells {
        if !has_data(s) {
            return StatCells {
                average: "no data".into(),
                target: "–".into(),
                interval: "–".into(),
                in_bounds: "–".into(),
                verdict: s.verdict.label(),
            };
        }
        StatCells {
            average: fmt_fixed(s.time_average, 4),
            target: fmt_fixed(s.target, 2),
            // No interval (too little data for a spread; a note says why): a dash, not NaN.
            interval: if s.interval.lower.is_nan() {
                "none (see note)".into()
            } else {
                format!(
                    "[{}, {}]",
                    fmt_fixed(s.interval.lower, 4),
                    fmt_fixed(s.interval.upper, 4)
                )
            },
            in_bounds: format!("{:.1}%", 100.0 * s.fraction_in_bounds),
            verdict: s.verdict.label(),
        }
    }
}

/// A component's value and interval cells, 3 decimals ([`fmt_fixed`]); `no data` and a dash
/// for a component that was never measured (a sensor that never reported in the run).
pub(crate) fn component_cells(c: &ComponentStat) -> (String, String) {
    if c.samples > 0.0 && c.value.is_finite() {
        (
            fmt_fixed(c.value, 3),
            format!(
                "[{}, {}]",
                fmt_fixed(c.interval.lower, 3),
                fmt_fixed(c.interval.upper, 3)
            ),
        )
    } else {
        ("no data".into(), "–".into())
    }
}

/// A component's zero-mean cells: its mean (signed, 2 decimals, "!" when the test failed)
/// and its z, or dashes without a test.
pub(crate) fn mean_cells(c: &ComponentStat) -> (String, String) {
    if !c.mean.is_finite() {
        return ("–".into(), "–".into());
    }
    let mark = if c.mean_verdict == Verdict::Biased {
        " !"
    } else {
        ""
    };
    let z = if c.mean_z.is_finite() {
        fmt_signed(c.mean_z, 1)
    } else {
        "–".into()
    };
    (format!("{}{mark}", fmt_signed(c.mean, 2)), z)
}

/// Whether any step had data for `s`.
pub(crate) fn has_data(s: &StatisticSummary) -> bool {
    s.steps_with_data > 0
}

/// Why `s` has no data, in words, for a report of `r`.
pub(crate) fn no_data_reason(s: &StatisticSummary, r: &ConsistencyReport) -> String {
    if r.diverged_runs > 0 && r.diverged_runs == r.runs {
        let why = match r.verdict {
            Verdict::TruthOverflow => "its truth overflowed",
            Verdict::IllConditioned => "a covariance was too ill-conditioned to invert",
            _ => "its filter diverged",
        };
        format!(
            "the A{} test has no data: in every run {why} before a step could be scored",
            s.name
        )
    } else {
        format!(
            "the A{} test has no data: no step of the {} runs × {} steps had {}",
            s.name,
            r.runs,
            r.steps,
            if s.name == "NIS" {
                "a measurement"
            } else {
                "a scored state"
            }
        )
    }
}

/// What stopped runs early, in words, by the verdict it set.
pub(crate) fn stopped_runs(verdict: Verdict) -> &'static str {
    match verdict {
        Verdict::TruthOverflow => "the truth overflowed",
        Verdict::IllConditioned => "a covariance was too ill-conditioned to invert",
        _ => "filter diverged",
    }
}

/// An interval's ends relative to its target: "±4.4%" where they sit alike, or
/// "−8.4% / +8.9%" (a chi-square interval, or one cut at zero).
fn spread_text(target: f64, i: &crate::stats::Interval) -> String {
    let below = 100.0 * (target - i.lower) / target;
    let above = 100.0 * (i.upper - target) / target;
    if (below - above).abs() < 0.05 {
        format!("±{:.1}%", 0.5 * (below + above))
    } else {
        format!("−{below:.1}% / +{above:.1}%")
    }
}

/// For a statistic whose gate interval rests on the spread of the per-run sums (a filter that
/// supplies no error map), the sentence that says so and what it costs: the interval's
/// half-width against the textbook one's, each relative to the target (for 128 runs × 400
/// steps of a 2-state filter, about ±4.4% instead of −1.2% / +1.2%).
///
/// For one run (a single recording), the sentence says the interval comes from batch means
/// over its steps instead, and what a second recording would add.
pub fn run_spread_note(s: &StatisticSummary) -> Option<String> {
    let half = |i: &crate::stats::Interval| spread_text(s.target, i);
    if s.interval.lower.is_nan() && s.time_average.is_finite() {
        return Some(format!(
            "the filter supplies no error map, and one run of {} steps is too short for the spread of its A{} sum over time (batch means needs {} blocks of {} steps), so A{} has no interval and no verdict: a recording of at least {} steps, or a second recording, would give one",
            s.steps_with_data,
            s.name,
            crate::stats::MIN_BATCHES,
            crate::stats::MIN_BATCH_STEPS,
            s.name,
            crate::stats::MIN_BATCHES * crate::stats::MIN_BATCH_STEPS,
        ));
    }
    if let Some(b) = s.batch_spread_batches {
        return Some(format!(
            "the filter supplies no error map and there is one run, so the A{} interval comes from batch means: the spread of the sums of {b} blocks of consecutive steps (Student t, {} degrees of freedom), widened to contain the textbook interval: {} around {} instead of {} (it catches only larger errors; a longer or a second recording narrows it)",
            s.name,
            b - 1,
            half(&s.interval),
            fmt_g(s.target),
            half(&s.naive_interval),
        ));
    }
    s.run_spread_runs.map(|n| {
        format!(
            "the filter supplies no error map, so the A{} interval comes from the spread of the {n} per-run sums (Student t), widened to contain the textbook interval: {} around {} instead of {} (it catches only larger errors; more runs narrow it)",
            s.name,
            half(&s.interval),
            fmt_g(s.target),
            half(&s.naive_interval),
        )
    })
}
