//! Hypotheses about why no Q and R fit a linear filter: each a change of the filter's model
//! with parameters of its own, appended to θ, so that the tuner fits them with the noise
//! parameters (issue 38). A hypothesis is a [`Hypothesized`] experiment: the base problem's
//! truth, the filter changed at every θ.
//!
//! | hypothesis | the filter's change | its parameters (neutral value) |
//! | --- | --- | --- |
//! | time step | `F ← F^s`, every Q term rebuilt for the scaled step from its own noise input ([`time`]) | `dt_scale` (1) |
//! | initial covariance | `P0 ← c P0` | `p0_scale` (1) |
//! | sensor gain | `H ← diag(g) H` | `gain_<z>` (1) |
//! | measurement matrix | `H ← G Rot H`: the components rotated into each other pair by pair (a misalignment), then scaled | `gain_<z>` (1), `rot_<i>_<j>` (1: no rotation; the angle in rad is `ln` of it) |
//! | delay of d steps | the measurement reads the state d steps back (lagged copies of the state) | none |
//! | coloured sensor noise | a first-order Gauss–Markov state per component added to the reading | `gm_corr_<z>` (per-step correlation), `gm_var_<z>` (variance; neutral at its lower bound) |
//! | sensor bias | a constant state per component, its prior mean and variance fitted: constant across runs (variance → 0) or drawn per run (mean → 0) | `bias_mean_<z>` (1: the mean is `σ ln` of it), `bias_var_<z>` (lower bound) |
//! | a missing motion state | each process-noise input drives a Gauss–Markov state (Singer; a random walk at a rate near 0) | `singer_rate_<q>` (per step), `singer_drive_<q>` (its driving noise's density; neutral at its lower bound) |
//! | the noise model's kind | each Q term swapped between continuous (CWNA) and piecewise-constant (DWNA) white noise | none |
//! | a full R | correlations between the measurement components | `rho_<i>_<j>` (1: uncorrelated; ρ = tanh of `ln` of it) |
//!
//! Hypotheses that add states are judged, like the others, by the full gate: the NEES is
//! taken on the filter's own states (the map's rows), the added ones having nothing in the
//! truth to compare with.

#![allow(non_snake_case)]

mod build;
mod filter_at;
mod kinds;
mod read;
mod time;

pub use kinds::{Added, Hypothesis};
pub use read::ReadThrough;

use nalgebra::DMatrix;

use super::{
    Block, Covariances, Definition, Experiment, ExperimentError, LinearExperiment, RunOptions,
};
use crate::filter::KalmanFilter;
use crate::montecarlo::{self, Engine, McConfig, SharedTrack, expected_accumulator_tracked};
use crate::params::Target;
use crate::stats::Accumulator;

/// A per-step correlation below which a sensor's Gauss–Markov noise is white.
const WHITE_CORR: f64 = 0.3;
/// A per-step decay rate above which a Gauss–Markov motion state is white.
const WHITE_RATE: f64 = 1.2;

/// A linear problem with its filter changed by a [`Hypothesis`]; its parameters are the
/// base problem's followed by the hypothesis's own.
#[derive(Debug, Clone)]
pub struct Hypothesized {
    base: LinearExperiment,
    hypothesis: Hypothesis,
    definition: Definition,
    /// What the change needs, worked out once.
    prep: build::Prep,
    /// The truth's moments over the test's steps, which no candidate changes: built at the
    /// first exact evaluation, read by every one after it.
    track: SharedTrack,
}

/// A changed experiment a hypothesis trial fits: the base's parameters, then the change's
/// own ([`Changed::added`]).
pub trait Changed: Experiment {
    /// The hypothesis the change is.
    fn hypothesis(&self) -> Hypothesis;

    /// The added parameters, in θ's order after the base's.
    fn added(&self) -> &[Added];

    /// Whether `theta`'s added parameters change nothing.
    fn at_neutral(&self, theta: &[f64]) -> bool;

    /// An added parameter's name and value as a reader reads them (an offset in its
    /// units, an angle in rad), from its name and value in θ.
    fn reading(&self, name: &str, value: f64) -> (String, f64);

    /// The change in a few words.
    fn words(&self) -> String {
        self.hypothesis().words()
    }
}

