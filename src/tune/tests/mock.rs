//! A stand-in experiment whose sums are a formula of θ, so that J and its minimum are
//! known exactly and an evaluation costs microseconds (as hyperfine's `MockExecutor`
//! stands in for running commands).
//!
//! State component j has mean normalized error `c_j(θ) = Π_i (θ*_i/θ_i)^{A_ji}`, and the
//! filter's NEES is their sum (what a diagonal P gives), so the confirmation's gate sees
//! the same error as the components. One measurement component is always consistent
//! (ν²/S = 1). With only the component weight on, J is exactly
//!
//! ```text
//! J(y) = (1/n_x) Σ_j (Σ_i A_ji (y*_i − y_i))²,   y = ln θ,
//! ```
//!
//! a quadratic in log space with its minimum 0 at y* (a flat direction where A is singular).
//!
//! Variants: [`Mock::measuring`] puts the components in the measurements instead (no states,
//! no ground truth), [`Mock::without_exact_sums`] offers only Monte Carlo sums, and
//! [`Mock::with_blocks`] declares decoupled blocks.
//!
//! [`Mock::bent`] adds a quadratic term to each component's log, `ln c_j = Σ_i A_ji d_i +
//! Σ_i B_ji d_i²` with `d = y* − y`, so that J can have two basins (see
//! [`super::two_basins`]).

use std::sync::Mutex;
use std::sync::atomic::{AtomicUsize, Ordering};

use crate::experiment::{Block, Definition, Experiment, ExperimentError, Info, RunOptions, Source};
use crate::montecarlo::McConfig;
use crate::params::{ParamDef, ParamSpace, Target};
use crate::stats::Accumulator;
use crate::tune::cost::Cost;
use crate::tune::{Objective, Scoring, TuneSettings, Weights};

/// The mock experiment.
pub(crate) struct Mock {
    definition: Definition,
    /// θ*: the parameters at which every component is consistent.
    pub truth: Vec<f64>,
    /// `A`, one row per state component.
    exponents: Vec<Vec<f64>>,
    /// `B`, one row per state component, when the mock is bent ([`Mock::bent`]).
    bend: Option<Vec<Vec<f64>>>,
    /// A candidate diverges when parameter `.0` exceeds `.1`.
    diverge_above: Option<(usize, f64)>,
    /// A candidate diverges when parameter `.0` is below `.1`.
    diverge_below: Option<(usize, f64)>,
    /// Calls of `expected` and `monte_carlo_with`.
    pub calls: AtomicUsize,
    /// Those calls that returned diverged sums.
    pub diverged_calls: AtomicUsize,
    /// The parameter values of every call, in call order.
    pub points: Mutex<Vec<Vec<f64>>>,
    /// The run count asked of every Monte Carlo call, in call order.
    pub runs: Mutex<Vec<usize>>,
    /// The components are measurement components (no states).
    measuring: bool,
    /// `expected` gives exact sums.
    exact: bool,
    /// The decoupled blocks, if declared.
    blocks: Option<Vec<Block>>,
    /// A Monte Carlo call fails (as a broken worker does) when parameter `.0` exceeds `.1`.
    fail_above: Option<(usize, f64)>,
    /// The sums are the same for every seed (a filter over one recorded data set).
    recorded: bool,
    /// `ln c_j` offset by `.0[j]` at every θ (a misfit no parameter removes), in exact sums
    /// and in Monte Carlo calls of fewer than `.1` runs (a misfit that more runs dispel).
    offset: Option<(Vec<f64>, usize)>,
}

