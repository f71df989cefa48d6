//! The sensor-side hypotheses on a filter held as code (a catalog model's, a Rust model's):
//! autotune cannot change its model, but it feeds it its readings, so it can change what
//! the filter reads — a sensor's constant offset or its gain, through a
//! [`crate::filter::Correction`].

use super::build::added;
use super::{Added, Changed, Hypothesis};
use crate::experiment::{Definition, Experiment, ExperimentError, RunOptions, TruthReuse};
use crate::filter::Correction;
use crate::montecarlo::{McConfig, TapeUsage};
use crate::params::Target;
use crate::stats::Accumulator;

/// `base` with its filter reading every measurement component corrected: offset `b_j`
/// (`bias_mean_<z>`, neutral 1: the offset is `σ_j ln` of it, σ_j the component's
/// innovation standard deviation at the run's best fit) or gain `g_j` (`gain_<z>`,
/// neutral 1), appended to θ after the base's parameters.
pub struct ReadThrough<'a> {
    base: &'a dyn Experiment,
    hypothesis: Hypothesis,
    definition: Definition,
    added: Vec<Added>,
    /// σ_j per measurement component, in its units: the unit of an offset.
    scales: Vec<f64>,
}

impl<'a> ReadThrough<'a> {
    /// `hypothesis` on `base`, a filter that reads what autotune feeds it, with the
    /// components' innovation standard deviations `scales` ([`HeldAsCode::innovation_scales`]);
    /// `None` for a hypothesis that changes more than what the filter reads, or scales
    /// that are not one per component.
    pub fn new(base: &'a dyn Experiment, hypothesis: Hypothesis, scales: &[f64]) -> Option<Self> {
        let names = base.measurement_names();
        if scales.len() != names.len() {
            return None;
        }
        let added: Vec<Added> = match hypothesis {
            Hypothesis::SensorGain => names
                .iter()
                .map(|z| {
                    added(
                        format!("gain_{z}"),
                        1.0,
                        0.2,
                        5.0,
                        1.0,
                        "the reading's gain: the filter reads it divided by this",
                    )
                })
                .collect(),
            Hypothesis::SensorBias => names
                .iter()
                .map(|z| {
                    added(
                        format!("bias_mean_{z}"),
                        1.0,
                        (-30f64).exp(),
                        30f64.exp(),
                        1.0,
                        "the reading's constant offset in innovation standard deviations (ln of it)",
                    )
                })
                .collect(),
            _ => return None,
        };
        let mut definition = base.definition().clone();
        definition
            .params
            .params
            .extend(added.iter().map(|a| a.def.clone()));
        Some(ReadThrough {
            base,
            hypothesis,
            definition,
            added,
            scales: scales.to_vec(),
        })
    }

    fn base_params(&self) -> usize {
        self.base.params().params.len()
    }

    /// The correction the added parameters `psi` make.
    fn correction(&self, psi: &[f64]) -> Correction {
        let mut c = Correction::none(self.scales.len());
        for (j, v) in psi.iter().enumerate() {
            match self.hypothesis {
                Hypothesis::SensorGain => c.gain[j] = *v,
                _ => c.offset[j] = self.scales[j] * v.ln(),
            }
        }
        c
    }
}

impl Changed for ReadThrough<'_> {
    fn hypothesis(&self) -> Hypothesis {
        self.hypothesis
    }

    fn added(&self) -> &[Added] {
        &self.added
    }

    fn at_neutral(&self, theta: &[f64]) -> bool {
        theta[self.base_params()..]
            .iter()
            .zip(&self.added)
            .all(|(v, a)| a.is_neutral(*v))
    }

    fn reading(&self, name: &str, value: f64) -> (String, f64) {
        if let Some(z) = name.strip_prefix("bias_mean_")
            && let Some(j) = self.base.measurement_names().iter().position(|n| n == z)
        {
            return (format!("offset_{z}"), self.scales[j] * value.ln());
        }
        (name.to_string(), value)
    }

    fn words(&self) -> String {
        match self.hypothesis {
            Hypothesis::SensorBias => {
                "a sensor's constant offset (in what the filter reads)".into()
            }
            h => format!("{} (in what the filter reads)", h.words()),
        }
    }
}

impl Experiment for ReadThrough<'_> {
    fn definition(&self) -> &Definition {
        &self.definition
    }

    fn monte_carlo_with(
        &self,
        theta: &[f64],
        mc: &McConfig,
        options: RunOptions<'_>,
    ) -> Result<Accumulator, ExperimentError> {
        let n = self.base_params();
        let c = self.correction(&theta[n..]);
        self.base
            .monte_carlo_corrected(&theta[..n], mc, options, &c)
            .unwrap_or_else(|| {
                // A base offers corrected runs at every θ or at none (`new` asked it for
                // its scales); one that refuses them scores as a filter that cannot run.
                Ok(crate::montecarlo::all_stopped(
                    mc,
                    self.state_names().len(),
                    self.measurement_names().len(),
                    &crate::filter::FilterError::Unsupported {
                        what: "corrected readings",
                    },
                ))
            })
    }
}

