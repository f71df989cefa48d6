//! The streaming side of the field-log tests: each sensor's updates are folded into sums as
//! they are read (a finished log and a log still being written alike), so memory does not
//! grow with the length of the log beyond the decimated series kept for the plots.

use std::collections::{HashMap, VecDeque};

use statrs::distribution::{ChiSquared, ContinuousCDF};

use super::settings::{NisSettings, Window};
use crate::stats::chi2_inv;

/// Most points of a sensor's series kept for the plots; beyond, every other point is
/// dropped and the stride doubles.
const SERIES_CAP: usize = 4000;
/// Most outliers of a sensor kept by time for the plots (all are counted).
const OUTLIERS_KEPT: usize = 1000;
/// Bins of the NIS histogram over `[0, χ²⁻¹(0.999, m)]`.
pub(super) const HIST_BINS: usize = 30;
/// Distinct degrees of freedom of a sensor given a histogram.
const HIST_DOFS: usize = 8;
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

/// A sensor of a log: its name, its components, and the estimator it belongs to.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SensorInfo {
    /// Name, e.g. `gps` or `ekf0.gps_hpos[1]`.
    pub name: String,
    /// Component names (`gps_1`, `gps_2`); empty when the log gives the NIS alone.
    pub components: Vec<String>,
    /// The estimator it belongs to (`ekf0` for PX4 instance 0; empty for a single filter):
    /// the advice compares a sensor with the others of its estimator.
    pub group: String,
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