impl Mock {
    /// A mock with parameters starting at 1 (bounds 1e-4 to 1e4), truth `truth` and
    /// exponent matrix `exponents` (one row per state component). Parameter i drives the
    /// state components where its exponent is not zero.
    pub(crate) fn new(truth: &[f64], exponents: &[&[f64]]) -> Mock {
        let params = (0..truth.len())
            .map(|i| ParamDef::new(&format!("p{i}"), 1.0))
            .collect();
        Mock {
            definition: Definition {
                info: Info {
                    name: "mock".into(),
                    description: String::new(),
                    source: Source::Program {
                        name: "mock".into(),
                    },
                },
                params: ParamSpace { params },
                state_names: (0..exponents.len()).map(|j| format!("s{j}")).collect(),
                measurement_names: vec!["z".into()],
                mc: McConfig::new(100, 10).expect("valid"),
            },
            truth: truth.to_vec(),
            exponents: exponents.iter().map(|r| r.to_vec()).collect(),
            bend: None,
            diverge_above: None,
            diverge_below: None,
            calls: AtomicUsize::new(0),
            diverged_calls: AtomicUsize::new(0),
            points: Mutex::new(Vec::new()),
            runs: Mutex::new(Vec::new()),
            measuring: false,
            exact: true,
            blocks: None,
            fail_above: None,
            recorded: false,
            offset: None,
        }
    }

    /// The mock whose parameter `i` its definition marks fixed.
    pub(crate) fn with_fixed(mut self, i: usize) -> Mock {
        self.definition.params.params[i].fixed = true;
        self
    }

    /// The mock whose component j is off by the factor `e^{o_j}` at every θ ([`Mock::j`]
    /// then has no zero), in its exact sums and in Monte Carlo calls of fewer than
    /// `below_runs` runs: `usize::MAX` for a misfit at any N, a finite count for one that
    /// the recheck on more runs does not repeat.
    pub(crate) fn misfit(mut self, o: &[f64], below_runs: usize) -> Mock {
        assert_eq!(o.len(), self.exponents.len(), "one offset per component");
        self.offset = Some((o.to_vec(), below_runs));
        self
    }

    /// The mock with its components in the measurements, `ν_j²/S_jj` averaging `c_j`, and
    /// no states (an experiment without ground truth): J is the same formula.
    pub(crate) fn measuring(mut self) -> Mock {
        self.measuring = true;
        self.definition.measurement_names = std::mem::take(&mut self.definition.state_names)
            .into_iter()
            .map(|s| s.replace('s', "z"))
            .collect();
        self
    }

    /// The mock without exact sums: every evaluation is a (mock) Monte Carlo run.
    pub(crate) fn without_exact_sums(mut self) -> Mock {
        self.exact = false;
        self
    }

    /// The mock whose Monte Carlo calls fail where parameter `i` exceeds `value`, as an
    /// external worker that breaks the protocol on some candidates.
    pub(crate) fn failing_above(mut self, i: usize, value: f64) -> Mock {
        self.fail_above = Some((i, value));
        self
    }

    /// The mock as a filter over one recorded data set ([`Sampling::seed_free`]): its
    /// sums were always the same for every seed; now it says so.
    pub(crate) fn recorded(mut self) -> Mock {
        self.recorded = true;
        self
    }

    /// The mock declaring `blocks` decoupled.
    pub(crate) fn with_blocks(mut self, blocks: Vec<Block>) -> Mock {
        self.blocks = Some(blocks);
        self
    }

    /// The mock with `ln c_j = Σ_i A_ji d_i + Σ_i B_ji d_i²` (`d = y* − y`), `B` given one
    /// row per state component. Each parameter's targets stay where A is not zero.
    pub(crate) fn bent(mut self, quadratic: &[&[f64]]) -> Mock {
        assert_eq!(
            quadratic.len(),
            self.exponents.len(),
            "one row of B per component"
        );
        self.bend = Some(quadratic.iter().map(|r| r.to_vec()).collect());
        self
    }

    /// The log-points of every call so far, in call order.
    pub(crate) fn log_points(&self) -> Vec<Vec<f64>> {
        let points = self.points.lock().unwrap();
        points
            .iter()
            .map(|t| t.iter().map(|v| v.ln()).collect())
            .collect()
    }

    /// Candidates whose parameter `i` exceeds `limit` diverge.
    pub(crate) fn diverging_above(mut self, i: usize, limit: f64) -> Mock {
        self.diverge_above = Some((i, limit));
        self
    }

    /// Candidates whose parameter `i` is below `limit` diverge.
    pub(crate) fn diverging_below(mut self, i: usize, limit: f64) -> Mock {
        self.diverge_below = Some((i, limit));
        self
    }

