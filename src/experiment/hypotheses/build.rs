//! Each hypothesis's added parameters, and the filter it gives at θ.

use nalgebra::DVector;

use super::kinds::{Added, Hypothesis};
use super::time::{Input, Steps};
use crate::experiment::LinearExperiment;
use crate::linalg::logm;
use crate::params::{Coef, ParamDef};

/// What a hypothesis needs, worked out once: its added parameters, the names of the
/// states it adds, and per Q term its noise input.
#[derive(Debug, Clone)]
pub(super) struct Prep {
    pub(super) hypothesis: Hypothesis,
    pub(super) added: Vec<Added>,
    pub(super) state_names: Vec<String>,
    pub(super) steps: Option<Steps>,
    /// Per Q term, its noise input (time step, kind, motion state).
    pub(super) inputs: Vec<Input>,
    /// Motion state: the base parameters whose Q terms drive a Gauss–Markov state, and the
    /// direction each drives.
    pub(super) driven: Vec<(usize, DVector<f64>)>,
    /// Measurement component standard deviations at the base θ (scales of the bias mean).
    pub(super) sigma_z: Vec<f64>,
    /// Steps of the base problem's runs (a slow motion state's initial variance).
    pub(super) horizon: f64,
}

/// `name` with bounds and a neutral value: a factor (neutral within 2%) that sizes the
/// change.
pub(super) fn added(
    name: String,
    neutral: f64,
    lower: f64,
    upper: f64,
    start: f64,
    about: &str,
) -> Added {
    let mut def = ParamDef::new(&name, start)
        .bounds(lower, upper)
        .about(about);
    def.value = start;
    Added {
        def,
        neutral,
        negligible: None,
        effect: true,
    }
}

/// A variance that sizes a change, negligible below `negligible`.
fn variance(
    name: String,
    lower: f64,
    upper: f64,
    start: f64,
    negligible: f64,
    about: &str,
) -> Added {
    Added {
        negligible: Some(negligible),
        ..added(name, lower, lower, upper, start, about)
    }
}

/// A parameter that shapes a change another one sizes (a rate, a correlation).
fn shape(name: String, lower: f64, upper: f64, start: f64, about: &str) -> Added {
    Added {
        effect: false,
        ..added(name, start, lower, upper, start, about)
    }
}

