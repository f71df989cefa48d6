//! Rendering: every text, JSON, Markdown, HTML (with SVG plots), JUnit XML and TOML that
//! autotune prints or writes, by command, with the primitives they share. Nothing here runs
//! an experiment; a command's files are written together by `crate::output`.
//!
//! - [`check`]: a consistency check's summary, JUnit, HTML and Markdown pages (the tune
//!   report's statistics reuse them) and the per-parameter advice;
//! - [`tune`]: a tuning run's summary, Markdown and JSON, and the tuned config it writes;
//! - [`nis`]: a field log's summary, Markdown, JUnit and HTML report;
//! - [`estimate`]: estimates of Q and R from recorded measurements, and `simulate`'s output;
//! - [`progress`]: a long check's bar and a tune's progress on stderr;
//! - [`format`](mod@format), [`html`] and `svg`: numbers, HTML escaping and page heads, and the plot
//!   primitives.

pub mod advice;
pub mod check;
pub(crate) mod consistency;
pub mod estimate;
pub mod format;
pub mod html;
pub mod init;
pub mod nis;
pub mod progress;
mod svg;
pub mod tune;
pub mod tuned;

pub use check::{CheckOutput, check_summary, gate_text, junit_xml, summary_text};
pub use consistency::cells::run_spread_note;
pub use format::{fmt_fixed, fmt_g, paint_verdicts};
