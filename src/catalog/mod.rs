//! The catalog of named nonlinear models a problem file selects with `[model] name = "…"`.
//!
//! Each entry is a truth model of higher fidelity than the filter it is paired with
//! (continuous dynamics integrated with its own RK4 step, sensors that come and go) and a
//! filter family (EKF or UKF) whose noise is set by named parameters. The problem loader
//! reads `[model]` and `[params]`, and builds the entry through [`CatalogEntry::build`];
//! the engine then sees only the [`TruthModel`] and [`Filter`] traits, which user models
//! implement the same way.

pub mod ctrv;
mod entry;
pub mod ins_gnss;
pub mod orbit2d;

pub use entry::{
    Builder, CatalogEntry, CatalogModel, ModelContext, ModelError, ParamInfo, parse_table, positive,
};

/// Every named model, in the order error messages list them.
pub fn entries() -> [CatalogEntry; 3] {
    [ctrv::ENTRY, orbit2d::ENTRY, ins_gnss::ENTRY]
}

/// The entry called `name`.
pub fn find(name: &str) -> Option<CatalogEntry> {
    entries().into_iter().find(|e| e.name == name)
}
