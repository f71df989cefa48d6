//! Variants of a linear experiment that a misfit explanation tries (see
//! [`super::Alteration`]): the filter's time step made a parameter, and constant offsets
//! taken off the sensors' readings.

#![allow(non_snake_case)]

use nalgebra::{DMatrix, DVector};

use super::{
    Alteration, Covariances, Definition, Experiment, ExperimentError, LinearExperiment, RunOptions,
};
use crate::linalg::{expm, logm};
use crate::model::LinearGaussianModel;
use crate::montecarlo::{Engine, McConfig};
use crate::params::{ParamDef, Target};
use crate::stats::Accumulator;

/// Name of the time-scale parameter a [`TimeScaled`] experiment appends.
pub const DT_SCALE: &str = "dt_scale";

/// How far a time-scale trial searches: a filter built for a tenth of the truth's step, or
/// ten times it, is as far as a designer's slip plausibly goes.
const DT_SCALE_RANGE: f64 = 10.0;

impl LinearExperiment {
    /// The experiment under `change`, or `None` when this filter cannot express it (a
    /// transition matrix without a real logarithm cannot be rescaled in time).
    pub(super) fn altered(&self, change: &Alteration) -> Option<Box<dyn Experiment>> {
        match change {
            Alteration::TimeScale => {
                let log_f = logm(&self.filter.F)?;
                let mut definition = self.definition.clone();
                definition.params.params.push(
                    ParamDef::new(DT_SCALE, 1.0)
                        .bounds(1.0 / DT_SCALE_RANGE, DT_SCALE_RANGE)
                        .about("the filter's time step over the configured one (F ← F^s)"),
                );
                Some(Box::new(TimeScaled {
                    base: self.clone(),
                    log_f,
                    definition,
                }))
            }
            Alteration::MeasurementOffset(d) => (d.len() == self.truth.n_z())
                .then(|| self.offset(d))
                .flatten(),
        }
    }

    /// The filter reading `z − d`. The engines simulate the truth and feed the filter its
    /// measurements, so the offset goes into the simulated readings: the truth gains one
    /// constant state (1, known exactly) that enters the measurement through `−d`, and the
    /// filter's map ignores it. The NEES is taken on the same states as before.
    fn offset(&self, d: &[f64]) -> Option<Box<dyn Experiment>> {
        let t = &self.truth;
        let (n, m) = (t.F.nrows(), t.n_z());
        let grow = |a: &DMatrix<f64>, corner: f64| {
            let mut b = DMatrix::zeros(n + 1, n + 1);
            b.view_mut((0, 0), (n, n)).copy_from(a);
            b[(n, n)] = corner;
            b
        };
        let mut H = DMatrix::zeros(m, n + 1);
        H.view_mut((0, 0), (m, n)).copy_from(&t.H);
        for (i, di) in d.iter().enumerate() {
            H[(i, n)] = -di;
        }
        let x0 = DVector::from_fn(n + 1, |i, _| if i < n { t.x0[i] } else { 1.0 });
        let truth = LinearGaussianModel::new(
            grow(&t.F, 1.0),
            H,
            grow(&t.Q, 0.0),
            t.R.clone(),
            x0,
            grow(&t.P0, 0.0),
        )
        .ok()?;
        let map = self
            .filter
            .map
            .clone()
            .unwrap_or_else(|| DMatrix::identity(n, n));
        let mut wide = DMatrix::zeros(map.nrows(), n + 1);
        wide.view_mut((0, 0), (map.nrows(), n)).copy_from(&map);
        let mut filter = self.filter.clone();
        filter.map = Some(wide);
        Some(Box::new(LinearExperiment {
            definition: self.definition.clone(),
            truth,
            filter,
        }))
    }
}

/// A linear experiment whose filter's time step is one more parameter, [`DT_SCALE`]
/// (dimensionless, last in θ): the filter predicts with `F^s = e^{s log F}`, the transition
/// over `s` times the step its F was built for. Q and R keep their terms.
#[derive(Debug, Clone)]
pub struct TimeScaled {
    base: LinearExperiment,
    log_f: DMatrix<f64>,
    definition: Definition,
}

impl TimeScaled {
    /// The base experiment with its filter's F rescaled by `theta`'s last value, and the
    /// base's own parameters.
    fn at<'t>(&self, theta: &'t [f64]) -> (LinearExperiment, &'t [f64]) {
        let (own, s) = theta.split_at(theta.len() - 1);
        let mut e = self.base.clone();
        e.filter.F = expm(&(&self.log_f * s[0]));
        (e, own)
    }
}

impl Experiment for TimeScaled {
    fn definition(&self) -> &Definition {
        &self.definition
    }

    fn truth_reuse(&self, since: crate::montecarlo::TapeUsage) -> super::TruthReuse {
        self.base.truth_reuse(since)
    }

    fn tape_usage(&self) -> crate::montecarlo::TapeUsage {
        self.base.tape_usage()
    }

    fn monte_carlo_with(
        &self,
        theta: &[f64],
        mc: &McConfig,
        options: RunOptions<'_>,
    ) -> Result<Accumulator, ExperimentError> {
        let (e, own) = self.at(theta);
        e.monte_carlo_with(own, mc, options)
    }

    fn supports(&self, engine: Engine) -> bool {
        self.base.supports(engine)
    }

    fn target(&self, i: usize) -> Option<Target> {
        (i + 1 < self.definition.params.params.len())
            .then(|| self.base.target(i))
            .flatten()
    }

    fn covariances(&self, theta: &[f64]) -> Option<Covariances> {
        self.base.covariances(&theta[..theta.len() - 1])
    }
}
