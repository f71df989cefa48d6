//! A live NIS monitor inside a Rust program: a filter hands it each update's innovation and
//! S per sensor, and it answers at any time with the statistics `autotune nis` would give
//! for the rows seen so far (and at the end, its whole report).
//!
//! The numbers are those of the field-log tests (module [`crate::fieldlog`]), made by the
//! same streaming sums ([`NisAnalyzer`]) fed through the same row checks as a CSV log:
//! - the **running NIS** of a sensor is its average `ν' S⁻¹ ν` over its updates inside the
//!   outlier gate, against the single-run interval of that average at the per-test level
//!   `1 − (1 − α)^{1/tests}` (Šidák over every test of every sensor), so that a consistent
//!   filter's monitor fails with probability at most α over the whole log;
//! - the **window** is the average NIS over the last K gated updates of the sensor (or those
//!   within the last w seconds), against its own two-sided `χ²` interval at α,
//!   `[χ²⁻¹(α/2, Σm)/K, χ²⁻¹(1 − α/2, Σm)/K]` with `Σm` the degrees of freedom in the window
//!   (Bar-Shalom, Li, Kirubarajan 2001, §5.4.2). Windows overlap and each is tested at α, so
//!   about α of them fall outside by chance: the window shows where the filter is now, the
//!   sensor's verdict judges the log;
//! - the **verdict** and the **advice** (a [`Finding`]) are the report's, in its words.
//!
//! The verdict so far is the one the log would get if it ended now, each time at α. Looking
//! at it many times during a run and raising an alarm at the first failure is a sequential
//! test whose false-alarm rate grows with the looks; the final report holds α.
//!
//! [`Finding`]: crate::stats::Finding

use std::collections::HashMap;

use nalgebra::{Dim, Matrix, RawStorage};

use super::LogSource;
use super::analysis::{MAX_SENSORS, NisAnalyzer};
use super::ingest::Ingest;
use super::ingest::{MAX_DIM, Row};
use super::report::NisReport;
use super::settings::NisSettings;
use super::text::{check_sensor, symmetric};
use crate::records::SensorRecord;
use crate::stats::Interval;

mod status;

pub use status::{MonitorStatus, SensorStatus, WindowStatus};

/// Watches a running filter's innovations, sensor by sensor, with the tests of
/// `autotune nis`.
///
/// Feed it every update ([`NisMonitor::update`]); ask it for the [`MonitorStatus`] whenever
/// a status line is due, and for the [`NisReport`] at the end: the report is the one
/// `autotune nis` makes from a CSV log of the same rows (docs/fieldlog.md), but for its
/// `sources` entry, which names the monitor instead of a file.
///
/// ```
/// use autotune::SimRng;
/// use autotune::{MonitorError, NisMonitor, NisSettings};
/// use autotune::Verdict;
/// use rand::{RngExt, SeedableRng};
/// use rand_distr::StandardNormal;
///
/// let mut monitor = NisMonitor::new(NisSettings::default());
/// let mut rng = SimRng::seed_from_u64(7);
/// // A GPS fix every 0.1 s whose filter believes S = diag(4, 4) m², while its innovations
/// // spread twice as wide (σ = 4 m): the filter is overconfident.
/// let s = [4.0, 0.0, 0.0, 4.0]; // m², row-major 2 × 2
/// for k in 0..400 {
///     let t = 0.1 * k as f64; // s
///     let nu = [
///         4.0 * rng.sample::<f64, _>(StandardNormal), // m
///         4.0 * rng.sample::<f64, _>(StandardNormal),
///     ];
///     monitor.update("gps", t, &nu, &s)?;
/// }
/// let status = monitor.status();
/// let gps = status.sensor("gps").unwrap();
/// assert_eq!(gps.verdict, Verdict::Overconfident);
/// assert!(gps.nis > gps.interval.upper);
/// println!("{gps}"); // gps: NIS … in […] (window 50: … in [1.484, 2.591]) overconfident
///
/// // What `autotune nis` would say of a log of these rows.
/// let report = monitor.report();
/// assert_eq!(report.sensors[0].updates, 400);
/// # Ok::<(), MonitorError>(())
/// ```
#[derive(Debug, Clone)]
pub struct NisMonitor {
    analyzer: NisAnalyzer,
    ingest: Ingest,
    /// Per sensor: its dimension and the time of its latest update (s).
    known: HashMap<String, (usize, f64)>,
    updates: usize,
}

impl Default for NisMonitor {
    /// A monitor with the settings `autotune nis` uses by default.
    fn default() -> Self {
        NisMonitor::new(NisSettings::default())
    }
}

