//! What every HTML report shares: escaping, the page head with its style sheet, figures.
//! The reports are self-contained: inline SVG plots and tables, no scripts, no network.

use std::fmt::Write;

/// Escape text for HTML and XML.
pub fn escape(s: &str) -> String {
    let mut o = String::with_capacity(s.len());
    for c in s.chars() {
        match c {
            '&' => o.push_str("&amp;"),
            '<' => o.push_str("&lt;"),
            '>' => o.push_str("&gt;"),
            '"' => o.push_str("&quot;"),
            '\'' => o.push_str("&apos;"),
            c => o.push(c),
        }
    }
    o
}

const STYLE: &str = "body{font-family:sans-serif;max-width:1400px;margin:1em auto;padding:0 1em;color:#111}\
table{border-collapse:collapse;margin:.5em 0}td,th{border:1px solid #999;padding:3px 8px;text-align:left}\
th{background:#e6e6e6}.row{display:flex;flex-wrap:wrap;gap:12px}.row figure{margin:0;max-width:640px}\
figcaption{font-size:90%;color:#333}.verdict{font-size:120%;font-weight:bold}\
svg{max-width:100%;height:auto}code{background:#f0f0f0;padding:0 3px}td.num{text-align:right;font-variant-numeric:tabular-nums}tr.off td.v{color:#a00;font-weight:bold}tr.biased td.m{color:#a00;font-weight:bold}.wide{overflow-x:auto}.wide table{font-size:90%}";

pub(crate) fn head(o: &mut String, title: &str) {
    head_styled(o, title, "");
}

/// The document's head with `extra` style rules after the common ones.
pub(crate) fn head_styled(o: &mut String, title: &str, extra: &str) {
    let _ = write!(
        o,
        "<!DOCTYPE html>\n{}\n<html lang=\"en\"><head><meta charset=\"utf-8\"><title>{}</title><style>{STYLE}{extra}</style></head><body>\n",
        crate::output::mark_comment(),
        escape(title)
    );
}

pub(crate) fn figure(o: &mut String, svg: &str, caption: &str) {
    let _ = writeln!(
        o,
        "<figure>{svg}<figcaption>{}</figcaption></figure>",
        escape(caption)
    );
}
