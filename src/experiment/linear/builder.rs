//! A linear-Gaussian model defined in Rust, built into the same [`LinearExperiment`] a
//! problem file's `[truth]` and `[filter]` become: one type for a linear model however it
//! is written, with the linear fast path, the exact expected statistics the tuner scores on,
//! the decoupled blocks and the per-parameter targets.

#![allow(non_snake_case)]

use nalgebra::{DMatrix, DVector};

use super::{FilterModel, LinearExperiment};
use crate::experiment::described::{Described, check_name, description_setters, param_space};
use crate::input::SettingError;
use crate::linalg::covariance_defect;
use crate::model::LinearGaussianModel;
use crate::montecarlo::McConfig;
use crate::params::{Coef, CovModel, CovTerm, ParamDef};

/// Collects a linear model's parts; [`LinearModelBuilder::build`] checks them once.
///
/// The truth is `x_k = F x_{k−1} + w_k, w_k ~ N(0, Q)`, `z_k = H x_k + v_k, v_k ~ N(0, R)`,
/// `x_0 ~ N(x0, P0)`; the filter believes the same F, H, x0 and P0, with its own Q and R
/// made of one term per parameter, `Q(θ) = Σ θ_i B_i` over the process-noise parameters and
/// `R(θ)` likewise.
pub struct LinearModelBuilder {
    described: Described,
    F: Option<DMatrix<f64>>,
    H: Option<DMatrix<f64>>,
    initial: Option<(DVector<f64>, DMatrix<f64>)>,
    truth_noise: Option<(DMatrix<f64>, DMatrix<f64>)>,
    /// Each parameter, whether it is process noise, and its basis.
    terms: Vec<(ParamDef, bool, DMatrix<f64>)>,
}

impl LinearExperiment {
    /// Start a linear model called `name` (used for output names: letters, digits, `_`,
    /// `-`).
    pub fn builder(name: &str) -> LinearModelBuilder {
        LinearModelBuilder {
            described: Described::new(name),
            F: None,
            H: None,
            initial: None,
            truth_noise: None,
            terms: Vec::new(),
        }
    }
}

impl LinearModelBuilder {
    /// The state transition over one step, n × n.
    pub fn transition(mut self, F: DMatrix<f64>) -> Self {
        self.F = Some(F);
        self
    }

    /// The measurement matrix, m × n.
    pub fn observation(mut self, H: DMatrix<f64>) -> Self {
        self.H = Some(H);
        self
    }

    /// The initial state's mean (n) and covariance (n × n, positive definite): the truth
    /// draws its x_0 from them and the filter starts from them.
    pub fn initial(mut self, x0: DVector<f64>, P0: DMatrix<f64>) -> Self {
        self.initial = Some((x0, P0));
        self
    }

    /// The truth's process noise covariance per step (n × n) and measurement noise
    /// covariance (m × m), both positive semidefinite.
    pub fn truth_noise(mut self, Q: DMatrix<f64>, R: DMatrix<f64>) -> Self {
        self.truth_noise = Some((Q, R));
        self
    }

    /// A process noise parameter: the filter's Q gains `θ · basis` (n × n, symmetric
    /// positive semidefinite; `def`'s value is the filter's configured one). θ follows the
    /// order of these calls and of [`LinearModelBuilder::measurement_noise`]'s.
    pub fn process_noise(mut self, def: ParamDef, basis: DMatrix<f64>) -> Self {
        self.terms.push((def, true, basis));
        self
    }

    /// A measurement noise parameter: the filter's R gains `θ · basis` (m × m, symmetric
    /// positive semidefinite).
    pub fn measurement_noise(mut self, def: ParamDef, basis: DMatrix<f64>) -> Self {
        self.terms.push((def, false, basis));
        self
    }

    description_setters!();

