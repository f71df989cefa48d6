//! What a sensor reports at one step: the type shared by truth models, which produce
//! measurements, and filters, which consume them.

use nalgebra::DVector;

/// One sensor's measurement at one step.
#[derive(Debug, Clone, PartialEq)]
pub struct Measurement {
    /// Index of the sensor that produced it, into the filter's sensor list.
    pub sensor: usize,
    /// Measured values, in the sensor's units; its length is that sensor's dimension.
    pub z: DVector<f64>,
}

/// Offsets of each sensor's first component in the concatenated measurement components
/// (all sensors' components in sensor order), from the sensors' dimensions.
pub fn sensor_offsets(dims: &[usize]) -> Vec<usize> {
    let mut off = Vec::with_capacity(dims.len());
    let mut acc = 0;
    for d in dims {
        off.push(acc);
        acc += d;
    }
    off
}
