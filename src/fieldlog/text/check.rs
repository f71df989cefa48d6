//! The checks a row of either text format passes: a sensor's name and a symmetric S. A file
//! of their own because the CSV columns and the JSON Lines rows both apply them.

use crate::records::shown_up_to;

/// Why a sensor name is refused.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub(in crate::fieldlog) enum SensorNameError {
    #[error("empty sensor name")]
    Empty,
    /// Too long or with control characters (the name, as an error quotes it).
    #[error("'{0}' is not a sensor name (at most 64 printable characters)")]
    Invalid(String),
}

pub(in crate::fieldlog) fn check_sensor(name: &str) -> Result<(), SensorNameError> {
    if name.is_empty() {
        return Err(SensorNameError::Empty);
    }
    if name.len() > 64 || name.chars().any(char::is_control) {
        return Err(SensorNameError::Invalid(shown_up_to(name, 24)));
    }
    Ok(())
}

/// `Err((i, j))` (1-based) where S is not symmetric to a relative 1e-9.
pub(in crate::fieldlog) fn symmetric(s: &[f64], m: usize) -> Result<(), (usize, usize)> {
    for i in 0..m {
        for j in 0..i {
            let (a, b) = (s[i * m + j], s[j * m + i]);
            if (a - b).abs() > 1e-9 * a.abs().max(b.abs()) {
                return Err((i + 1, j + 1));
            }
        }
    }
    Ok(())
}
