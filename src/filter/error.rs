//! Why a filter could not continue ([`FilterError`]), and the bound on a covariance's
//! condition number its message names (`filter::conditioning` explains the bound).

use crate::measurement::Measurement;

/// Largest Jacobi-scaled condition number of a covariance the engine inverts: the NEES and
/// NIS keep about 4 of their 16 digits there (see the module documentation).
pub const MAX_CONDITION: f64 = 1e12;

/// The condition number in words, for an [`FilterError::IllConditioned`] message.
pub fn describe(condition: f64) -> String {
    if condition.is_finite() {
        format!("condition number {condition:.1e}, above {MAX_CONDITION:.0e}")
    } else {
        "numerically singular".to_string()
    }
}

/// Why a filter could not continue.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum FilterError {
    /// A covariance that must be positive definite is not.
    #[error("{which} is not positive definite at step {step}")]
    NotPositiveDefinite {
        /// "S" (innovation covariance) or "P" (state covariance).
        which: &'static str,
        /// Time step.
        step: usize,
    },
    /// A covariance the filter or the engine inverts is too ill-conditioned for the result
    /// to mean anything: its Jacobi-scaled condition number exceeds
    /// [`MAX_CONDITION`] (see `conditioning`).
    #[error("{which} is ill-conditioned at step {step} ({}): its inverse keeps fewer than 4 significant digits", describe(*condition))]
    IllConditioned {
        /// "P⁻" (predicted covariance), "S" (innovation covariance) or "P" (state
        /// covariance).
        which: &'static str,
        /// Time step.
        step: usize,
        /// Its Jacobi-scaled condition number (infinite when numerically singular: no
        /// Cholesky factor, or entries that overflowed).
        condition: f64,
    },
    /// The filter needs something its model does not provide.
    #[error("the model does not provide {what}")]
    Unsupported {
        /// What is missing.
        what: &'static str,
    },
    /// A measurement from a sensor the filter does not know, or of the wrong dimension.
    #[error("measurement from sensor {sensor} has dimension {got}, expected {expected}")]
    BadMeasurement {
        /// Sensor index.
        sensor: usize,
        /// Its dimension.
        got: usize,
        /// The sensor's dimension (0 if unknown).
        expected: usize,
    },
}

/// Check that `meas` has the dimension `expected` of its sensor (`None`: the filter has no
/// such sensor); otherwise the [`FilterError::BadMeasurement`] naming both.
pub fn check_measurement(expected: Option<usize>, meas: &Measurement) -> Result<(), FilterError> {
    match expected {
        Some(d) if d == meas.z.len() => Ok(()),
        _ => Err(FilterError::BadMeasurement {
            sensor: meas.sensor,
            got: meas.z.len(),
            expected: expected.unwrap_or(0),
        }),
    }
}
