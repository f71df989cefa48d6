//! A Rust user's own truth model and filter family as an [`Experiment`].

use super::described::{Described, check_name, description_setters, param_space};
use super::held::Held;
use super::{Covariances, Definition, Experiment, ExperimentError, RunOptions};
use crate::filter::Filter;
use crate::input::SettingError;
use crate::model::TruthModel;
use crate::montecarlo::{McConfig, TruthCache};
use crate::params::{ParamDef, Target};
use crate::stats::Accumulator;

/// Q and R of the filter at θ, for reports and tuned configs.
type CovarianceFn = Box<dyn Fn(&[f64]) -> Covariances + Send + Sync>;

/// A truth model `T` and a filter builder `B: θ ↦ filter`, with named parameters that each
/// drive known components. Built by [`RustModel::builder`], which checks everything once;
/// `check`, `tune`, the reports, the advice and [`crate::app::main`] then treat it as they
/// treat a problem file.
///
/// ```
/// use autotune::{RustModel, Experiment};
/// use autotune::LinearGaussian;
/// use autotune::LinearGaussianModel;
/// use autotune::McConfig;
/// use autotune::{ParamDef, Target, dwna_block};
/// use nalgebra::{DMatrix, DVector};
///
/// let f = DMatrix::from_row_slice(2, 2, &[1.0, 1.0, 0.0, 1.0]);
/// let h = DMatrix::from_row_slice(1, 2, &[1.0, 0.0]);
/// let (x0, p0) = (DVector::zeros(2), DMatrix::identity(2, 2));
/// let truth = LinearGaussianModel::new(
///     f.clone(), h.clone(), dwna_block(1.0) * 0.5, DMatrix::from_element(1, 1, 1.0),
///     x0.clone(), p0.clone(),
/// ).unwrap();
/// let filter = move |theta: &[f64]| LinearGaussian {
///     F: f.clone(), H: h.clone(),
///     Q: dwna_block(1.0) * theta[0], R: DMatrix::from_element(1, 1, theta[1]),
///     x0: x0.clone(), P0: p0.clone(),
/// };
/// let model = RustModel::builder("cv1d_rust", truth, filter)
///     .states(["x", "vx"])
///     .measurements(["x"])
///     .param(ParamDef::new("q_accel", 0.5).unit("(m/s²)²"), Target::process(&[0, 1]))
///     .param(ParamDef::new("r_pos", 1.0).unit("m²"), Target::measurement(&[0]))
///     .montecarlo(McConfig::new(50, 100).unwrap())
///     .build()
///     .unwrap();
/// let report = autotune::check(&model, &[0.5, 1.0], model.mc(), autotune::Truth::Known).unwrap();
/// assert_eq!(report.nees.unwrap().target, 2.0);
/// ```
pub struct RustModel<T, B> {
    definition: Definition,
    truth: T,
    build: B,
    targets: Vec<Target>,
    covariances: Option<CovarianceFn>,
    truth_values: Option<Vec<f64>>,
    /// The truth does not depend on θ (the builder makes the filter only).
    truth_cache: TruthCache,
    /// The builder again, boxed, where the model is replayable.
    replay: Option<ReplayFn>,
}

/// A filter builder `θ ↦ filter` behind a box, so that the filter can be run over a
/// recording ([`HeldAsCode::replay_filter`]).
type ReplayFn = Box<dyn Fn(&[f64]) -> Box<dyn Filter> + Send + Sync>;

/// Collects a [`RustModel`] experiment's parts; [`RustModelBuilder::build`] checks them.
pub struct RustModelBuilder<T, B> {
    described: Described,
    truth: T,
    build: B,
    params: Vec<(ParamDef, Target)>,
    covariances: Option<CovarianceFn>,
    truth_values: Option<Vec<f64>>,
    replay: Option<ReplayFn>,
}

impl<T, F, B> RustModel<T, B>
where
    T: TruthModel,
    F: Filter,
    B: Fn(&[f64]) -> F + Sync,
{
    /// Start an experiment called `name` (used for output names: letters, digits, `_`, `-`)
    /// from a truth model and a filter builder `θ ↦ filter` (θ in the order the parameters
    /// are added).
    pub fn builder(name: &str, truth: T, build: B) -> RustModelBuilder<T, B> {
        RustModelBuilder {
            described: Described::new(name),
            truth,
            build,
            params: Vec::new(),
            covariances: None,
            truth_values: None,
            replay: None,
        }
    }

    /// The truth and its runs' cache, as the filters held as code share them.
    fn held(&self) -> Held<'_, T> {
        Held {
            truth: &self.truth,
            cache: &self.truth_cache,
        }
    }
}

