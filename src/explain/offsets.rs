//! The constant sensor offsets that best make a filter's errors zero-mean.

use nalgebra::{DMatrix, DVector};

use super::first_moments;
use crate::experiment::{Alteration, Experiment};
use crate::montecarlo::McConfig;

/// The offsets, one per measurement component (measurement units, sensor order), that the
/// filter of `experiment` at `theta` should take off its readings for its errors to average
/// zero, or `None` when the experiment cannot take offsets or its filter diverges.
///
/// With common random numbers a linear filter's first-moment sums are exactly affine in the
/// offsets, so `1 + n_z` Monte Carlo evaluations under `mc` (one at zero, one per component
/// at one standard deviation of its noise) give the map, and a least-squares solve (SVD,
/// ignoring directions the sums do not see) gives the offsets. `use_states` includes the
/// state errors' means (with ground truth); without them only the innovations' count, and
/// a bias the filter absorbs into its state (a position offset on a position sensor) is
/// invisible.
pub fn fit_offsets(
    experiment: &dyn Experiment,
    theta: &[f64],
    mc: &McConfig,
    use_states: bool,
) -> Option<Vec<f64>> {
    let m = experiment.measurement_names().len();
    let scale: Vec<f64> = match experiment.covariances(theta) {
        Some(c) if c.R.nrows() == m => (0..m)
            .map(|i| {
                let s = c.R[(i, i)].sqrt();
                if s.is_finite() && s > 0.0 { s } else { 1.0 }
            })
            .collect(),
        _ => vec![1.0; m],
    };
    let sums = |d: Vec<f64>| -> Option<Vec<f64>> {
        let e = experiment.alter(&Alteration::MeasurementOffset(d))?;
        let acc = e.monte_carlo(theta, mc).ok()?;
        (acc.diverged_runs == 0).then(|| first_moments(&acc, use_states))
    };
    let r0 = DVector::from_vec(sums(vec![0.0; m])?);
    let mut jac = DMatrix::zeros(r0.len(), m);
    for i in 0..m {
        let mut d = vec![0.0; m];
        d[i] = scale[i];
        let ri = DVector::from_vec(sums(d)?);
        jac.set_column(i, &(ri - &r0));
    }
    let svd = jac.svd(true, true);
    let tol = 1e-9 * svd.singular_values.max();
    let c = svd.solve(&(-r0), tol).ok()?;
    Some(c.iter().zip(&scale).map(|(c, s)| c * s).collect())
}