impl crate::experiment::Structure for ReadThrough<'_> {
    fn target(&self, i: usize) -> Option<Target> {
        (i < self.base_params())
            .then(|| self.base.target(i))
            .flatten()
    }
}

impl crate::experiment::HeldAsCode for ReadThrough<'_> {}

impl crate::experiment::Sampling for ReadThrough<'_> {
    fn truth_reuse(&self, since: TapeUsage) -> TruthReuse {
        self.base.truth_reuse(since)
    }

    fn tape_usage(&self) -> TapeUsage {
        self.base.tape_usage()
    }
}

#[cfg(test)]
mod tests {
    use nalgebra::{DMatrix, DVector};

    use super::*;
    use crate::experiment::{HeldAsCode, RustModel, Structure};
    use crate::filter::KalmanFilter;
    use crate::model::LinearGaussianModel;
    use crate::params::ParamDef;

    /// A static scalar state seen directly: F = 1, Q = 0, H = 1, R = r, P0 = p; θ = (r).
    fn static_model(
        r: f64,
        p: f64,
    ) -> RustModel<LinearGaussianModel, impl Fn(&[f64]) -> KalmanFilter + Sync> {
        let one = DMatrix::identity(1, 1);
        let truth = LinearGaussianModel::new(
            one.clone(),
            one.clone(),
            DMatrix::zeros(1, 1),
            &one * r,
            DVector::zeros(1),
            &one * p,
        )
        .unwrap();
        let filter = move |theta: &[f64]| KalmanFilter {
            F: DMatrix::identity(1, 1),
            H: DMatrix::identity(1, 1),
            Q: DMatrix::zeros(1, 1),
            R: DMatrix::identity(1, 1) * theta[0],
            x0: DVector::zeros(1),
            P0: DMatrix::identity(1, 1) * p,
        };
        RustModel::builder("static", truth, filter)
            .states(["x"])
            .measurements(["z"])
            .param(ParamDef::new("r", r), Target::measurement(&[0]))
            .montecarlo(McConfig::new(40, 30).unwrap().with_seed(3))
            .build()
            .unwrap()
    }

    #[test]
    fn the_scales_are_the_root_mean_innovation_variance_of_the_first_run() {
        // S_k = P_{k−1} + r with 1/P_k = 1/p + k/r: the filter's S does not depend on the
        // data, so the one run's mean S is this sum.
        let (r, p) = (2.0, 5.0);
        let model = static_model(r, p);
        let steps = model.mc().steps();
        let mean_s = (1..=steps)
            .map(|k| 1.0 / (1.0 / p + (k - 1) as f64 / r) + r)
            .sum::<f64>()
            / steps as f64;
        let s = model.innovation_scales(&[r], model.mc()).unwrap();
        assert!(
            (s[0] - mean_s.sqrt()).abs() < 1e-12,
            "{s:?} vs {}",
            mean_s.sqrt()
        );
    }

    #[test]
    fn a_reading_change_adds_its_parameters_and_corrects_what_the_filter_reads() {
        let model = static_model(2.0, 5.0);
        let scales = [1.5];
        assert!(ReadThrough::new(&model, Hypothesis::TimeStep, &scales).is_none());
        assert!(ReadThrough::new(&model, Hypothesis::SensorGain, &[1.0, 2.0]).is_none());
        let gain = ReadThrough::new(&model, Hypothesis::SensorGain, &scales).unwrap();
        let bias = ReadThrough::new(&model, Hypothesis::SensorBias, &scales).unwrap();
        let names = |e: &ReadThrough| -> Vec<String> {
            e.params().params.iter().map(|p| p.name.clone()).collect()
        };
        assert_eq!(names(&gain), ["r", "gain_z"]);
        assert_eq!(names(&bias), ["r", "bias_mean_z"]);
        // At its neutral value the change reads the measurement as it is: the base's sums,
        // bit for bit.
        let mc = *model.mc();
        let base = model.monte_carlo(&[2.0], &mc).unwrap();
        for e in [&gain, &bias] {
            let same = e.monte_carlo(&[2.0, 1.0], &mc).unwrap();
            assert_eq!(same, base);
            assert!(e.at_neutral(&[2.0, 1.0]) && !e.at_neutral(&[2.0, 1.1]));
        }
        // Off its neutral value it changes the sums.
        assert_ne!(
            gain.monte_carlo(&[2.0, 1.3], &mc).unwrap().nis_sum,
            base.nis_sum
        );
        // The offset is σ ln of its parameter; a gain reads as itself.
        assert_eq!(
            bias.correction(&[2f64.exp()]),
            Correction {
                offset: vec![3.0],
                gain: vec![1.0]
            }
        );
        assert_eq!(gain.correction(&[1.25]).gain, vec![1.25]);
        let (name, v) = bias.reading("bias_mean_z", (-2f64).exp());
        assert_eq!((name.as_str(), v), ("offset_z", -3.0));
        assert_eq!(gain.reading("gain_z", 1.25), ("gain_z".to_string(), 1.25));
        assert!(bias.words().contains("what the filter reads"));
        // Only the base's parameters have targets.
        assert!(gain.target(0).is_some() && gain.target(1).is_none());
    }
}
