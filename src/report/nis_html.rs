//! The HTML report of `autotune nis`.

use crate::fieldlog::NisReport;

/// A self-contained HTML report of a field log.
pub fn nis_html(report: &NisReport) -> String {
    let text = super::nis::nis_summary_text(report);
    format!(
        "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\"><title>autotune nis</title></head><body><pre>{}</pre></body></html>\n",
        super::html::escape(&text)
    )
}