impl Prep {
    pub(super) fn new(base: &LinearExperiment, h: Hypothesis, theta: &[f64]) -> Option<Self> {
        let kf = base.filter_at(theta);
        let (n, m) = (kf.F.nrows(), kf.H.nrows());
        let names = &base.definition.measurement_names;
        let r_diag: Vec<f64> = (0..m)
            .map(|j| kf.R[(j, j)].max(f64::MIN_POSITIVE))
            .collect();
        let needs_steps = matches!(
            h,
            Hypothesis::TimeStep | Hypothesis::NoiseKind | Hypothesis::MotionState
        );
        let steps = if needs_steps {
            Some(Steps::new(logm(&kf.F)?))
        } else {
            None
        };
        let inputs: Vec<Input> = match &steps {
            Some(s) => base
                .filter
                .q
                .terms
                .iter()
                .map(|t| s.input(&t.basis))
                .collect(),
            None => Vec::new(),
        };
        let mut prep = Prep {
            hypothesis: h,
            added: Vec::new(),
            state_names: Vec::new(),
            steps,
            inputs,
            driven: Vec::new(),
            sigma_z: r_diag.iter().map(|r| r.sqrt()).collect(),
            horizon: base.definition.mc.steps() as f64,
        };
        match h {
            Hypothesis::TimeStep => prep.added.push(added(
                "dt_scale".into(),
                1.0,
                0.1,
                10.0,
                1.0,
                "the filter's step over the configured one (F and Q rebuilt)",
            )),
            Hypothesis::InitialCovariance => prep.added.push(added(
                "p0_scale".into(),
                1.0,
                1e-4,
                1e4,
                1.0,
                "the filter's P0 over the configured one",
            )),
            Hypothesis::SensorGain | Hypothesis::MeasurementMatrix => {
                if h == Hypothesis::MeasurementMatrix && m < 2 {
                    return None;
                }
                for z in names {
                    prep.added.push(added(
                        format!("gain_{z}"),
                        1.0,
                        0.2,
                        5.0,
                        1.0,
                        "a gain on H's row",
                    ));
                }
                if h == Hypothesis::MeasurementMatrix {
                    for i in 0..m {
                        for j in i + 1..m {
                            prep.added.push(added(
                                format!("rot_{}_{}", names[i], names[j]),
                                1.0,
                                (-0.5f64).exp(),
                                0.5f64.exp(),
                                1.0,
                                "the rotation between components i and j, rad (ln of it)",
                            ));
                        }
                    }
                }
            }
            Hypothesis::Delay(d) => {
                if d == 0 {
                    return None;
                }
                for lag in 1..=d {
                    for s in &base.definition.state_names {
                        prep.state_names.push(format!("{s}_lag{lag}"));
                    }
                }
            }
            Hypothesis::ColouredNoise => {
                for (z, r) in names.iter().zip(&r_diag) {
                    prep.added.push(shape(
                        format!("gm_corr_{z}"),
                        1e-3,
                        0.999,
                        0.5,
                        "per-step correlation of the sensor noise",
                    ));
                    prep.added.push(variance(
                        format!("gm_var_{z}"),
                        r * 1e-6,
                        r * 1e3,
                        r * 0.1,
                        r * 1e-2,
                        "variance of the correlated part",
                    ));
                    prep.state_names.push(format!("gm_{z}"));
                }
            }
            Hypothesis::SensorBias => {
                for (z, r) in names.iter().zip(&r_diag) {
                    prep.added.push(added(
                        format!("bias_mean_{z}"),
                        1.0,
                        (-30f64).exp(),
                        30f64.exp(),
                        1.0,
                        "the bias's mean in noise standard deviations (ln of it)",
                    ));
                    prep.added.push(variance(
                        format!("bias_var_{z}"),
                        r * 1e-8,
                        r * 1e4,
                        r * 1e-4,
                        r * 1e-2,
                        "the bias's variance from run to run",
                    ));
                    prep.state_names.push(format!("bias_{z}"));
                }
            }
            Hypothesis::MotionState => {
                let steps = prep.steps.as_ref()?;
                let params = &base.definition.params.params;
                for (i, p) in params.iter().enumerate() {
                    let terms: Vec<usize> = (0..base.filter.q.terms.len())
                        .filter(|&t| base.filter.q.terms[t].coef == Coef::Param(i))
                        .collect();
                    let Some(&t) = terms.first() else { continue };
                    let Some(dir) = Steps::direction(&prep.inputs[t]) else {
                        continue;
                    };
                    let q = theta[i].max(f64::MIN_POSITIVE);
                    prep.driven.push((i, dir));
                    prep.added.push(shape(
                        format!("singer_rate_{}", p.name),
                        1e-4,
                        10.0,
                        0.1,
                        "decay rate per step of the Gauss–Markov state (near 0: a random walk)",
                    ));
                    prep.added.push(variance(
                        format!("singer_drive_{}", p.name),
                        q * 1e-8,
                        q * 1e6,
                        q * 0.1,
                        q * 1e-4,
                        "density of the noise driving the Gauss–Markov state, per step",
                    ));
                    prep.state_names.push(format!("singer_{}", p.name));
                }
                let _ = steps;
                if prep.driven.is_empty() {
                    return None;
                }
            }
            Hypothesis::NoiseKind => {
                let steps = prep.steps.as_ref()?;
                if prep.inputs.iter().all(|i| steps.swapped(i).is_none()) {
                    return None;
                }
            }
            Hypothesis::FullR => {
                if m < 2 {
                    return None;
                }
                for i in 0..m {
                    for j in i + 1..m {
                        prep.added.push(added(
                            format!("rho_{}_{}", names[i], names[j]),
                            1.0,
                            (-3f64).exp(),
                            3f64.exp(),
                            1.0,
                            "correlation of two components' noise (tanh of ln of it)",
                        ));
                    }
                }
            }
        }
        let _ = n;
        Some(prep)
    }
}