    /// Check every part and build the experiment. Errors name the setting (`name`,
    /// `transition`, `observation`, `initial.P0`, `truth_noise.Q`, `params.q_accel.basis`,
    /// `states`, …).
    pub fn build(self) -> Result<LinearExperiment, SettingError> {
        check_name(&self.described.name)?;
        let missing =
            |setting: &str, what: &str| SettingError::new(setting, format!("missing: {what}"));
        let F = self.F.ok_or_else(|| missing("transition", "give F"))?;
        let H = self.H.ok_or_else(|| missing("observation", "give H"))?;
        let (x0, P0) = self
            .initial
            .ok_or_else(|| missing("initial", "give x0 and P0"))?;
        let (Q, R) = self
            .truth_noise
            .ok_or_else(|| missing("truth_noise", "give Q and R"))?;
        let n = F.nrows();
        let m = H.nrows();
        shape("transition", &F, n, n)?;
        shape("observation", &H, m, n)?;
        if m == 0 {
            return Err(SettingError::new("observation", "H has no rows"));
        }
        if x0.len() != n {
            return Err(SettingError::new(
                "initial.x0",
                format!("{} entries for {n} states", x0.len()),
            ));
        }
        finite("transition", F.iter())?;
        finite("observation", H.iter())?;
        finite("initial.x0", x0.iter())?;
        covariance("initial.P0", &P0, n, true)?;
        covariance("truth_noise.Q", &Q, n, false)?;
        covariance("truth_noise.R", &R, m, false)?;
        let (defs, kinds): (Vec<ParamDef>, Vec<(bool, DMatrix<f64>)>) = self
            .terms
            .into_iter()
            .map(|(def, process, basis)| (def, (process, basis)))
            .unzip();
        let params = param_space(defs)?;
        let (mut q, mut r) = (
            CovModel {
                dim: n,
                terms: vec![],
            },
            CovModel {
                dim: m,
                terms: vec![],
            },
        );
        for (i, (process, basis)) in kinds.into_iter().enumerate() {
            let (cov, dim) = if process { (&mut q, n) } else { (&mut r, m) };
            let setting = format!("params.{}.basis", params.params[i].name);
            covariance(&setting, &basis, dim, false)?;
            cov.terms.push(CovTerm {
                coef: Coef::Param(i),
                basis,
            });
        }
        let definition = self.described.definition(params, n, m)?;
        let truth = LinearGaussianModel::new(F.clone(), H.clone(), Q, R, x0.clone(), P0.clone())
            .map_err(|e| SettingError::new(format!("truth_noise.{}", e.which), e.to_string()))?;
        let filter = FilterModel {
            F,
            H,
            x0,
            P0,
            q,
            r,
            map: None,
        };
        Ok(LinearExperiment::new(definition, truth, filter))
    }
}

/// The unit tests' constant-velocity model: F = [[1, 1], [0, 1]], H = [1, 0], x0 = 0,
/// P0 = I, truth q = 0.5 (DWNA) and r = 1, parameters `q` and `r` at those values.
#[cfg(test)]
pub(crate) fn cv1d_for_tests() -> LinearModelBuilder {
    use crate::params::dwna_block;
    LinearExperiment::builder("cv1d")
        .transition(DMatrix::from_row_slice(2, 2, &[1.0, 1.0, 0.0, 1.0]))
        .observation(DMatrix::from_row_slice(1, 2, &[1.0, 0.0]))
        .initial(DVector::zeros(2), DMatrix::identity(2, 2))
        .truth_noise(dwna_block(1.0) * 0.5, DMatrix::identity(1, 1))
        .process_noise(ParamDef::new("q", 0.5), dwna_block(1.0))
        .measurement_noise(ParamDef::new("r", 1.0), DMatrix::identity(1, 1))
}

/// `m` is `rows × cols`.
fn shape(setting: &str, m: &DMatrix<f64>, rows: usize, cols: usize) -> Result<(), SettingError> {
    if m.nrows() != rows || m.ncols() != cols {
        return Err(SettingError::new(
            setting,
            format!("{} × {}, want {rows} × {cols}", m.nrows(), m.ncols()),
        ));
    }
    Ok(())
}

/// Every entry is a finite number.
fn finite<'a>(setting: &str, mut v: impl Iterator<Item = &'a f64>) -> Result<(), SettingError> {
    match v.find(|x| !x.is_finite()) {
        Some(x) => Err(SettingError::new(
            setting,
            format!("entry {x} is not finite"),
        )),
        None => Ok(()),
    }
}

