//! What the commands that judge a filter by its consistency report share in their
//! renderings: its table cells, its HTML sections, its plots.

pub(crate) mod cells;
pub(crate) mod html;
pub mod plots;
