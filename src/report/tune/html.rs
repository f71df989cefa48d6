//! The HTML report of `autotune tune`.

use std::fmt::Write;

use crate::experiment::Experiment;
use crate::report::advice::{Recommendation, family_finding};
use crate::report::consistency::html::{plots, stats_table};
use crate::report::consistency::plots::objective_svg;
use crate::report::format::{fmt_fixed, fmt_g};
use crate::report::html::{escape, figure, head};
use crate::tune::TuneResult;

/// The HTML report of `autotune tune`: recommendations, before/after statistics and plots
/// side by side, and the objective's progress.
pub fn tune_html(
    experiment: &dyn Experiment,
    res: &TuneResult,
    recs: &[Recommendation],
    explanations: &[crate::explain::Explanation],
) -> String {
    let info = experiment.info();
    let mut o = String::new();
    head(&mut o, &format!("autotune tune: {}", info.name));
    let _ = writeln!(o, "<h1>autotune tune: {}</h1>", escape(&info.name));
    let confirmed = if res.confirmation.recorded {
        format!(
            "Confirmation on the recorded measurements the search scored on, α = {}",
            res.alpha
        )
    } else {
        format!(
            "Confirmation on fresh seeds (from seed {}), N = {} runs × T = {} steps, α = {}",
            res.confirm_seed, res.runs, res.steps, res.alpha
        )
    };
    let _ = writeln!(
        o,
        "<p>{} — <code>{}</code>. {confirmed}.</p>",
        escape(&info.description),
        escape(&info.source.label())
    );
    let _ = writeln!(
        o,
        "<p class=\"verdict\">Before: {}. {}: {}. Confirmation: {}.</p>",
        escape(res.before.verdict.label()),
        super::after_heading(res),
        escape(res.after.verdict.describe()),
        escape(&res.confirmation.text())
    );
    if let Some(lines) = family_finding(res, explanations) {
        let _ = write!(o, "<h2>{}</h2><ul>", super::misfit_heading(res));
        for l in lines {
            let _ = write!(o, "<li>{}</li>", escape(&l));
        }
        o.push_str("</ul>\n");
    }
    o.push_str("<h2>Recommendations</h2><ul>");
    for r in recs {
        let _ = write!(o, "<li>{}</li>", escape(&r.advice));
    }
    o.push_str("</ul>\n<table><tr><th>parameter</th><th>unit</th><th>initial</th><th>tuned</th><th>factor</th><th>determined within</th></tr>\n");
    for r in recs {
        let res_text = r.resolution_text();
        let _ = writeln!(
            o,
            "<tr><td><code>{}</code></td><td>{}</td><td>{}</td><td>{}</td><td>×{}</td><td>{}</td></tr>",
            escape(&r.param),
            escape(&r.unit),
            fmt_g(r.initial),
            fmt_g(r.tuned),
            fmt_fixed(r.factor, 3),
            res_text
        );
    }
    o.push_str("</table>\n<h2>Consistency before and after</h2>\n");
    let reports = [("initial", &res.before), ("tuned", &res.after)];
    stats_table(&mut o, &reports);
    plots(&mut o, &reports);
    o.push_str("<h2>Search</h2><div class=\"row\">");
    figure(
        &mut o,
        &objective_svg("objective against evaluations", &res.history),
        &format!(
            "{} evaluations ({:?} scoring), {} diverged candidates; objective {:.3e} → {:.3e}.",
            res.evaluations,
            res.scoring,
            res.diverged_evaluations,
            res.objective_initial.total,
            res.objective_final.total
        ),
    );
    let _ = writeln!(
        o,
        "</div><p><small>autotune {}</small></p></body></html>",
        env!("CARGO_PKG_VERSION")
    );
    o
}