impl Changed for Hypothesized {
    fn hypothesis(&self) -> Hypothesis {
        Hypothesized::hypothesis(self)
    }

    fn added(&self) -> &[Added] {
        Hypothesized::added(self)
    }

    fn at_neutral(&self, theta: &[f64]) -> bool {
        Hypothesized::at_neutral(self, theta)
    }

    fn reading(&self, name: &str, value: f64) -> (String, f64) {
        Hypothesized::reading(self, name, value)
    }
}

impl Hypothesized {
    /// `hypothesis` on `base`, its added parameters' ranges scaled by the base's noise at
    /// `theta`; `None` when the filter cannot express it (a transition matrix without a
    /// real logarithm, a single measurement component for a mixing, …).
    pub fn new(base: &LinearExperiment, hypothesis: Hypothesis, theta: &[f64]) -> Option<Self> {
        let prep = build::Prep::new(base, hypothesis, theta)?;
        let mut definition = base.definition.clone();
        definition
            .params
            .params
            .extend(prep.added.iter().map(|a| a.def.clone()));
        Some(Hypothesized {
            base: base.clone(),
            hypothesis,
            definition,
            prep,
            track: SharedTrack::default(),
        })
    }

    /// The hypothesis.
    pub fn hypothesis(&self) -> Hypothesis {
        self.hypothesis
    }

    /// The added parameters, in θ's order after the base's.
    pub fn added(&self) -> &[Added] {
        &self.prep.added
    }

    /// How many parameters the base problem has.
    pub fn base_params(&self) -> usize {
        self.base.definition.params.params.len()
    }

    /// Whether `theta`'s added parameters change nothing ([`Added::is_neutral`] for each that
    /// sizes the change); never for a change without parameters (a delay, the other kind
    /// of noise), which is structural.
    pub fn at_neutral(&self, theta: &[f64]) -> bool {
        let own = &theta[self.base_params()..];
        // A Gauss–Markov state that forgets within a step or two is white noise: more R (a
        // sensor's) or more Q (a motion state's), which the noise parameters already are,
        // not a correlated disturbance.
        match self.hypothesis {
            Hypothesis::ColouredNoise => {
                return own
                    .chunks(2)
                    .zip(self.prep.added.chunks(2))
                    .all(|(v, a)| v[0] < WHITE_CORR || a[1].is_neutral(v[1]));
            }
            Hypothesis::MotionState => {
                return own
                    .chunks(2)
                    .zip(self.prep.added.chunks(2))
                    .all(|(v, a)| v[0] > WHITE_RATE || a[1].is_neutral(v[1]));
            }
            _ => {}
        }
        let sized: Vec<(&f64, &Added)> = own
            .iter()
            .zip(&self.prep.added)
            .filter(|(_, a)| a.effect)
            .collect();
        !sized.is_empty() && sized.iter().all(|(v, a)| a.is_neutral(**v))
    }

    /// An added parameter's fitted value as it reads in the model, with the name it reads
    /// under: a bias mean in the measurement's units (`σ ln v`), a rotation's angle in rad
    /// (`ln v`), a correlation coefficient (`tanh ln v`); any other parameter as it is.
    pub fn reading(&self, name: &str, value: f64) -> (String, f64) {
        let names = &self.base.definition.measurement_names;
        if let Some(z) = name.strip_prefix("bias_mean_")
            && let Some(j) = names.iter().position(|n| n == z)
        {
            return (format!("bias_{z} mean"), self.prep.sigma_z[j] * value.ln());
        }
        if let Some(pair) = name.strip_prefix("rot_") {
            return (format!("angle_{pair} (rad)"), value.ln());
        }
        if let Some(pair) = name.strip_prefix("rho_") {
            return (format!("ρ_{pair}"), value.ln().tanh());
        }
        (name.to_string(), value)
    }

    /// The filter and its map at `theta`; `None` when the change gives no valid filter
    /// there (a correlation matrix that is not positive definite).
    fn filter_at(&self, theta: &[f64]) -> Option<(KalmanFilter, Option<DMatrix<f64>>)> {
        let n = self.base_params();
        filter_at::filter(&self.base, &self.prep, &theta[..n], &theta[n..])
    }
}

