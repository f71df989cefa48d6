//! What range of each parameter a record supports, as `estimate` prints it: the profile
//! likelihood's interval and where the record's gate passes, with how much data they rest
//! on and what more would add.

use std::fmt::Write;

use super::EstimateSummary;
use crate::estimate::{GateRanges, LikelihoodRanges};
use crate::report::format::range_text;

/// The supported-range table of an estimate's free parameters, and the sentence that says
/// what it rests on.
pub fn ranges_text(
    o: &mut String,
    summary: &EstimateSummary<'_>,
    likelihood: &LikelihoodRanges,
    gate: &GateRanges,
) {
    let _ = writeln!(
        o,
        "supported by the record: the {:.0}% profile-likelihood interval, and where the record passes the gate (the other parameters at the estimate)",
        100.0 * likelihood.level
    );
    let _ = writeln!(
        o,
        "{:<14} {:>26} {:>26}",
        "parameter", "likelihood interval", "gate passes"
    );
    let gate_missing = if gate.passes_at_point {
        "not traced"
    } else {
        "fails at the estimate"
    };
    for (i, d) in summary.params.params.iter().enumerate() {
        if d.fixed {
            continue;
        }
        let _ = writeln!(
            o,
            "{:<14} {:>26} {:>26}",
            d.name,
            range_text(likelihood.ranges[i].as_ref(), "not traced"),
            range_text(gate.ranges[i].as_ref(), gate_missing)
        );
    }
    let _ = writeln!(o, "{}", rests_on(summary));
}

/// What the ranges rest on: the record's size, and that they narrow only with more of it.
pub fn rests_on(summary: &EstimateSummary<'_>) -> String {
    let what = if summary.sequences == 1 {
        "one recording".to_string()
    } else {
        format!("{} recordings", summary.sequences)
    };
    format!(
        "judged on {what} ({} steps, {} measured values), not on simulated runs: there are no fresh seeds to confirm on; a second recording of the same length would narrow these ranges by about 1/√2",
        summary.steps, summary.values
    )
}

/// The ranges as the JSON `--json` adds under `"supported"`.
pub fn ranges_json(likelihood: &LikelihoodRanges, gate: &GateRanges) -> serde_json::Value {
    serde_json::json!({
        "level": likelihood.level,
        "likelihood": likelihood.ranges,
        "likelihood_evaluations": likelihood.evaluations,
        "gate_passes_at_point": gate.passes_at_point,
        "gate": gate.ranges,
        "gate_evaluations": gate.evaluations,
    })
}
