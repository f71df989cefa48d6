//! A tune configured, then run (argmin's executor): the model, the settings validated once
//! ([`TuneSettings`]), where to start and what to hold, then [`Tuner::run`]. What the model
//! already says is the default: its configured values are the start, the parameters it
//! marks fixed stay fixed, and its own Monte Carlo test scores the candidates.

use super::{Observer, TuneError, TuneResult, TuneSettings};
use crate::experiment::Experiment;
use crate::input::SettingError;
use crate::montecarlo::McConfig;

/// One tuning run of a model, configured step by step and then run:
///
/// ```
/// use autotune::prelude::*;
///
/// let p = Problem::load(std::path::Path::new("problems/cv1d.toml")).unwrap();
/// let result = p
///     .tuner(TuneSettings::default())
///     .from(&[5.0, 10.0]) // q_accel ((m/s²)²), r_pos (m²): 10× off
///     .run(&Silent)
///     .unwrap();
/// assert!((result.tuned[0] / 0.5 - 1.0).abs() < 1e-4);
/// ```
#[derive(Clone)]
pub struct Tuner<'a> {
    model: &'a dyn Experiment,
    settings: TuneSettings,
    start: Vec<f64>,
    fixed: Vec<bool>,
    mc: McConfig,
}

impl<'a> Tuner<'a> {
    /// A tune of `model` under `settings`, from the model's configured parameter values,
    /// holding the parameters it marks fixed, scored on its own Monte Carlo test.
    pub fn new(model: &'a dyn Experiment, settings: TuneSettings) -> Tuner<'a> {
        let params = model.params();
        Tuner {
            model,
            settings,
            start: params.values(),
            fixed: params.params.iter().map(|p| p.fixed).collect(),
            mc: *model.mc(),
        }
    }

    /// Start from `start`: one value per parameter, in [`Experiment::params`] order, in
    /// each parameter's own unit. A length that does not match fails at [`Tuner::run`].
    pub fn from(mut self, start: &[f64]) -> Tuner<'a> {
        self.start = start.to_vec();
        self
    }

    /// Hold the parameter called `name` at its start value as well. Fails on a name the
    /// model does not have.
    pub fn fix(mut self, name: &str) -> Result<Tuner<'a>, TuneError> {
        let params = &self.model.params().params;
        match params.iter().position(|p| p.name == name) {
            Some(i) => {
                self.fixed[i] = true;
                Ok(self)
            }
            None => {
                let known: Vec<&str> = params.iter().map(|p| p.name.as_str()).collect();
                Err(SettingError::new(
                    "fix",
                    format!("no parameter {name:?} (the model has {})", known.join(", ")),
                )
                .into())
            }
        }
    }

    /// Score the candidates on `mc` instead of the model's own Monte Carlo test.
    pub fn mc(mut self, mc: &McConfig) -> Tuner<'a> {
        self.mc = *mc;
        self
    }

    /// Which parameters are held, in [`Experiment::params`] order.
    pub fn fixed(&self) -> &[bool] {
        &self.fixed
    }

    /// Run the tune, telling `observer` how it goes. Fails before the search on a start
    /// whose length is not the parameter count, or on settings that do not suit the
    /// model; a search that ends inconsistent is a result ([`TuneResult::status`]), not
    /// an error.
    pub fn run(&self, observer: &dyn Observer) -> Result<TuneResult, TuneError> {
        super::tune(
            self.model,
            &self.start,
            &self.fixed,
            &self.mc,
            &self.settings,
            observer,
        )
    }
}

/// [`Tuner::new`] as a method of every experiment: `model.tuner(settings)`.
pub trait Tunable {
    /// A tune of this model under `settings` ([`Tuner::new`]).
    fn tuner(&self, settings: TuneSettings) -> Tuner<'_>;
}

impl<E: Experiment> Tunable for E {
    fn tuner(&self, settings: TuneSettings) -> Tuner<'_> {
        Tuner::new(self, settings)
    }
}

impl Tunable for dyn Experiment + '_ {
    fn tuner(&self, settings: TuneSettings) -> Tuner<'_> {
        Tuner::new(self, settings)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::tune::Silent;
    use crate::tune::tests::Mock;

    #[test]
    fn a_tuner_starts_where_the_model_is_and_holds_what_it_fixes() {
        let mock = two();
        let t = mock.tuner(TuneSettings::default());
        assert_eq!(t.start, mock.params().values());
        assert_eq!(t.fixed, vec![false, false]);
        assert_eq!(t.mc, *mock.mc());
        let name = mock.params().params[1].name.clone();
        let t = t.fix(&name).unwrap();
        assert_eq!(t.fixed(), &[false, true]);
        let held = two().with_fixed(0);
        assert_eq!(held.tuner(TuneSettings::default()).fixed(), &[true, false]);
        match t.clone().fix("no_such_parameter") {
            Err(TuneError::Setting(e)) => {
                assert_eq!(e.setting, "fix");
                assert!(e.message.contains(&name), "{}", e.message);
            }
            other => panic!("{:?}", other.map(|_| ())),
        }
    }

    fn two() -> Mock {
        Mock::new(&[0.3, 20.0], &[&[4.0, 2.0], &[0.0, 8.0]])
    }

    #[test]
    fn a_tuner_runs_the_tune_it_was_given() {
        let mock = two();
        let start: Vec<f64> = mock.params().values().iter().map(|v| v * 3.0).collect();
        let settings = TuneSettings::default();
        let mc = mock.mc().with_seed(7);
        let name = mock.params().params[0].name.clone();
        let by_tuner = mock
            .tuner(settings.clone())
            .from(&start)
            .mc(&mc)
            .fix(&name)
            .unwrap()
            .run(&Silent)
            .unwrap();
        let mut fixed = vec![false; start.len()];
        fixed[0] = true;
        let direct = super::super::tune(&mock, &start, &fixed, &mc, &settings, &Silent).unwrap();
        assert_eq!(by_tuner.tuned, direct.tuned);
        assert_eq!(by_tuner.tuned[0], start[0]);
        assert_eq!(by_tuner.evaluations, direct.evaluations);
        match mock.tuner(settings).from(&start[1..]).run(&Silent) {
            Err(TuneError::Shape { start, params, .. }) => assert_eq!(start + 1, params),
            other => panic!("{:?}", other.map(|_| ())),
        }
    }
}