impl Experiment for Hypothesized {
    fn definition(&self) -> &Definition {
        &self.definition
    }

    fn monte_carlo_with(
        &self,
        theta: &[f64],
        mc: &McConfig,
        run: RunOptions<'_>,
    ) -> Result<Accumulator, ExperimentError> {
        let n_x = self.definition.state_names.len();
        let n_z = self.definition.measurement_names.len();
        let Some((kf, map)) = self.filter_at(theta) else {
            return Ok(montecarlo::all_stopped(
                mc,
                n_x,
                n_z,
                &crate::filter::FilterError::NotPositiveDefinite {
                    which: "R",
                    step: 0,
                },
            ));
        };
        Ok(montecarlo::run_linear_with(
            &self.base.truth,
            &kf,
            map.as_ref(),
            mc,
            run,
        ))
    }
}

impl crate::experiment::Structure for Hypothesized {
    fn supports(&self, engine: Engine) -> bool {
        engine != Engine::Generic
    }

    fn expected(&self, theta: &[f64], mc: &McConfig) -> Option<Accumulator> {
        let n_x = self.definition.state_names.len();
        let n_z = self.definition.measurement_names.len();
        let stopped = |e: &crate::filter::FilterError| montecarlo::all_stopped(mc, n_x, n_z, e);
        Some(match self.filter_at(theta) {
            Some((kf, map)) => {
                let truth = &self.base.truth;
                let track = self.track.get(truth, &kf, map.as_ref(), mc.steps());
                expected_accumulator_tracked(truth, &kf, map.as_ref(), mc, Some(&track))
                    .unwrap_or_else(|e| stopped(&e))
            }
            None => stopped(&crate::filter::FilterError::NotPositiveDefinite {
                which: "R",
                step: 0,
            }),
        })
    }

    fn target(&self, i: usize) -> Option<Target> {
        (i < self.base_params())
            .then(|| self.base.target(i))
            .flatten()
    }

    fn covariances(&self, theta: &[f64]) -> Option<Covariances> {
        self.base.covariances(&theta[..self.base_params()])
    }

    /// The base's decoupled blocks, each added parameter in the block of what it changes:
    /// a measurement component's (a gain, a sensor state), a process-noise parameter's (a
    /// motion state). A change that couples everything (the time step, P0, a mixing, a
    /// full R) leaves no blocks.
    fn blocks(&self) -> Option<Vec<Block>> {
        let mut blocks = self.base.blocks()?;
        let n = self.base_params();
        let names = &self.base.definition.measurement_names;
        let params = &self.base.definition.params.params;
        for (k, a) in self.prep.added.iter().enumerate() {
            let name = &a.def.name;
            let of_z = |z: &String| {
                ["gain_", "gm_corr_", "gm_var_", "bias_mean_", "bias_var_"]
                    .iter()
                    .any(|p| name.strip_prefix(p) == Some(z.as_str()))
            };
            let block = if let Some(j) = names.iter().position(of_z) {
                blocks.iter().position(|b| b.measurements.contains(&j))
            } else if let Some(i) = params.iter().position(|p| {
                ["singer_rate_", "singer_drive_"]
                    .iter()
                    .any(|s| name.strip_prefix(s) == Some(p.name.as_str()))
            }) {
                blocks.iter().position(|b| b.params.contains(&i))
            } else {
                None
            };
            blocks[block?].params.push(n + k);
        }
        Some(blocks)
    }
}

impl crate::experiment::HeldAsCode for Hypothesized {}

impl crate::experiment::Sampling for Hypothesized {}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_hypothesis_changes_the_part_of_the_filter_it_names() {
        let base = crate::experiment::cv1d_for_tests().build().unwrap();
        let h = Hypothesized::new(&base, Hypothesis::InitialCovariance, &[0.5, 1.0]).unwrap();
        assert_eq!(h.params().names(), ["q", "r", "p0_scale"]);
        let (kf, map) = h.filter_at(&[0.5, 1.0, 3.0]).unwrap();
        let plain = base.filter_at(&[0.5, 1.0]);
        assert_eq!(kf.P0, plain.P0 * 3.0);
        assert_eq!((kf.F, kf.Q, kf.R), (plain.F, plain.Q, plain.R));
        assert!(map.is_none());
    }
}