impl NisMonitor {
    /// A monitor testing at `settings` (the family-wise α, the outlier gate, the moving
    /// window and the whiteness lags, as `autotune nis --alpha --gate --window --lags`).
    pub fn new(settings: NisSettings) -> Self {
        NisMonitor {
            analyzer: NisAnalyzer::new(settings),
            ingest: Ingest::default(),
            known: HashMap::new(),
            updates: 0,
        }
    }

    /// Add one update (fusion) of `sensor` at `time` (seconds, any origin, not earlier than
    /// the sensor's previous update): its innovation `nu` = ν = z − h(x̂⁻) (m entries, in the
    /// measurement's units, 1 ≤ m ≤ 64) and its covariance `s` = S = H P⁻ H' + R (m × m,
    /// row-major, units²; symmetric to a relative 1e-9 and positive definite).
    ///
    /// A sensor keeps its dimension. An update that is refused leaves the monitor as it was.
    pub fn update(
        &mut self,
        sensor: &str,
        time: f64,
        nu: &[f64],
        s: &[f64],
    ) -> Result<(), MonitorError> {
        let m = nu.len();
        self.check(sensor, time, m)?;
        if s.len() != m * m {
            return Err(MonitorError::CovarianceLength {
                sensor: sensor.to_string(),
                m,
                len: s.len(),
            });
        }
        self.add(sensor, time, nu, s.to_vec())
    }

    /// [`NisMonitor::update`] with S as an m × m nalgebra matrix (fixed-size, dynamic or a
    /// view).
    pub fn update_matrix<R: Dim, C: Dim, St: RawStorage<f64, R, C>>(
        &mut self,
        sensor: &str,
        time: f64,
        nu: &[f64],
        s: &Matrix<f64, R, C, St>,
    ) -> Result<(), MonitorError> {
        let m = nu.len();
        self.check(sensor, time, m)?;
        let (rows, cols) = s.shape();
        if (rows, cols) != (m, m) {
            return Err(MonitorError::CovarianceShape {
                sensor: sensor.to_string(),
                m,
                rows,
                cols,
            });
        }
        let row_major = (0..m)
            .flat_map(|i| (0..m).map(move |j| (i, j)))
            .map(|ij| s[ij])
            .collect();
        self.add(sensor, time, nu, row_major)
    }

    /// The checks that need neither S nor the analyzer: name, dimension, time.
    fn check(&self, sensor: &str, time: f64, m: usize) -> Result<(), MonitorError> {
        check_sensor(sensor).map_err(|e| MonitorError::SensorName(e.to_string()))?;
        let name = || sensor.to_string();
        if !(1..=MAX_DIM).contains(&m) {
            return Err(MonitorError::InnovationLength {
                sensor: name(),
                len: m,
            });
        }
        if !time.is_finite() {
            return Err(MonitorError::NotFinite {
                sensor: name(),
                what: "the time",
            });
        }
        match self.known.get(sensor) {
            Some(&(before, _)) if before != m => Err(MonitorError::DimensionChanged {
                sensor: name(),
                m,
                before,
            }),
            Some(&(_, previous)) if time < previous => Err(MonitorError::TimeBackwards {
                sensor: name(),
                time,
                previous,
            }),
            Some(_) => Ok(()),
            None if self.analyzer.sensor_count() >= MAX_SENSORS => {
                Err(MonitorError::TooManySensors { sensor: name() })
            }
            None => Ok(()),
        }
    }

    /// Check the numbers and fold the update in, as the CSV reader does a row.
    fn add(
        &mut self,
        sensor: &str,
        time: f64,
        nu: &[f64],
        s: Vec<f64>,
    ) -> Result<(), MonitorError> {
        let m = nu.len();
        let name = || sensor.to_string();
        if nu.iter().any(|v| !v.is_finite()) {
            return Err(MonitorError::NotFinite {
                sensor: name(),
                what: "ν",
            });
        }
        if s.iter().any(|v| !v.is_finite()) {
            return Err(MonitorError::NotFinite {
                sensor: name(),
                what: "S",
            });
        }
        symmetric(&s, m).map_err(|(row, col)| MonitorError::NotSymmetric {
            sensor: name(),
            time,
            row,
            col,
        })?;
        let row = Row {
            time,
            sensor: name(),
            record: SensorRecord::Raw { nu: nu.to_vec(), s },
        };
        // The checks above leave the analyzer only what it checks before it changes
        // anything: whether S is positive definite and the NIS finite.
        self.ingest
            .add(row, &mut self.analyzer)
            .map_err(|(_, reason)| MonitorError::Rejected {
                sensor: name(),
                time,
                reason,
            })?;
        self.known.insert(name(), (m, time));
        self.updates += 1;
        Ok(())
    }

