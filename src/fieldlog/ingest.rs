//! Parsed rows of a generic log into the analyzer, and the count of rows skipped: shared by
//! the batch reader and the follower.

use std::collections::HashMap;

use super::analysis::{NisAnalyzer, SensorInfo, Update};
use crate::input::FileError;
use crate::records::{SensorRecord, normalize_sensor};

/// Largest measurement dimension of a sensor (and degrees of freedom of a precomputed NIS).
pub(super) const MAX_DIM: usize = 64;

/// What one row says.
#[derive(Debug, Clone, PartialEq)]
pub(super) struct Row {
    pub time: f64,
    pub sensor: String,
    pub record: SensorRecord,
}

/// Skipped rows listed by line number in the notes.
const LISTED: usize = 5;

/// Feeds parsed rows into an analyzer: sensors registered on first sight, time order per
/// sensor checked, numbers normalized as the records reader does.
#[derive(Debug, Default, Clone)]
pub(super) struct Ingest {
    last_time: HashMap<String, f64>,
}

impl Ingest {
    /// Add `row`; `Err((field, message))` for a row that cannot be judged.
    pub(super) fn add(&mut self, row: Row, an: &mut NisAnalyzer) -> Result<(), (String, String)> {
        let (dim, components) = match &row.record {
            SensorRecord::Raw { nu, .. } => (nu.len(), true),
            SensorRecord::Normalized { dof, .. } => (dof.max(1.0) as usize, false),
        };
        let n = match normalize_sensor(&row.record, dim, components) {
            Ok(Ok(n)) => n,
            Ok(Err(why)) => return Err((field_of(&row.record), why.to_string())),
            Err(why) => return Err((field_of(&row.record), why.to_string())),
        };
        if n.dof.fract() != 0.0 {
            return Err(("dof".into(), format!("{} is not a whole number", n.dof)));
        }
        // A sensor has at most MAX_DIM components, given as ν or as a precomputed NIS; the
        // quantiles of each distinct dof cost the analyzer up to a millisecond, so a larger
        // bound would let a log of distinct dofs run for many minutes.
        if n.dof > MAX_DIM as f64 {
            return Err((
                "dof".into(),
                format!(
                    "{} is more than {MAX_DIM}, the largest dimension of a sensor",
                    n.dof
                ),
            ));
        }
        if let Some(&t) = self.last_time.get(&row.sensor)
            && row.time < t
        {
            return Err((
                "time".into(),
                // `{:?}`: the shortest exact form, in exponent form when huge.
                format!(
                    "{:?} is before this sensor's previous update at {t:?}",
                    row.time
                ),
            ));
        }
        let names = if components {
            (1..=dim).map(|j| format!("{}_{j}", row.sensor)).collect()
        } else {
            Vec::new()
        };
        let i = an
            .sensor(SensorInfo {
                name: row.sensor.clone(),
                components: names,
                group: String::new(),
            })
            .map_err(|e| ("sensor".to_string(), e.to_string()))?;
        self.last_time.insert(row.sensor, row.time);
        an.push(
            i,
            Update {
                time: row.time,
                nis: n.nis,
                dof: n.dof as usize,
                u: n.u,
                sd: None,
            },
        )
        .map_err(|e| ("nu".to_string(), e.to_string()))
    }
}

fn field_of(r: &SensorRecord) -> String {
    match r {
        SensorRecord::Raw { .. } => "S".into(),
        SensorRecord::Normalized { .. } => "nis".into(),
    }
}

/// Counts and lists skipped rows for the notes.
#[derive(Debug, Default)]
pub(super) struct Skips {
    pub count: usize,
    first: Vec<String>,
}

impl Skips {
    pub(super) fn add(&mut self, e: &FileError) {
        self.count += 1;
        if self.first.len() < LISTED {
            self.first.push(format!(
                "line {}: {}{}",
                e.line.unwrap_or(0),
                if e.field.is_empty() {
                    String::new()
                } else {
                    format!("{}: ", e.field)
                },
                e.message
            ));
        }
    }

    pub(super) fn note(&self) -> Option<String> {
        (self.count > 0).then(|| {
            format!(
                "{} malformed rows skipped (first: {})",
                self.count,
                self.first.join("; ")
            )
        })
    }
}
