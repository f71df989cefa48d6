//! A linear problem: `[truth]` and `[filter]` become a [`LinearExperiment`].

#![allow(non_snake_case)]

use super::spec::{FilterSpec, ProblemSpec, TruthSpec};
use super::validate::{VResult, Validator};
use crate::experiment::{Definition, FilterModel, Info, LinearExperiment};
use crate::input::FileError;
use crate::model::LinearGaussianModel;
use crate::montecarlo::McConfig;

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
        let dt = s.dt;
        let Some((tF, tA)) = self.dynamics("truth", &t.F, &t.A, dt, None)? else {
            return self.err("truth.F", "missing: give F (discrete) or A (continuous)");
        };
        let n = tF.nrows();
        let tH = self.matrix("truth.H", &t.H, None, Some(n))?;
        let m = tH.nrows();
        let tx0 = self.vector("truth.x0", &t.x0, n)?;
        let tP0 = self.matrix("truth.P0", &t.P0, Some(n), Some(n))?;
        self.symmetric_psd("truth.P0", &tP0, false)?;
        let tQ = self
            .cov_model("truth.Q", &t.Q, n, true, dt, tA.as_ref(), None)?
            .build(&[]);
        let tR = self
            .cov_model("truth.R", &t.R, m, false, dt, None, None)?
            .build(&[]);
        self.symmetric_psd("truth.Q", &tQ, false)?;
        self.symmetric_psd("truth.R", &tR, false)?;

        let params = self.params(&s.params)?;
        let (fF, fA) = match self.dynamics("filter", &f.F, &f.A, dt, Some(n))? {
            Some(d) => d,
            None => (tF.clone(), tA.clone()),
        };
        let fH = match &f.H {
            Some(h) => self.matrix("filter.H", h, Some(m), Some(n))?,
            None => tH.clone(),
        };
        let fx0 = match &f.x0 {
            Some(x) => self.vector("filter.x0", x, n)?,
            None => tx0.clone(),
        };
        let (fP0, p0_field) = match &f.P0 {
            Some(p) => (self.matrix("filter.P0", p, Some(n), Some(n))?, "filter.P0"),
            None => (tP0.clone(), "truth.P0 (used as filter.P0)"),
        };
        self.symmetric_psd(p0_field, &fP0, true)?;
        let q = self.cov_model("filter.Q", &f.Q, n, true, dt, fA.as_ref(), Some(&params))?;
        let r = self.cov_model("filter.R", &f.R, m, false, dt, None, Some(&params))?;
        for (i, p) in params.params.iter().enumerate() {
            if !q.uses(i) && !r.uses(i) {
                return self.err(
                    format!("params.{}", p.name),
                    "not used by any filter.Q or filter.R term",
                );
            }
        }
        let truth = LinearGaussianModel::new(tF, tH, tQ, tR, tx0, tP0)
            .map_err(|e| FileError::new(self.file, format!("truth.{}", e.which), e.to_string()))?;
        let state_names = self.names("state_names", &s.state_names, n, "x")?;
        let measurement_names = self.names("measurement_names", &s.measurement_names, m, "z")?;
        Ok(LinearExperiment {
            definition: Definition {
                info,
                params,
                state_names,
                measurement_names,
                mc,
            },
            truth,
            filter: FilterModel {
                F: fF,
                H: fH,
                x0: fx0,
                P0: fP0,
                q,
                r,
            },
        })
    }
}
