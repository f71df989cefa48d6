//! A linear problem: `[truth]` and `[filter]` become a [`LinearExperiment`].
//!
//! The filter may carry other states than the truth (fewer, typically: the truth has an
//! acceleration, a sensor bias or a flexible mode the filter omits). `filter.map` (n_f × n_t)
//! takes the truth's state to the filter's, and the filter then gives its own F (or A) and H;
//! its x0 and P0 default to the truth's through the map (`map · x0`, `map · P0 · map'`).

#![allow(non_snake_case)]

use nalgebra::{DMatrix, DVector};

use super::spec::{FilterSpec, MatrixSpec, ProblemSpec, TruthSpec};
use super::validate::{VResult, Validator};
use crate::experiment::{Definition, FilterModel, Info, LinearExperiment};
use crate::input::FileError;
use crate::model::LinearGaussianModel;
use crate::montecarlo::McConfig;
use crate::params::ParamSpace;

/// `[truth]`'s matrices: F (and A, when given in continuous time), H, x0, P0, Q, R.
struct TruthMatrices {
    F: DMatrix<f64>,
    A: Option<DMatrix<f64>>,
    H: DMatrix<f64>,
    x0: DVector<f64>,
    P0: DMatrix<f64>,
    Q: DMatrix<f64>,
    R: DMatrix<f64>,
}

