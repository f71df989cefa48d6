//! `ins_gnss` (placeholder until implemented).

use super::{CatalogEntry, CatalogModel, ModelContext, ModelError};

/// The catalog entry.
pub const ENTRY: CatalogEntry = CatalogEntry {
    name: "ins_gnss",
    about: "not implemented yet",
    params: &[],
    build,
};

fn build(_t: &toml::Table, _c: &ModelContext) -> Result<Box<dyn CatalogModel>, ModelError> {
    Err(ModelError::new("", "not implemented yet"))
}