/// What the reader dropped before the statistics, per sensor (PX4 logs say it; other
/// formats only skip rows).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize)]
pub struct Dropped {
    /// Rows repeating the previous row's values (a publication, not a fusion).
    pub repeats: usize,
    /// Rows where the channel was not fused (innovation and variance both zero).
    pub idle: usize,
    /// Rows with a non-finite innovation or a variance that is not positive.
    pub invalid: usize,
    /// Rows outside the in-air time, when restricted to it.
    pub on_ground: usize,
    /// Rows whose innovation is exactly 0 beside a positive variance: no draw of `N(0, S)`
    /// is exactly 0, so such a row is a placeholder, not a fusion (PX4 logs).
    pub zero_innovation: usize,
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

/// One point of a sensor's series: an update's NIS and the moving window's average and
/// interval after it.
#[derive(Debug, Clone, Copy, serde::Serialize)]
pub struct SeriesPoint {
    /// Time, seconds.
    pub t: f64,
    /// The update's NIS.
    pub nis: f64,
    /// The window's average NIS (absent until the window has filled).
    pub window: Option<f64>,
    /// The window's interval at α.
    pub lower: Option<f64>,
    /// Upper end.
    pub upper: Option<f64>,
    /// The first component's innovation ν and its `√S`, in the measurement's units, when
    /// the log gives them.
    pub innovation: Option<(f64, f64)>,
}

/// The running sums of one sensor.
#[derive(Debug, Clone)]
pub(super) struct SensorSums {
    pub info: SensorInfo,
    pub dropped: Dropped,
    pub updates: usize,
    pub outliers: usize,
    pub gated: usize,
    pub nis_sum: f64,
    pub nis_sum_all: f64,
    pub dof_sum: f64,
    pub mean_sum: f64,
    pub var_sum: f64,
    pub inside: usize,
    pub first_time: Option<f64>,
    pub last_time: f64,
    /// The previous update's time in the current sequence (None after a break).
    prev_time: Option<f64>,
    /// Updates whose time is not after the previous update's of the same sequence.
    pub non_increasing: usize,
    /// Smallest and largest time seen.
    pub time_min: f64,
    pub time_max: f64,
    /// Where the moving window in seconds started filling; reset when time goes back, so a
    /// window never spans a jump backwards.
    window_start: Option<f64>,
    pub comp_sum: Vec<f64>,
    /// Σ ν_j/√S_jj per component over the updates inside the outlier gate (the zero-mean
    /// test's numerator; `comp_n` counts them).
    pub comp_mean_sum: Vec<f64>,
    pub comp_n: Vec<f64>,
    /// Whiteness sums per lag and component, index `(lag − 1) · m + j`; only as many lags
    /// as have been paired (a sensor of 64 components at 100 lags needs 200 kB, which a
    /// log of one update per sensor would otherwise allocate for every row).
    pub white_ab: Vec<f64>,
    pub white_a2: Vec<f64>,
    pub white_b2: Vec<f64>,
    pub white_pairs: Vec<f64>,
    /// The last L updates' normalized innovations (None: an outlier or no components).
    ring: VecDeque<Option<Vec<f64>>>,
    window: VecDeque<(f64, f64, usize)>,
    window_nis: f64,
    window_dof: usize,
    pub windows: usize,
    pub windows_outside: usize,
    pub window_min: Option<(f64, f64)>,
    pub window_max: Option<(f64, f64)>,
    pub last_window: Option<(f64, f64, f64)>,
    pub series: Vec<SeriesPoint>,
    stride: usize,
    skipped: usize,
    pub outlier_points: Vec<(f64, f64)>,
    pub hist: Vec<(usize, Vec<u64>, u64)>,
}

impl SensorSums {
    fn new(info: SensorInfo) -> Self {
        let m = info.components.len();
        SensorSums {
            info,
            dropped: Dropped::default(),
            updates: 0,
            outliers: 0,
            gated: 0,
            nis_sum: 0.0,
            nis_sum_all: 0.0,
            dof_sum: 0.0,
            mean_sum: 0.0,
            var_sum: 0.0,
            inside: 0,
            first_time: None,
            last_time: f64::NAN,
            prev_time: None,
            non_increasing: 0,
            time_min: f64::INFINITY,
            time_max: f64::NEG_INFINITY,
            window_start: None,
            comp_sum: vec![0.0; m],
            comp_mean_sum: vec![0.0; m],
            comp_n: vec![0.0; m],
            white_ab: Vec::new(),
            white_a2: Vec::new(),
            white_b2: Vec::new(),
            white_pairs: Vec::new(),
            ring: VecDeque::new(),
            window: VecDeque::new(),
            window_nis: 0.0,
            window_dof: 0,
            windows: 0,
            windows_outside: 0,
            window_min: None,
            window_max: None,
            last_window: None,
            series: Vec::new(),
            stride: 1,
            skipped: 0,
            outlier_points: Vec::new(),
            hist: Vec::new(),
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

impl SensorSums {
    /// Note an update's time: the span, the order within the sequence, and where a moving
    /// window in seconds starts.
    fn add_time(&mut self, time: f64) {
        if self.first_time.is_none() {
            self.first_time = Some(time);
        }
        self.last_time = time;
        if self.prev_time.is_some_and(|t| time <= t) {
            self.non_increasing += 1;
        }
        self.prev_time = Some(time);
        if self.window_start.is_none() {
            self.window_start = Some(time);
        }
        self.time_min = self.time_min.min(time);
        self.time_max = self.time_max.max(time);
    }

    /// Add the normalized innovations `u` of an update inside the gate: their sums per
    /// component, and the whiteness products with the last L of the same sequence.
    fn add_components(&mut self, u: &[f64]) {
        let m = u.len();
        let need = self.ring.len() * m;
        if self.white_ab.len() < need {
            for v in [
                &mut self.white_ab,
                &mut self.white_a2,
                &mut self.white_b2,
                &mut self.white_pairs,
            ] {
                v.resize(need, 0.0);
            }
        }
        for (back, prev) in self.ring.iter().rev().enumerate() {
            let Some(prev) = prev else { continue };
            let base = back * m;
            for j in 0..m {
                self.white_ab[base + j] += u[j] * prev[j];
                self.white_a2[base + j] += u[j] * u[j];
                self.white_b2[base + j] += prev[j] * prev[j];
                self.white_pairs[base + j] += 1.0;
            }
        }
        for (j, x) in u.iter().enumerate() {
            self.comp_sum[j] += x * x;
            self.comp_mean_sum[j] += x;
            self.comp_n[j] += 1.0;
        }
    }

    /// Move the moving window over gated updates to one at `time`; whether it is full. A
    /// window in seconds cannot reach across a jump back in time: it starts afresh there.
    fn slide_window(&mut self, window: Window, time: f64, nis: f64, dof: usize) -> bool {
        if matches!(window, Window::Seconds(_)) && self.window.back().is_some_and(|b| time < b.0) {
            self.window.clear();
            self.window_nis = 0.0;
            self.window_dof = 0;
            self.window_start = Some(time);
        }
        self.window.push_back((time, nis, dof));
        self.window_nis += nis;
        self.window_dof += dof;
        match window {
            Window::Updates(n) => {
                while self.window.len() > n {
                    evict(self);
                }
                self.window.len() == n
            }
            Window::Seconds(w) => {
                // A window whose updates all share one time spans no seconds: keeping them
                // all would grow without bound on a log whose clock stands still.
                while self
                    .window
                    .front()
                    .is_some_and(|f| time - f.0 > w || (f.0 >= time && self.window.len() > 1))
                {
                    evict(self);
                }
                // A time window counts once the sensor's data span it.
                self.window_start.is_some_and(|t0| time - t0 >= w)
            }
        }
    }

    /// Keep every `stride`-th point of the series, halving it (and doubling the stride)
    /// when it reaches [`SERIES_CAP`].
    fn add_series_point(&mut self, point: SeriesPoint) {
        self.skipped += 1;
        if self.skipped >= self.stride {
            self.skipped = 0;
            self.series.push(point);
            if self.series.len() >= SERIES_CAP {
                let kept: Vec<SeriesPoint> = self.series.iter().step_by(2).copied().collect();
                self.series = kept;
                self.stride *= 2;
            }
        }
    }
}

fn evict(s: &mut SensorSums) {
    if let Some((_, nis, dof)) = s.window.pop_front() {
        s.window_nis -= nis;
        s.window_dof -= dof;
    }
    if s.window.is_empty() {
        // Rounding must not leave a residue in an empty window.
        s.window_nis = 0.0;
    }
}

fn add_to_histogram(s: &mut SensorSums, dof: usize, nis: f64, top: f64) {
    let at = match s.hist.iter().position(|h| h.0 == dof) {
        Some(at) => at,
        None if s.hist.len() < HIST_DOFS => {
            s.hist.push((dof, vec![0; HIST_BINS], 0));
            s.hist.len() - 1
        }
        None => return,
    };
    let h = &mut s.hist[at];
    let bin = (nis / top * HIST_BINS as f64).floor();
    if bin >= HIST_BINS as f64 {
        h.2 += 1;
    } else {
        h.1[bin.max(0.0) as usize] += 1;
    }
}