impl Validator<'_> {
    /// Build the linear truth, the filter's model and the parameters.
    pub(super) fn linear_problem(
        &self,
        s: &ProblemSpec,
        t: &TruthSpec,
        f: &FilterSpec,
        info: Info,
        mc: McConfig,
    ) -> VResult<LinearExperiment> {
        let dt = s.dt.unwrap_or(1.0);
        let tm = self.truth_matrices(t, dt)?;
        let (n, m) = (tm.F.nrows(), tm.H.nrows());
        let params = self.params(&s.params)?;
        let map = match &f.map {
            Some(spec) => self.truth_map(spec, n)?,
            None => None,
        };
        let filter = self.filter_model(f, &tm, map, &params, dt)?;
        let nf = filter.F.nrows();
        let mapped = filter.map.is_some();
        let truth = LinearGaussianModel::new(tm.F, tm.H, tm.Q, tm.R, tm.x0, tm.P0)
            .map_err(|e| FileError::new(self.file, format!("truth.{}", e.which), e.to_string()))?;
        let state_names = self
            .names("state_names", &s.state_names, nf, "x")
            .map_err(|e| {
                if mapped {
                    FileError {
                        message: format!("{} (they name the filter's states)", e.message),
                        ..e
                    }
                } else {
                    e
                }
            })?;
        let measurement_names = self.names("measurement_names", &s.measurement_names, m, "z")?;
        Ok(LinearExperiment::new(
            Definition {
                info,
                params,
                state_names,
                measurement_names,
                mc,
            },
            truth,
            filter,
        ))
    }

    /// `[truth]`'s matrices, checked (Q and R built from their fixed terms).
    fn truth_matrices(&self, t: &TruthSpec, dt: f64) -> VResult<TruthMatrices> {
        let Some((F, A)) = self.dynamics("truth", &t.F, &t.A, dt, None)? else {
            return self.err("truth.F", "missing: give F (discrete) or A (continuous)");
        };
        let n = F.nrows();
        let H = self.matrix("truth.H", &t.H, None, Some(n))?;
        let m = H.nrows();
        let x0 = self.vector("truth.x0", &t.x0, n)?;
        let P0 = self.matrix("truth.P0", &t.P0, Some(n), Some(n))?;
        self.symmetric_psd("truth.P0", &P0, false)?;
        let Q = self
            .cov_model("truth.Q", &t.Q, n, true, dt, A.as_ref(), None)?
            .build(&[]);
        let R = self
            .cov_model("truth.R", &t.R, m, false, dt, None, None)?
            .build(&[]);
        self.symmetric_psd("truth.Q", &Q, false)?;
        self.symmetric_psd("truth.R", &R, false)?;
        Ok(TruthMatrices {
            F,
            A,
            H,
            x0,
            P0,
            Q,
            R,
        })
    }

    /// `[filter]`'s model: its own matrices where given, the truth's (through `map`, when
    /// there is one) otherwise, with Q and R over `params`, each of which it must use.
    fn filter_model(
        &self,
        f: &FilterSpec,
        tm: &TruthMatrices,
        map: Option<DMatrix<f64>>,
        params: &ParamSpace,
        dt: f64,
    ) -> VResult<FilterModel> {
        let (n, m) = (tm.F.nrows(), tm.H.nrows());
        let nf = map.as_ref().map_or(n, |m| m.nrows());
        // Without a map the filter's matrices have the truth's number of states; a filter
        // of another size is what a map is for, so say so (not for H's rows, which count
        // measurements).
        let hint = |e: FileError| match &map {
            None if e.message.contains("expected") && e.field != "filter.H" => FileError {
                message: format!(
                    "{} (the truth's {n} states; a filter with other states needs filter.map)",
                    e.message
                ),
                ..e
            },
            _ => e,
        };
        let (fF, fA) = match self
            .dynamics("filter", &f.F, &f.A, dt, Some(nf))
            .map_err(hint)?
        {
            Some(d) => d,
            None if map.is_none() => (tm.F.clone(), tm.A.clone()),
            None => return self.err("filter.F", own_matrix(nf, n, "F (or A), n_f × n_f")),
        };
        let fH = match &f.H {
            Some(h) => self
                .matrix("filter.H", h, Some(m), Some(nf))
                .map_err(hint)?,
            None if map.is_none() => tm.H.clone(),
            None => return self.err("filter.H", own_matrix(nf, n, "H, m × n_f")),
        };
        let fx0 = match (&f.x0, &map) {
            (Some(x), _) => self.vector("filter.x0", x, nf).map_err(hint)?,
            (None, Some(M)) => M * &tm.x0,
            (None, None) => tm.x0.clone(),
        };
        let (fP0, p0_field) = match (&f.P0, &map) {
            (Some(p), _) => (
                self.matrix("filter.P0", p, Some(nf), Some(nf))
                    .map_err(hint)?,
                "filter.P0",
            ),
            (None, Some(M)) => (
                M * &tm.P0 * M.transpose(),
                "truth.P0 through filter.map (used as filter.P0)",
            ),
            (None, None) => (tm.P0.clone(), "truth.P0 (used as filter.P0)"),
        };
        self.symmetric_psd(p0_field, &fP0, true)?;
        let q = self.cov_model("filter.Q", &f.Q, nf, true, dt, fA.as_ref(), Some(params))?;
        let r = self.cov_model("filter.R", &f.R, m, false, dt, None, Some(params))?;
        for (i, p) in params.params.iter().enumerate() {
            if !q.uses(i) && !r.uses(i) {
                return self.err(
                    format!("params.{}", p.name),
                    "not used by any filter.Q or filter.R term",
                );
            }
        }
        Ok(FilterModel {
            F: fF,
            H: fH,
            x0: fx0,
            P0: fP0,
            q,
            r,
            map,
        })
    }

    /// `filter.map`: n_f × n_t, finite; `None` when it is the identity (the filter then has
    /// the truth's states, exactly as without a map).
    fn truth_map(&self, spec: &MatrixSpec, n_t: usize) -> VResult<Option<DMatrix<f64>>> {
        if let Some(row) = spec.first()
            && row.len() != n_t
        {
            return self.err(
                "filter.map",
                format!(
                    "has {} columns, expected {n_t}: one per truth state (map is n_f × n_t, \
                     e = map · x_true − x̂)",
                    row.len()
                ),
            );
        }
        let M = self.matrix("filter.map", spec, None, Some(n_t))?;
        let identity = M.nrows() == n_t && M == DMatrix::identity(n_t, n_t);
        Ok((!identity).then_some(M))
    }
}

/// Why the filter must give its own `what` when it has a map.
fn own_matrix(n_f: usize, n_t: usize, what: &str) -> String {
    let states = |n: usize| format!("{n} state{}", if n == 1 { "" } else { "s" });
    let dims = if n_f == n_t {
        format!("filter.map changes the state ({})", states(n_f))
    } else {
        format!(
            "the filter has {} (filter.map's rows) and the truth {n_t}",
            states(n_f)
        )
    };
    format!("missing: {dims}, so the truth's cannot be used; give the filter's own {what}")
}
