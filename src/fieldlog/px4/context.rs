//! What the PX4 reader knows while it reads one log ([`Ctx`]): the topics, the options, the
//! land detector's rows, the time origin, the logged rates.

use std::collections::BTreeMap;

use super::read::Read;
use crate::fieldlog::ReadOptions;

/// Largest gap between an innovations row and the variances row it is paired with, µs.
pub(super) const PAIR_WITHIN_US: u64 = 50_000;

/// Whether the vehicle is in the air at `t` (µs): the latest land-detector row at or
/// before `t` says not landed; before the first row, on the ground.
pub(super) fn in_air(land: &[(u64, bool)], t: u64) -> bool {
    let i = land.partition_point(|r| r.0 <= t);
    i > 0 && !land[i - 1].1
}

/// What the reader knows while it reads one log.
pub(super) struct Ctx<'a> {
    pub(super) read: &'a Read,
    pub(super) options: &'a ReadOptions,
    pub(super) land: Vec<(u64, bool)>,
    pub(super) origin: u64,
    pub(super) rates: BTreeMap<&'static str, f64>,
    /// No parameter or topic confirms that EKF2 published the innovations.
    pub(super) publisher_assumed: bool,
}

impl Ctx<'_> {
    pub(super) fn secs(&self, t: u64) -> f64 {
        (t as f64 - self.origin as f64) * 1e-6
    }
}
