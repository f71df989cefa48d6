//! Output: the human summary, JSON, JUnit XML, and tuned configs; a command's files are
//! checked before its work and written together, atomically (see [`Outputs`]).

pub mod advice;
pub mod html;
mod junit;
pub mod nis;
pub mod nis_html;
mod nis_plots;
pub mod plots;
mod summary;
pub mod tune;
pub mod tuned;
mod write;

pub use junit::junit_xml;
pub use summary::{fmt_fixed, fmt_g, gate_text, run_spread_note, summary_text};
pub use write::{
    Outputs, REPORT_FILES, WriteError, check_output_file, check_report_dir, remove_temporary_files,
    write_file,
};

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
