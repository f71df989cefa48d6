//! The streaming side of the field-log tests: each sensor's updates are folded into sums as
//! they are read (a finished log and a log still being written alike), so memory does not
//! grow with the length of the log beyond the decimated series kept for the plots.

use std::collections::HashMap;

use statrs::distribution::{ChiSquared, ContinuousCDF};

use super::settings::NisSettings;
use crate::stats::chi2_inv;

mod sensor;

use sensor::add_to_histogram;
pub use sensor::{Dropped, SensorInfo, SeriesPoint};
pub(super) use sensor::{HIST_BINS, SensorSums};

/// Most outliers of a sensor kept by time for the plots (all are counted).
const OUTLIERS_KEPT: usize = 1000;
/// Most sensors (PX4: channels of every estimator instance) one analysis takes: each costs a
/// few kilobytes and a block of the report, and a real log has at most a few hundred.
pub const MAX_SENSORS: usize = 10_000;

/// Why the analyzer refused a sensor or an update.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum AnalyzerError {
    /// A sensor seen before with another number of components.
    #[error("sensor {sensor} has {here} components here, {before} before")]
    Components {
        /// Its name.
        sensor: String,
        /// Components now.
        here: usize,
        /// Components before.
        before: usize,
    },
    /// One sensor more than [`MAX_SENSORS`] (its name, as an error quotes it).
    #[error("more than {MAX_SENSORS} sensors (a new one, '{0}'): too many to judge")]
    TooManySensors(String),
    /// An update of a sensor index the analyzer does not have.
    #[error("no sensor {0}")]
    NoSensor(usize),
    /// Degrees of freedom outside 1..=64.
    #[error("{sensor}: dof {dof} is not in 1..=64")]
    Dof {
        /// The sensor.
        sensor: String,
        /// The update's degrees of freedom.
        dof: usize,
    },
    /// A NIS that is negative or not finite, or a time that is not finite.
    #[error("{sensor}: NIS {nis} at time {time}")]
    Nis {
        /// The sensor.
        sensor: String,
        /// The update's NIS.
        nis: f64,
        /// Its time.
        time: f64,
    },
    /// Normalized innovations not one finite value per component.
    #[error("{sensor}: {given} normalized innovations for {components} components")]
    Normalized {
        /// The sensor.
        sensor: String,
        /// Values given.
        given: usize,
        /// The sensor's components.
        components: usize,
    },
}

/// One update (fusion) of a sensor.
#[derive(Debug, Clone, PartialEq)]
pub struct Update {
    /// Time, seconds (any origin; increasing within a sequence).
    pub time: f64,
    /// `ν' S⁻¹ ν`.
    pub nis: f64,
    /// Its degrees of freedom (the measurement dimension), ≥ 1.
    pub dof: usize,
    /// `ν_j/√S_jj` per component, when the log gives ν and S.
    pub u: Option<Vec<f64>>,
    /// `√S_jj` per component, in the measurement's units, when the log gives S: with `u` it
    /// gives the innovation itself for the plots.
    pub sd: Option<Vec<f64>>,
}

/// Quantiles and truncated moments of `χ²(m)` for one m.
#[derive(Debug, Clone, Copy)]
pub(super) struct DofQuantiles {
    /// Per-update interval at α.
    pub lower: f64,
    pub upper: f64,
    /// Outlier gate `χ²⁻¹(1 − p, m)`.
    pub gate: f64,
    /// Mean and variance of `χ²(m)` conditioned on not exceeding the gate.
    pub mean: f64,
    pub var: f64,
    /// Histogram range `χ²⁻¹(0.999, m)`.
    pub hist_top: f64,
}

