//! A sensor as the analysis sees it: what it is ([`SensorInfo`]), what the reader dropped of
//! it, and its running sums, with the window, series and histogram that fold one update in.
//! Apart from the analyzer so that the per-sensor bookkeeping reads on its own.

use std::collections::VecDeque;

use crate::fieldlog::settings::Window;

/// Most points of a sensor's series kept for the plots; beyond, every other point is
/// dropped and the stride doubles.
const SERIES_CAP: usize = 4000;

/// Bins of the NIS histogram over `[0, χ²⁻¹(0.999, m)]`.
pub(in crate::fieldlog) const HIST_BINS: usize = 30;
/// Distinct degrees of freedom of a sensor given a histogram.
const HIST_DOFS: usize = 8;

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
pub(in crate::fieldlog) struct SensorSums {
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
    pub(super) prev_time: Option<f64>,
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
    pub(super) ring: VecDeque<Option<Vec<f64>>>,
    pub(super) window: VecDeque<(f64, f64, usize)>,
    pub(super) window_nis: f64,
    pub(super) window_dof: usize,
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
    pub(super) fn new(info: SensorInfo) -> Self {
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

impl SensorSums {
    /// Note an update's time: the span, the order within the sequence, and where a moving
    /// window in seconds starts.
    pub(super) fn add_time(&mut self, time: f64) {
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
    pub(super) fn add_components(&mut self, u: &[f64]) {
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
    pub(super) fn slide_window(&mut self, window: Window, time: f64, nis: f64, dof: usize) -> bool {
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
    pub(super) fn add_series_point(&mut self, point: SeriesPoint) {
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

pub(super) fn add_to_histogram(s: &mut SensorSums, dof: usize, nis: f64, top: f64) {
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
