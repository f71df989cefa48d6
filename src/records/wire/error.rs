//! Why a sums answer is refused.

/// Why a sums answer is refused.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum WireError {
    /// Not base64.
    #[error("'sums' is not base64: {0}")]
    Base64(String),
    /// Not this format, or another version of it.
    #[error("'sums' is not autotune's sums format (version 2): another autotune's worker library?")]
    Magic,
    /// It ended early.
    #[error("'sums' ends early, at byte {0}")]
    Truncated(usize),
    /// Sums after inline records of the same request.
    #[error("'sums' after inline records: answer one or the other")]
    AfterRecords,
    /// Bytes after its end.
    #[error("'sums' has {0} bytes after its end")]
    Trailing(usize),
    /// A size differs from the request's.
    #[error("'sums' {what} is {got}, the request's {want}")]
    Shape {
        /// The size.
        what: &'static str,
        /// The answer's.
        got: usize,
        /// The request's.
        want: usize,
    },
    /// A number no records could give.
    #[error("'sums' {what} is {value}, which no records give")]
    Impossible {
        /// Which sum.
        what: &'static str,
        /// Its value, as shown.
        value: String,
    },
    /// A divergence that does not fit the request.
    #[error(
        "'sums' divergence {0} is malformed (run outside the request, step outside 1..=T, unknown cause or reason not UTF-8)"
    )]
    Divergence(usize),
}