impl DofQuantiles {
    fn new(m: usize, alpha: f64, gate_p: f64) -> Self {
        let mf = m as f64;
        let gate = chi2_inv(1.0 - gate_p, mf);
        let cdf = |k: f64| {
            ChiSquared::new(k)
                .expect("positive degrees of freedom")
                .cdf(gate)
        };
        // E[X; X ≤ g] = m F_{m+2}(g) and E[X²; X ≤ g] = m(m+2) F_{m+4}(g) for X ~ χ²(m).
        let f0 = cdf(mf);
        let mean = mf * cdf(mf + 2.0) / f0;
        let second = mf * (mf + 2.0) * cdf(mf + 4.0) / f0;
        DofQuantiles {
            lower: chi2_inv(alpha / 2.0, mf),
            upper: chi2_inv(1.0 - alpha / 2.0, mf),
            gate,
            mean,
            var: (second - mean * mean).max(0.0),
            hist_top: chi2_inv(0.999, mf),
        }
    }
}

/// Folds the updates of a log's sensors into their sums.
#[derive(Debug, Clone)]
pub struct NisAnalyzer {
    pub(super) settings: NisSettings,
    pub(super) sensors: Vec<SensorSums>,
    by_name: HashMap<String, usize>,
    quantiles: HashMap<usize, DofQuantiles>,
    window_bounds: HashMap<usize, (f64, f64)>,
}

impl NisAnalyzer {
    /// An analyzer with `settings` and no sensors yet.
    pub fn new(settings: NisSettings) -> Self {
        NisAnalyzer {
            settings,
            sensors: Vec::new(),
            by_name: HashMap::new(),
            quantiles: HashMap::new(),
            window_bounds: HashMap::new(),
        }
    }

    /// The settings.
    pub fn settings(&self) -> &NisSettings {
        &self.settings
    }

    /// The index of sensor `info.name`, adding it when new. `Err` when a sensor of that
    /// name was seen with other components, or when it would be one more than
    /// [`MAX_SENSORS`].
    pub fn sensor(&mut self, info: SensorInfo) -> Result<usize, AnalyzerError> {
        if let Some(&i) = self.by_name.get(&info.name) {
            let known = &self.sensors[i].info;
            if known.components.len() != info.components.len() {
                return Err(AnalyzerError::Components {
                    sensor: info.name,
                    here: info.components.len(),
                    before: known.components.len(),
                });
            }
            return Ok(i);
        }
        let i = self.sensors.len();
        if i >= MAX_SENSORS {
            return Err(AnalyzerError::TooManySensors(crate::records::shown_up_to(
                &info.name, 40,
            )));
        }
        self.by_name.insert(info.name.clone(), i);
        self.sensors.push(SensorSums::new(info));
        Ok(i)
    }

    /// Number of sensors seen.
    pub fn sensor_count(&self) -> usize {
        self.sensors.len()
    }

    /// Add rows the reader dropped for sensor `i`.
    pub fn drop_rows(&mut self, i: usize, d: Dropped) {
        let s = &mut self.sensors[i].dropped;
        s.repeats += d.repeats;
        s.idle += d.idle;
        s.invalid += d.invalid;
        s.on_ground += d.on_ground;
        s.zero_innovation += d.zero_innovation;
    }

    /// A new sequence starts (another file, run or estimator reset): whiteness pairs and the
    /// moving window do not reach across it.
    pub fn break_sequences(&mut self) {
        for s in &mut self.sensors {
            s.prev_time = None;
            s.ring.clear();
            s.window.clear();
            s.window_nis = 0.0;
            s.window_dof = 0;
        }
    }

    pub(super) fn quantiles(&mut self, m: usize) -> DofQuantiles {
        let (alpha, gate) = (self.settings.alpha(), self.settings.gate());
        *self
            .quantiles
            .entry(m)
            .or_insert_with(|| DofQuantiles::new(m, alpha, gate))
    }

    fn window_bounds(&mut self, dof: usize, count: usize) -> (f64, f64) {
        let alpha = self.settings.alpha();
        let (lo, hi) = *self.window_bounds.entry(dof).or_insert_with(|| {
            (
                chi2_inv(alpha / 2.0, dof as f64),
                chi2_inv(1.0 - alpha / 2.0, dof as f64),
            )
        });
        (lo / count as f64, hi / count as f64)
    }