/// `m` is a `dim × dim` covariance (positive definite where `definite`).
fn covariance(
    setting: &str,
    m: &DMatrix<f64>,
    dim: usize,
    definite: bool,
) -> Result<(), SettingError> {
    shape(setting, m, dim, dim)?;
    match covariance_defect(m, definite) {
        Some(message) => Err(SettingError::new(setting, message)),
        None => Ok(()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::experiment::{Experiment, Structure};
    use crate::params::{NoiseKind, dwna_block};
    use crate::problem::Problem;

    fn cv1d() -> LinearModelBuilder {
        LinearExperiment::builder("cv1d")
            .transition(DMatrix::from_row_slice(2, 2, &[1.0, 1.0, 0.0, 1.0]))
            .observation(DMatrix::from_row_slice(1, 2, &[1.0, 0.0]))
            .initial(
                DVector::from_column_slice(&[0.0, 1.0]),
                DMatrix::from_diagonal(&DVector::from_column_slice(&[4.0, 1.0])),
            )
            .truth_noise(dwna_block(1.0) * 0.5, DMatrix::identity(1, 1))
            .process_noise(ParamDef::new("q_accel", 0.5), dwna_block(1.0))
            .measurement_noise(ParamDef::new("r_pos", 1.0), DMatrix::identity(1, 1))
            .states(["pos", "vel"])
            .measurements(["pos"])
            .montecarlo(McConfig::new(20, 30).unwrap())
    }

    #[test]
    fn the_builder_makes_the_model_a_problem_file_makes() {
        // problems/cv1d.toml is this model: the same matrices and sums at any θ, the same
        // targets.
        let built = cv1d().build().unwrap();
        let file = Problem::load(std::path::Path::new("problems/cv1d.toml")).unwrap();
        let lin = file.linear().unwrap();
        assert_eq!(built.filter_at(&[0.7, 2.0]), lin.filter_at(&[0.7, 2.0]));
        assert_eq!(built.truth.model, lin.truth.model);
        let mc = McConfig::new(20, 30).unwrap();
        let (a, b) = (
            built.monte_carlo(&[0.7, 2.0], &mc).unwrap(),
            file.monte_carlo(&[0.7, 2.0], &mc).unwrap(),
        );
        assert_eq!(a.nees_sum, b.nees_sum);
        assert_eq!(a.nis_sum, b.nis_sum);
        let t = built.target(0).unwrap();
        assert_eq!((t.kind, t.components), (NoiseKind::Process, vec![0, 1]));
        let t = built.target(1).unwrap();
        assert_eq!((t.kind, t.components), (NoiseKind::Measurement, vec![0]));
        assert_eq!(built.state_names(), ["pos", "vel"]);
        assert_eq!(built.params().names(), ["q_accel", "r_pos"]);
        assert_eq!(built.mc().runs(), 20);
    }

    #[test]
    fn the_builder_names_the_setting_it_refuses() {
        let refused = |b: LinearModelBuilder| b.build().err().unwrap().setting;
        assert_eq!(
            refused(cv1d().transition(DMatrix::identity(3, 3))),
            "observation"
        );
        assert_eq!(
            refused(cv1d().observation(DMatrix::zeros(1, 3))),
            "observation"
        );
        assert_eq!(
            refused(cv1d().observation(DMatrix::zeros(0, 2))),
            "observation"
        );
        assert_eq!(
            refused(cv1d().transition(DMatrix::from_row_slice(2, 1, &[1.0, 0.0]))),
            "transition"
        );
        assert_eq!(
            refused(cv1d().transition(DMatrix::from_element(2, 2, f64::NAN))),
            "transition"
        );
        assert_eq!(
            refused(cv1d().observation(DMatrix::from_row_slice(1, 2, &[f64::INFINITY, 0.0]))),
            "observation"
        );
        let x0_nan = DVector::from_element(2, f64::NAN);
        assert_eq!(
            refused(cv1d().initial(x0_nan, DMatrix::identity(2, 2))),
            "initial.x0"
        );
        let short = DVector::zeros(1);
        assert_eq!(
            refused(cv1d().initial(short, DMatrix::identity(2, 2))),
            "initial.x0"
        );
        // P0 must be definite; Q and R only semidefinite.
        let singular = DMatrix::from_diagonal(&DVector::from_column_slice(&[1.0, 0.0]));
        assert_eq!(
            refused(cv1d().initial(DVector::zeros(2), singular.clone())),
            "initial.P0"
        );
        assert!(
            cv1d()
                .truth_noise(singular.clone(), DMatrix::identity(1, 1))
                .build()
                .is_ok()
        );
        let negative = DMatrix::from_element(1, 1, -1.0);
        assert_eq!(
            refused(cv1d().truth_noise(singular.clone(), negative.clone())),
            "truth_noise.R"
        );
        assert_eq!(
            refused(cv1d().truth_noise(-singular.clone(), DMatrix::identity(1, 1))),
            "truth_noise.Q"
        );
        assert_eq!(
            refused(cv1d().measurement_noise(ParamDef::new("r2", 1.0), negative)),
            "params.r2.basis"
        );
        assert_eq!(
            refused(cv1d().process_noise(ParamDef::new("q2", 1.0), DMatrix::identity(1, 1))),
            "params.q2.basis"
        );
        assert_eq!(
            refused(cv1d().process_noise(ParamDef::new("q_accel", 1.0), singular)),
            "params.q_accel"
        );
        assert_eq!(refused(cv1d().states(["x"])), "states");
        assert_eq!(refused(LinearExperiment::builder("a b")), "name");
        assert_eq!(refused(LinearExperiment::builder("cv")), "transition");
        for (setting, without) in [
            ("transition", cv1d_without(0)),
            ("observation", cv1d_without(1)),
            ("initial", cv1d_without(2)),
            ("truth_noise", cv1d_without(3)),
        ] {
            assert_eq!(refused(without), setting);
        }
    }

    /// cv1d's builder with part `k` (F, H, initial, truth noise) left out.
    fn cv1d_without(k: usize) -> LinearModelBuilder {
        let mut b = cv1d();
        match k {
            0 => b.F = None,
            1 => b.H = None,
            2 => b.initial = None,
            _ => b.truth_noise = None,
        }
        b
    }
}