impl<T, F, B> RustModelBuilder<T, B>
where
    T: TruthModel,
    F: Filter,
    B: Fn(&[f64]) -> F + Sync,
{
    /// Let the filter run over a recording as well as over the truth's runs (the library's
    /// `estimate::FilterReplay`: maximum likelihood on its innovations, judging and tuning it
    /// on the recording). The builder is kept a second time behind a box, which needs a
    /// filter that owns its data (`F: 'static`) and a builder that can be cloned.
    pub fn replayable(mut self) -> Self
    where
        B: Clone + Send + 'static,
        F: 'static,
    {
        let build = self.build.clone();
        self.replay = Some(Box::new(move |theta: &[f64]| -> Box<dyn Filter> {
            Box::new(build(theta))
        }));
        self
    }

    description_setters!();

    /// Add a parameter and what it drives; θ follows the order of these calls.
    pub fn param(mut self, def: ParamDef, target: Target) -> Self {
        self.params.push((def, target));
        self
    }

    /// Q (n_x × n_x) and R (n_z × n_z) at θ, written into tuned configs and reports.
    pub fn covariances(
        mut self,
        f: impl Fn(&[f64]) -> Covariances + Send + Sync + 'static,
    ) -> Self {
        self.covariances = Some(Box::new(f));
        self
    }

    /// The parameter values equal to the truth's noise, where known (tests compare with them).
    pub fn truth_values(mut self, values: Vec<f64>) -> Self {
        self.truth_values = Some(values);
        self
    }

    /// Check every part and build the experiment. Errors name the setting (`name`,
    /// `params.q_accel.lower`, `states`, `params.r_pos.target`, …).
    pub fn build(self) -> Result<RustModel<T, B>, SettingError> {
        check_name(&self.described.name)?;
        let (defs, targets): (Vec<ParamDef>, Vec<Target>) = self.params.into_iter().unzip();
        let params = param_space(defs)?;
        let filter = (self.build)(&params.values());
        let n_x = filter.n_x();
        let n_z: usize = filter.sensor_dims().iter().sum();
        for (def, t) in params.params.iter().zip(&targets) {
            let n = match t.kind {
                crate::params::NoiseKind::Process => n_x,
                crate::params::NoiseKind::Measurement => n_z,
            };
            if let Some(&j) = t.components.iter().find(|&&j| j >= n) {
                return Err(SettingError::new(
                    format!("params.{}.target", def.name),
                    format!("component {j} is out of range (there are {n})"),
                ));
            }
        }
        if let Some(v) = &self.truth_values
            && v.len() != params.params.len()
        {
            return Err(SettingError::new(
                "truth_values",
                format!("{} values for {} parameters", v.len(), params.params.len()),
            ));
        }
        let definition = self.described.definition(params, n_x, n_z)?;
        Ok(RustModel {
            definition,
            truth: self.truth,
            build: self.build,
            targets,
            covariances: self.covariances,
            truth_values: self.truth_values,
            truth_cache: TruthCache::default(),
            replay: self.replay,
        })
    }
}

impl<T, F, B> Experiment for RustModel<T, B>
where
    T: TruthModel,
    F: Filter,
    B: Fn(&[f64]) -> F + Sync,
{
    fn definition(&self) -> &Definition {
        &self.definition
    }

    fn monte_carlo_with(
        &self,
        theta: &[f64],
        mc: &McConfig,
        run: RunOptions<'_>,
    ) -> Result<Accumulator, ExperimentError> {
        self.held().monte_carlo(&(self.build)(theta), mc, run)
    }
}

impl<T, F, B> crate::experiment::Structure for RustModel<T, B>
where
    T: TruthModel,
    F: Filter,
    B: Fn(&[f64]) -> F + Sync,
{
    fn target(&self, i: usize) -> Option<Target> {
        self.targets.get(i).cloned()
    }

    fn covariances(&self, theta: &[f64]) -> Option<Covariances> {
        self.covariances.as_ref().map(|f| f(theta))
    }

    fn truth_values(&self) -> Option<Vec<f64>> {
        self.truth_values.clone()
    }
}

impl<T, F, B> crate::experiment::HeldAsCode for RustModel<T, B>
where
    T: TruthModel,
    F: Filter,
    B: Fn(&[f64]) -> F + Sync,
{
    fn monte_carlo_corrected(
        &self,
        theta: &[f64],
        mc: &McConfig,
        run: RunOptions<'_>,
        correction: &crate::filter::Correction,
    ) -> Option<Result<Accumulator, ExperimentError>> {
        self.held()
            .corrected(&(self.build)(theta), mc, run, correction)
    }

    fn innovation_scales(&self, theta: &[f64], mc: &McConfig) -> Option<Vec<f64>> {
        self.held().innovation_scales(&(self.build)(theta), mc)
    }

    /// Where the model was made [`RustModelBuilder::replayable`].
    fn replay_filter(&self, theta: &[f64]) -> Option<Box<dyn Filter + '_>> {
        self.replay
            .as_ref()
            .map(|build| -> Box<dyn Filter + '_> { build(theta) })
    }

    fn simulation_truth(&self) -> Option<&dyn TruthModel> {
        Some(&self.truth)
    }
}

impl<T, F, B> crate::experiment::Sampling for RustModel<T, B>
where
    T: TruthModel,
    F: Filter,
    B: Fn(&[f64]) -> F + Sync,
{
    // Every evaluation runs the generic engine.
    fn splits_runs(&self) -> bool {
        true
    }

    fn truth_reuse(&self, since: crate::montecarlo::TapeUsage) -> super::TruthReuse {
        self.held().truth_reuse(since)
    }

    fn tape_usage(&self) -> crate::montecarlo::TapeUsage {
        self.held().tape_usage()
    }
}
