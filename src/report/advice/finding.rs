//! What a tuning run that needed explaining says in the end: whether "no value fits" is
//! proven or undecided, the best statistics achievable, and which changes of the filter's
//! model made it consistent.

use crate::explain::Explanation;
use crate::stats::Verdict;
use crate::tune::{TuneResult, TuneStatus};

/// What a tuning run that needed explaining (`crate::explain::needed`) says about it, in
/// lines of text: whether "no value fits" is proven (its certificate) or undecided, the best
/// achievable statistics and what stays off; then the explanations: the changes whose
/// trial made the filter consistent (the simplest first; when several fit, the data do not
/// decide between them), or that none of the tried changes does; what was tried and did
/// not fit; and what could not be tried. `None` when there is nothing to explain.
pub fn family_finding(result: &TuneResult, explanations: &[Explanation]) -> Option<Vec<String>> {
    let mut lines = match result.status {
        TuneStatus::Inconsistent | TuneStatus::Undecided => best_achievable(result),
        _ if explanations.is_empty() => return None,
        _ => vec!["the search needed more room than its bounds gave".to_string()],
    };
    let fitted: Vec<&Explanation> = explanations.iter().filter(|e| e.fits()).collect();
    let tried: Vec<&Explanation> = explanations
        .iter()
        .filter(|e| e.trial.is_some() && !e.fits())
        .collect();
    let untried: Vec<&Explanation> = explanations.iter().filter(|e| e.trial.is_none()).collect();
    match fitted.len() {
        // Some tried changes may pass yet explain nothing (their own parameters at no
        // change, or a case of another): then none "makes it consistent" would be false.
        0 if tried
            .iter()
            .any(|e| e.trial.as_ref().is_some_and(|t| t.consistent())) =>
        {
            lines.push(
                "none of the tried changes explains it (those that pass changed nothing, or repeat another): autotune names no cause (what stays off is above)".to_string(),
            )
        }
        0 if !tried.is_empty() => lines.push(
            "none of the tried changes makes it consistent: autotune names no cause (what stays off is above)".to_string(),
        ),
        0 => {}
        1 => lines.push("why: one change makes the filter consistent:".to_string()),
        n => lines.push(format!(
            "why: {n} changes each make the filter consistent, and the data do not decide between them (the simplest first: judged by the full gate before by the innovations alone, then with the fewest added parameters):"
        )),
    }
    for (k, e) in fitted.iter().enumerate() {
        lines.push(format!("{}. {}", k + 1, e.line()));
    }
    if !tried.is_empty() {
        // Each line says which: no fit, a fit that changed nothing, or a case of one above.
        lines.push("tried, and not explaining it:".to_string());
        lines.extend(tried.iter().map(|e| format!("- {}", e.line())));
    }
    // One line per reason, in the order the reasons first appear.
    let mut reasons: Vec<&str> = Vec::new();
    for e in &untried {
        let why = e.untried.as_deref().unwrap_or_default();
        if !reasons.contains(&why) {
            reasons.push(why);
        }
    }
    for why in reasons {
        let what: Vec<String> = untried
            .iter()
            .filter(|e| e.untried.as_deref().unwrap_or_default() == why)
            .map(|e| e.cause.words())
            .collect();
        lines.push(format!("not tried ({why}): {}", what.join("; ")));
    }
    Some(lines)
}

/// Why a failed confirmation is not a proven misfit.
fn undecided(result: &TuneResult) -> String {
    let c = &result.confirmation;
    let head = if c.recorded {
        "the tuned filter fails the gate on the recorded measurements, but that no value fits is not proven".to_string()
    } else {
        format!(
            "the tuned filter fails its confirmation ({} of {} fresh seeds pass; a consistent filter passes at least {}), but that no value fits is not proven",
            c.passed, c.seeds, c.band_low
        )
    };
    match &result.certificate {
        Some(cert) if cert.recheck_passed == Some(true) => format!(
            "{head}: the best fit passes the gate on {} runs, so the effect is at the limit of what {} runs can see (check with --runs {} or more to decide)",
            cert.recheck_runs, result.runs, cert.recheck_runs
        ),
        Some(cert) if cert.agreeing >= 2 => format!(
            "{head}: the gate cannot decide at the best fit on {} runs (inconclusive), so the effect is at the limit of what the runs can see",
            cert.recheck_runs
        ),
        Some(cert) => format!(
            "{head}: the searches from {} starts in a box widened ×{} do not agree on the best score ({} of them do), so the search cannot tell whether a better fit exists",
            cert.starts.len(),
            crate::tune::certify::WIDEN,
            cert.agreeing
        ),
        None => head,
    }
}

/// The best achievable statistics of a family that does not fit, and what stays off.
fn best_achievable(result: &TuneResult) -> Vec<String> {
    let a = &result.after;
    let c = &result.confirmation;
    let mut lines = vec![if result.status == TuneStatus::Undecided {
        undecided(result)
    } else if c.recorded {
        format!(
            "no value of the free parameters makes this filter consistent with the recorded measurements: at the best fit they fail the gate (which a consistent filter does on a fraction α = {} of records, so look at what stays off below)",
            result.alpha
        )
    } else {
        let proof = result.certificate.as_ref().map_or(String::new(), |cert| {
            format!(
                " (proven: {} of {} searches from starts spread over a box widened ×{} agree on the best score, and the best fit fails the gate again on {} runs)",
                cert.agreeing,
                cert.starts.len(),
                crate::tune::certify::WIDEN,
                cert.recheck_runs
            )
        });
        format!(
            "no value of the free parameters makes this filter consistent{proof}: at the best fit {} of {} fresh seeds pass the gate (a consistent filter passes at least {}); the values below are a best fit of a model that does not fit, not a tuning to apply",
            c.passed, c.seeds, c.band_low
        )
    }];
    let stats: Vec<String> = a
        .nees
        .iter()
        .chain(std::iter::once(&a.nis))
        .map(|s| {
            let c = crate::report::consistency::cells::StatCells::of(s);
            format!(
                "A{} {} (target {}, interval {})",
                s.name, c.average, c.target, c.interval
            )
        })
        .collect();
    lines.push(format!("best achievable: {}", stats.join(", ")));
    let off: Vec<String> = a
        .state_components
        .iter()
        .chain(&a.measurement_components)
        .filter(|c| matches!(c.verdict, Verdict::Overconfident | Verdict::Underconfident))
        .map(|c| {
            let stat = if c.kind == "state" { "e²/P" } else { "ν²/S" };
            let dir = if c.verdict == Verdict::Overconfident {
                "errors larger than the filter believes"
            } else {
                "errors smaller than the filter believes"
            };
            format!(
                "{} {stat} = {} ({dir})",
                c.name,
                crate::report::format::fmt_fixed(c.value, 3)
            )
        })
        .collect();
    if !off.is_empty() {
        lines.push(format!("components that stay off: {}", off.join("; ")));
    }
    let lagging: Vec<String> = a
        .whiteness_tests
        .iter()
        .filter(|w| w.verdict == Verdict::NotWhite)
        .map(|w| format!("{} ρ₁ = {:+.3}", w.component, w.rho1))
        .collect();
    if !lagging.is_empty() {
        lines.push(format!(
            "innovations stay correlated in time: {}",
            lagging.join("; ")
        ));
    }
    lines
}