    /// Updates taken so far, all sensors.
    pub fn updates(&self) -> usize {
        self.updates
    }

    /// The statistics so far, per sensor, and the verdict. Each call computes the report of
    /// everything seen (about half a millisecond per sensor on a long log, where an update
    /// costs a few microseconds): call it when a status line is due, not at every update.
    pub fn status(&self) -> MonitorStatus {
        let r = self.analyzer.report();
        let window = self.analyzer.settings().window();
        let sensors = r
            .sensors
            .iter()
            .map(|s| SensorStatus {
                name: s.name.clone(),
                updates: s.updates,
                outliers: s.outliers,
                nis: s.nis.mean,
                interval: s.nis.interval,
                window: s.window.last.map(|(nis, lower, upper)| WindowStatus {
                    window,
                    nis,
                    interval: Interval { lower, upper },
                }),
                verdict: s.verdict,
                advice: s.finding.clone(),
            })
            .collect();
        MonitorStatus {
            time: r
                .sensors
                .iter()
                .map(|s| s.time_span.1)
                .fold(f64::NAN, f64::max),
            updates: self.updates,
            sensors,
            verdict: r.verdict,
        }
    }

    /// Everything `autotune nis` reports about a CSV log of the updates so far
    /// (docs/fieldlog.md), with one source: path `live`, format `monitor`, a row per update.
    pub fn report(&self) -> NisReport {
        let mut r = self.analyzer.report();
        r.sources = vec![LogSource {
            path: "live".into(),
            format: "monitor".into(),
            rows: self.updates,
            skipped_rows: 0,
            notes: Vec::new(),
            px4: None,
        }];
        r
    }
}

/// Why [`NisMonitor::update`] refused an update. The monitor is left as it was.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum MonitorError {
    /// The sensor name is empty, longer than 64 bytes, or has control characters.
    #[error("sensor name: {0}")]
    SensorName(String),
    /// ν has no entries, or more than 64.
    #[error("{sensor}: ν has {len} entries (a sensor has 1 to 64 components)")]
    InnovationLength {
        /// Sensor name.
        sensor: String,
        /// Entries of ν.
        len: usize,
    },
    /// S as a slice does not have m² entries.
    #[error("{sensor}: S has {len} entries for ν of {m}: expected {m}×{m}, row-major")]
    CovarianceLength {
        /// Sensor name.
        sensor: String,
        /// Entries of ν.
        m: usize,
        /// Entries of S.
        len: usize,
    },
    /// S as a matrix is not m × m.
    #[error("{sensor}: S is {rows}×{cols} for ν of {m}: expected {m}×{m}")]
    CovarianceShape {
        /// Sensor name.
        sensor: String,
        /// Entries of ν.
        m: usize,
        /// Rows of S.
        rows: usize,
        /// Columns of S.
        cols: usize,
    },
    /// The sensor's earlier updates had another dimension.
    #[error("{sensor}: ν has {m} entries where the sensor's earlier updates had {before}")]
    DimensionChanged {
        /// Sensor name.
        sensor: String,
        /// Entries of ν now.
        m: usize,
        /// Entries of ν before.
        before: usize,
    },
    /// The time is before the sensor's previous update.
    #[error("{sensor}: time {time:?} s is before the sensor's previous update at {previous:?} s")]
    TimeBackwards {
        /// Sensor name.
        sensor: String,
        /// This update's time, s.
        time: f64,
        /// The previous update's time, s.
        previous: f64,
    },
    /// The time, ν or S has an entry that is NaN or infinite.
    #[error("{sensor}: {what} is not finite")]
    NotFinite {
        /// Sensor name.
        sensor: String,
        /// "the time", "ν" or "S".
        what: &'static str,
    },
    /// `S_ij` and `S_ji` differ by more than a relative 1e-9.
    #[error(
        "{sensor} at {time:?} s: S_{row}_{col} differs from S_{col}_{row}: S must be symmetric"
    )]
    NotSymmetric {
        /// Sensor name.
        sensor: String,
        /// Time, s.
        time: f64,
        /// Row (1-based).
        row: usize,
        /// Column (1-based).
        col: usize,
    },
    /// A new sensor beyond the most one analysis takes.
    #[error("{sensor}: a new sensor beyond the {} a monitor takes", MAX_SENSORS)]
    TooManySensors {
        /// Sensor name.
        sensor: String,
    },
    /// The statistics refused the update: S is not positive definite, or `ν' S⁻¹ ν`
    /// overflowed.
    #[error("{sensor} at {time:?} s: {reason}")]
    Rejected {
        /// Sensor name.
        sensor: String,
        /// Time, s.
        time: f64,
        /// Why, in words.
        reason: String,
    },
}
