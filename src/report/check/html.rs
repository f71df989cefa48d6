//! The HTML and Markdown pages of `check` and `tune`: the statistics tables, the plots and
//! the advice.

use std::fmt::Write;

use crate::experiment::Experiment;
use crate::report::consistency::html::{components_table, plots, stats_table};
use crate::report::format::fmt_g;
use crate::report::html::{escape, head};
use crate::stats::ConsistencyReport;

/// The HTML report of `autotune check`.
pub fn check_html(
    experiment: &dyn Experiment,
    params: &[(String, f64)],
    r: &ConsistencyReport,
) -> String {
    let info = experiment.info();
    let mut o = String::new();
    head(&mut o, &format!("autotune check: {}", info.name));
    let _ = writeln!(o, "<h1>autotune check: {}</h1>", escape(&info.name));
    let _ = writeln!(
        o,
        "<p>{} — <code>{}</code>, N = {} runs × T = {} steps, α = {}.</p>",
        escape(&info.description),
        escape(&info.source.label()),
        r.runs,
        r.steps,
        r.alpha
    );
    let _ = writeln!(
        o,
        "<p class=\"verdict\">Verdict: {}</p>",
        escape(r.verdict.describe())
    );
    if !params.is_empty() {
        o.push_str("<table><tr><th>parameter</th><th>value</th></tr>");
        for (n, v) in params {
            let _ = write!(
                o,
                "<tr><td><code>{}</code></td><td>{}</td></tr>",
                escape(n),
                fmt_g(*v)
            );
        }
        o.push_str("</table>\n");
    }
    stats_table(&mut o, &[("configured", r)]);
    components_table(&mut o, r);
    plots(&mut o, &[("configured", r)]);
    let _ = writeln!(
        o,
        "<p><small>autotune {}</small></p></body></html>",
        env!("CARGO_PKG_VERSION")
    );
    o
}

/// The Markdown report of `autotune check`.
pub fn check_markdown(
    experiment: &dyn Experiment,
    params: &[(String, f64)],
    r: &ConsistencyReport,
) -> String {
    let mut o = String::new();
    let name = &experiment.info().name;
    let _ = writeln!(o, "{}", crate::output::mark_comment());
    let _ = writeln!(o, "# autotune check: {name}\n");
    let _ = writeln!(o, "**Verdict: {}**\n", r.verdict.describe());
    let _ = writeln!(o, "```\n{}```", super::summary_text(name, params, r));
    o
}
