//! `check`'s renderers, which `tune`'s reports share: the human summary, JUnit XML, the HTML
//! and Markdown pages with their plots, and the per-parameter advice.

pub mod html;
mod junit;
pub mod summary;

pub use junit::junit_xml;
pub use summary::{check_summary, gate_text, summary_text};

use serde::Serialize;

use crate::stats::ConsistencyReport;

/// What a `check` run reports, for machines.
#[derive(Debug, Clone, Serialize)]
pub struct CheckOutput<'a> {
    /// Problem name.
    pub problem: &'a str,
    /// Problem file.
    pub file: String,
    /// SHA-256 of the problem file (`null` for a model defined in Rust).
    pub problem_hash: Option<&'a str>,
    /// Base seed.
    pub seed: u64,
    /// Parameter values the filter was run with.
    pub params: Vec<(String, f64)>,
    /// The statistics.
    pub report: &'a ConsistencyReport,
    /// autotune version.
    pub version: &'static str,
}