    /// The log-truth y*.
    pub(crate) fn y_star(&self) -> Vec<f64> {
        self.truth.iter().map(|t| t.ln()).collect()
    }

    /// J at θ, from the formula in the module doc.
    pub(crate) fn j(&self, theta: &[f64]) -> f64 {
        let c = self.components(theta, true);
        c.iter().map(|c| c.ln().powi(2)).sum::<f64>() / c.len() as f64
    }

    /// The components at θ, off by the misfit's factors when `offset` (see [`Mock::misfit`]).
    fn components(&self, theta: &[f64], offset: bool) -> Vec<f64> {
        let mut c = self.consistent_components(theta);
        if let (true, Some((o, _))) = (offset, &self.offset) {
            for (c, o) in c.iter_mut().zip(o) {
                *c *= o.exp();
            }
        }
        c
    }

    fn consistent_components(&self, theta: &[f64]) -> Vec<f64> {
        if let Some(bend) = &self.bend {
            let d: Vec<f64> = theta
                .iter()
                .zip(&self.truth)
                .map(|(t, s)| (s / t).ln())
                .collect();
            return self
                .exponents
                .iter()
                .zip(bend)
                .map(|(a, b)| {
                    let ln_c: f64 = (0..d.len()).map(|i| a[i] * d[i] + b[i] * d[i] * d[i]).sum();
                    ln_c.exp()
                })
                .collect();
        }
        self.exponents
            .iter()
            .map(|row| {
                row.iter()
                    .zip(theta.iter().zip(&self.truth))
                    .map(|(a, (t, s))| (s / t).powf(*a))
                    .product()
            })
            .collect()
    }

    /// The sums of `runs` runs of `steps` steps whose statistics equal their means exactly.
    /// The run count is the mock's own whatever the caller asks, so exact and Monte Carlo
    /// scoring see bit-identical sums.
    fn sums(&self, theta: &[f64], offset: bool) -> Accumulator {
        self.calls.fetch_add(1, Ordering::SeqCst);
        self.points.lock().unwrap().push(theta.to_vec());
        let c = self.components(theta, offset);
        let (runs, steps) = (self.mc().runs(), self.mc().steps());
        let (r, t) = (runs as f64, steps as f64);
        if self.measuring {
            return self.measurement_sums(theta, &c, runs, steps);
        }
        let (n_x, n_z) = (c.len(), 1);
        let mut acc = Accumulator::new(steps, n_x, n_z, 0);
        acc.runs = runs;
        let nees: f64 = c.iter().sum();
        for k in 0..steps {
            acc.nees_sum[k] = r * nees;
            acc.nees_sq[k] = r * nees * nees;
            acc.nees_dof[k] = r * n_x as f64;
            acc.nees_count[k] = r;
            acc.nis_sum[k] = r;
            acc.nis_sq[k] = r;
            acc.nis_dof[k] = r;
            acc.nis_count[k] = r;
        }
        // A chi-square NEES has variance 2 n_x per step.
        acc.nees_null_var = r * 2.0 * n_x as f64 * t;
        acc.null_var_runs = runs;
        for (j, cj) in c.iter().enumerate() {
            acc.state_comp_total[j] = cj * r * t;
            acc.state_comp_samples[j] = r * t;
            acc.state_comp_run_sum[j] = r * cj;
            acc.state_comp_run_sq[j] = r * cj * cj;
        }
        acc.meas_comp_total[0] = r * t;
        acc.meas_comp_samples[0] = r * t;
        acc.meas_comp_run_sum[0] = r;
        acc.meas_comp_run_sq[0] = r;
        acc.meas_comp_runs[0] = runs;
        if self
            .diverge_above
            .is_some_and(|(i, limit)| theta[i] > limit)
            || self
                .diverge_below
                .is_some_and(|(i, limit)| theta[i] < limit)
        {
            acc.diverged_runs = runs;
            self.diverged_calls.fetch_add(1, Ordering::SeqCst);
        }
        acc
    }