    /// Add an update of sensor `i`: a finite NIS ≥ 0 at a finite time, dof in 1..=64, `u` (if
    /// any) of the sensor's length with finite entries; `Err` says which is not.
    pub fn push(&mut self, i: usize, up: Update) -> Result<(), AnalyzerError> {
        // The readers check their rows; a Rust caller gets the same checks here, so that
        // nothing below can index out of range or average a NaN.
        let Some(sensor) = self.sensors.get(i) else {
            return Err(AnalyzerError::NoSensor(i));
        };
        if !(1..=64).contains(&up.dof) {
            return Err(AnalyzerError::Dof {
                sensor: sensor.info.name.clone(),
                dof: up.dof,
            });
        }
        if !(up.nis.is_finite() && up.nis >= 0.0 && up.time.is_finite()) {
            return Err(AnalyzerError::Nis {
                sensor: sensor.info.name.clone(),
                nis: up.nis,
                time: up.time,
            });
        }
        if let Some(u) = &up.u
            && (u.len() != sensor.info.components.len() || u.iter().any(|x| !x.is_finite()))
        {
            return Err(AnalyzerError::Normalized {
                sensor: sensor.info.name.clone(),
                given: u.len(),
                components: sensor.info.components.len(),
            });
        }
        self.push_checked(i, up);
        Ok(())
    }

    fn push_checked(&mut self, i: usize, up: Update) {
        let q = self.quantiles(up.dof);
        let lags = self.settings.lags();
        let window = self.settings.window();
        let s = &mut self.sensors[i];
        s.updates += 1;
        s.nis_sum_all += up.nis;
        s.add_time(up.time);
        if up.nis >= q.lower && up.nis <= q.upper {
            s.inside += 1;
        }
        add_to_histogram(s, up.dof, up.nis, q.hist_top);
        let outlier = up.nis > q.gate;
        let innovation = match (&up.u, &up.sd) {
            (Some(u), Some(sd)) if !u.is_empty() && !sd.is_empty() => Some((u[0] * sd[0], sd[0])),
            _ => None,
        };
        let u = if outlier { None } else { up.u };
        if let Some(u) = &u {
            s.add_components(u);
        }
        if lags > 0 {
            if s.ring.len() == lags {
                s.ring.pop_front();
            }
            s.ring.push_back(u);
        }
        if outlier {
            s.outliers += 1;
            if s.outlier_points.len() < OUTLIERS_KEPT {
                s.outlier_points.push((up.time, up.nis));
            }
            return;
        }
        s.gated += 1;
        s.nis_sum += up.nis;
        s.dof_sum += up.dof as f64;
        s.mean_sum += q.mean;
        s.var_sum += q.var;
        let full = s.slide_window(window, up.time, up.nis, up.dof);
        let point_window = if full && !s.window.is_empty() {
            Some(self.judge_window(i, up.time))
        } else {
            None
        };
        self.sensors[i].add_series_point(SeriesPoint {
            t: up.time,
            nis: up.nis,
            window: point_window.map(|w| w.0),
            lower: point_window.map(|w| w.1),
            upper: point_window.map(|w| w.2),
            innovation,
        });
    }

    /// Sensor `i`'s full moving window at `time`, judged against its bounds: its average
    /// and the bounds `(avg, lo, hi)`, counted among the sensor's windows.
    fn judge_window(&mut self, i: usize, time: f64) -> (f64, f64, f64) {
        let s = &self.sensors[i];
        let (count, dof, sum) = (s.window.len(), s.window_dof, s.window_nis);
        let avg = sum.max(0.0) / count as f64;
        let (lo, hi) = self.window_bounds(dof, count);
        let s = &mut self.sensors[i];
        s.windows += 1;
        if avg < lo || avg > hi {
            s.windows_outside += 1;
        }
        if s.window_min.is_none_or(|(v, _)| avg < v) {
            s.window_min = Some((avg, time));
        }
        if s.window_max.is_none_or(|(v, _)| avg > v) {
            s.window_max = Some((avg, time));
        }
        s.last_window = Some((avg, lo, hi));
        (avg, lo, hi)
    }
}
