//! `ctrv_radar_lidar` (placeholder until implemented).

use super::{CatalogEntry, CatalogModel, ModelContext, ModelError};

/// The catalog entry.
pub const ENTRY: CatalogEntry = CatalogEntry {
    name: "ctrv_radar_lidar",
    about: "not implemented yet",
    params: &[],
    build,
};

fn build(_t: &toml::Table, _c: &ModelContext) -> Result<Box<dyn CatalogModel>, ModelError> {
    Err(ModelError::new("", "not implemented yet"))
}