    /// [`Mock::sums`] of the measuring mock: component j's `ν_j²/S_jj` averages `c_j`, the
    /// NIS is their sum, and no state is estimated.
    fn measurement_sums(&self, theta: &[f64], c: &[f64], runs: usize, steps: usize) -> Accumulator {
        let n_z = c.len();
        let (r, t) = (runs as f64, steps as f64);
        let mut acc = Accumulator::new(steps, 0, n_z, 0);
        acc.runs = runs;
        let nis: f64 = c.iter().sum();
        for k in 0..steps {
            acc.nis_sum[k] = r * nis;
            acc.nis_sq[k] = r * nis * nis;
            acc.nis_dof[k] = r * n_z as f64;
            acc.nis_count[k] = r;
        }
        for (j, cj) in c.iter().enumerate() {
            acc.meas_comp_total[j] = cj * r * t;
            acc.meas_comp_samples[j] = r * t;
            acc.meas_comp_run_sum[j] = r * cj;
            acc.meas_comp_run_sq[j] = r * cj * cj;
            acc.meas_comp_runs[j] = runs;
        }
        if self
            .diverge_above
            .is_some_and(|(i, limit)| theta[i] > limit)
            || self
                .diverge_below
                .is_some_and(|(i, limit)| theta[i] < limit)
        {
            acc.diverged_runs = runs;
            self.diverged_calls.fetch_add(1, Ordering::SeqCst);
        }
        acc
    }
}

impl Experiment for Mock {
    fn definition(&self) -> &Definition {
        &self.definition
    }

    fn monte_carlo_with(
        &self,
        theta: &[f64],
        mc: &McConfig,
        _o: RunOptions<'_>,
    ) -> Result<Accumulator, ExperimentError> {
        self.runs.lock().unwrap().push(mc.runs());
        if let Some((i, v)) = self.fail_above
            && theta[i] > v
        {
            self.calls.fetch_add(1, Ordering::SeqCst);
            return Err(ExperimentError::RecordsDiffer {
                source_label: format!("p{i} = {}", theta[i]),
                held: (0, 0, 0),
                asked: (mc.runs(), mc.steps(), mc.lags()),
            });
        }
        let offset = self.offset.as_ref().is_some_and(|o| mc.runs() < o.1);
        Ok(self.sums(theta, offset))
    }
}

impl crate::experiment::Structure for Mock {
    fn expected(&self, theta: &[f64], _mc: &McConfig) -> Option<Accumulator> {
        self.exact.then(|| self.sums(theta, true))
    }

    fn blocks(&self) -> Option<Vec<Block>> {
        self.blocks.clone()
    }

    fn target(&self, i: usize) -> Option<Target> {
        let comps: Vec<usize> = (0..self.exponents.len())
            .filter(|&j| self.exponents[j][i] != 0.0)
            .collect();
        Some(if self.measuring {
            Target::measurement(&comps)
        } else {
            Target::process(&comps)
        })
    }
}

impl crate::experiment::HeldAsCode for Mock {}

impl crate::experiment::Sampling for Mock {
    fn seed_free(&self) -> bool {
        self.recorded
    }
}

/// Weights that leave J the component term alone (the formula in the module doc).
const COMPONENTS_ONLY: Weights = Weights {
    mean: 0.0,
    interval: 0.0,
    per_step: 0.0,
    components: 1.0,
    whiteness: 0.0,
    shape: 0.0,
    bias: 0.0,
};

/// Settings whose J is the formula in the module doc.
pub(crate) fn settings(scoring: Scoring) -> TuneSettings {
    TuneSettings::default()
        .with_weights(COMPONENTS_ONLY)
        .expect("weights not all zero")
        .with_scoring(scoring)
}

/// The search's cost on `mock` with the parameters flagged in `fixed` held at 1, exact
/// scoring, J the formula in the module doc.
pub(in crate::tune) fn cost<'a>(mock: &'a Mock, fixed: &[bool]) -> Cost<'a> {
    let start = mock.params().values();
    let objective = Objective::new(COMPONENTS_ONLY, false, mock.mc().alpha());
    let mut cost = Cost::new(mock, *mock.mc(), true, objective, &start, fixed);
    cost.objective.prepare(&mock.sums(&start, true));
    cost
}
