//! A filter that reads its measurements corrected for each component's offset and gain:
//! the change a sensor-side hypothesis makes to a filter held as code, which autotune can
//! make because it feeds the filter its readings.

use nalgebra::DVector;

use super::{Estimate, Filter, FilterError, Innovation, PredictResult, UpdateResult};
use crate::measurement::{Measurement, sensor_offsets};

/// What the filter reads instead of each measurement component z: `(z − offset) / gain`.
#[derive(Debug, Clone, PartialEq)]
pub struct Correction {
    /// Offset b per measurement component (all sensors' components in sensor order), in
    /// the component's units.
    pub offset: Vec<f64>,
    /// Gain g per measurement component, dimensionless, positive.
    pub gain: Vec<f64>,
}

impl Correction {
    /// No correction of `n_z` components: offsets 0, gains 1.
    pub fn none(n_z: usize) -> Self {
        Correction {
            offset: vec![0.0; n_z],
            gain: vec![1.0; n_z],
        }
    }
}

/// `inner` reading every measurement through a [`Correction`].
pub struct Corrected<'a, F: ?Sized> {
    inner: &'a F,
    correction: &'a Correction,
    /// Each sensor's first component in the correction's vectors.
    starts: Vec<usize>,
}

impl<'a, F: Filter + ?Sized> Corrected<'a, F> {
    /// `inner` reading through `correction`, which must have one offset and one gain per
    /// measurement component of `inner`'s sensors (`None` otherwise).
    pub fn new(inner: &'a F, correction: &'a Correction) -> Option<Self> {
        let dims = inner.sensor_dims();
        let n_z: usize = dims.iter().sum();
        (correction.offset.len() == n_z && correction.gain.len() == n_z).then(|| Corrected {
            inner,
            correction,
            starts: sensor_offsets(&dims),
        })
    }

    /// `meas` as the filter reads it. A sensor the filter does not have, or components past
    /// its dimension, are passed as they are: the engine refuses such a measurement before
    /// any filter reads it.
    fn read(&self, meas: &Measurement) -> Measurement {
        let Some(&s) = self.starts.get(meas.sensor) else {
            return meas.clone();
        };
        let c = self.correction;
        let z = DVector::from_iterator(
            meas.z.len(),
            meas.z.iter().enumerate().map(|(j, &z)| {
                match (c.offset.get(s + j), c.gain.get(s + j)) {
                    (Some(b), Some(g)) => (z - b) / g,
                    _ => z,
                }
            }),
        );
        Measurement {
            sensor: meas.sensor,
            z,
        }
    }
}

impl<F: Filter + ?Sized> Filter for Corrected<'_, F> {
    fn n_x(&self) -> usize {
        self.inner.n_x()
    }

    fn sensor_dims(&self) -> Vec<usize> {
        self.inner.sensor_dims()
    }

    fn initial(&self) -> Estimate {
        self.inner.initial()
    }

    fn predict(&self, k: usize, est: &mut Estimate) -> PredictResult {
        self.inner.predict(k, est)
    }

    fn predict_with_input(&self, k: usize, est: &mut Estimate, u: &DVector<f64>) -> PredictResult {
        self.inner.predict_with_input(k, est, u)
    }

    fn update(&self, k: usize, est: &mut Estimate, meas: &Measurement) -> UpdateResult {
        self.inner.update(k, est, &self.read(meas))
    }

    fn state_error(&self, truth: &DVector<f64>, estimate: &DVector<f64>) -> DVector<f64> {
        self.inner.state_error(truth, estimate)
    }

    fn update_into(
        &self,
        k: usize,
        est: &mut Estimate,
        meas: &Measurement,
        out: &mut Innovation,
    ) -> Result<(), FilterError> {
        self.inner.update_into(k, est, &self.read(meas), out)
    }

    fn state_error_into(
        &self,
        truth: &DVector<f64>,
        estimate: &DVector<f64>,
        out: &mut DVector<f64>,
    ) {
        self.inner.state_error_into(truth, estimate, out);
    }
}

#[cfg(test)]
mod tests {
    use nalgebra::{DMatrix, dvector};

    use super::*;
    use crate::filter::KalmanFilter;

    #[test]
    fn the_filter_reads_each_component_less_its_offset_over_its_gain() {
        // A static 2-state filter seeing both states: its innovation is what it read less
        // its prediction (0), so it shows the corrected reading exactly.
        let kf = KalmanFilter {
            F: DMatrix::identity(2, 2),
            H: DMatrix::identity(2, 2),
            Q: DMatrix::zeros(2, 2),
            R: DMatrix::identity(2, 2),
            x0: DVector::zeros(2),
            P0: DMatrix::identity(2, 2),
        };
        let c = Correction {
            offset: vec![1.5, -2.0],
            gain: vec![2.0, 0.5],
        };
        let f = Corrected::new(&kf, &c).unwrap();
        assert_eq!(f.sensor_dims(), vec![2]);
        let mut est = f.initial();
        let m = Measurement {
            sensor: 0,
            z: dvector![5.5, 1.0],
        };
        let i = f.update(1, &mut est, &m).unwrap();
        assert_eq!(i.nu, dvector![2.0, 6.0]);
        let mut est2 = f.initial();
        let mut out = Innovation::empty();
        f.update_into(1, &mut est2, &m, &mut out).unwrap();
        assert_eq!(out.nu, i.nu);
        assert_eq!(est2.x, est.x);
        // No correction reads the measurement as it is.
        let none = Correction::none(2);
        let g = Corrected::new(&kf, &none).unwrap();
        let mut est3 = g.initial();
        assert_eq!(g.update(1, &mut est3, &m).unwrap().nu, m.z);
        // One value per component, or none.
        assert!(Corrected::new(&kf, &Correction::none(3)).is_none());
    }
}
