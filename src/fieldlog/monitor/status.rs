//! What a monitor answers ([`MonitorStatus`], per sensor and per window) and the status line
//! each prints as: the answer's shape apart from the bookkeeping that computes it.

use std::fmt;

use crate::fieldlog::report::short;
use crate::fieldlog::settings::Window;
use crate::stats::{Finding, Interval, Verdict};

/// What a [`NisMonitor`] says about all its sensors so far; `Display` is a status line.
///
/// [`NisMonitor`]: super::NisMonitor
#[derive(Debug, Clone)]
pub struct MonitorStatus {
    /// Time of the latest update, s (NaN before the first).
    pub time: f64,
    /// Updates so far, all sensors.
    pub updates: usize,
    /// Per sensor, in the order of their first update.
    pub sensors: Vec<SensorStatus>,
    /// The verdict of every test of every sensor so far, at the family-wise α.
    pub verdict: Verdict,
}

impl MonitorStatus {
    /// The status of the sensor named `name`, once it has an update.
    pub fn sensor(&self, name: &str) -> Option<&SensorStatus> {
        self.sensors.iter().find(|s| s.name == name)
    }
}

/// What a [`NisMonitor`] says about one sensor so far; `Display` is its part of a status
/// line: `gps: NIS 2.104 in [1.874, 2.134] (window 50: 2.871 in [1.484, 2.591]) consistent`.
///
/// [`NisMonitor`]: super::NisMonitor
#[derive(Debug, Clone)]
pub struct SensorStatus {
    /// Sensor name.
    pub name: String,
    /// Updates so far, outliers included.
    pub updates: usize,
    /// Updates beyond the outlier gate (counted and tested apart, not averaged).
    pub outliers: usize,
    /// The running NIS: the average `ν' S⁻¹ ν` over the updates inside the gate (about m
    /// for a consistent filter with an m-dimensional sensor; NaN while every update is an
    /// outlier).
    pub nis: f64,
    /// Its interval at the per-test level that holds the family-wise α.
    pub interval: Interval,
    /// The latest full window, once the window has filled.
    pub window: Option<WindowStatus>,
    /// The verdict of all the sensor's tests (NIS level, outliers, components, whiteness,
    /// zero mean); inconclusive while there are too few updates for them to have power.
    pub verdict: Verdict,
    /// What the evidence blames when the sensor fails: `action` and `evidence` in the words
    /// of `autotune nis`'s advice.
    pub advice: Option<Finding>,
}

/// The moving window's latest average.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WindowStatus {
    /// The window (the settings').
    pub window: Window,
    /// The average NIS over the window's gated updates.
    pub nis: f64,
    /// Its two-sided interval at α, `χ²⁻¹(α/2, Σm)/K` to `χ²⁻¹(1 − α/2, Σm)/K` for K
    /// updates of Σm degrees of freedom together.
    pub interval: Interval,
}

impl fmt::Display for WindowStatus {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self.window {
            Window::Updates(n) => write!(f, "window {n}: ")?,
            Window::Seconds(s) => write!(f, "window {s} s: ")?,
        }
        write!(
            f,
            "{} in [{}, {}]",
            short(self.nis),
            short(self.interval.lower),
            short(self.interval.upper)
        )
    }
}

impl fmt::Display for SensorStatus {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        if self.nis.is_finite() {
            write!(
                f,
                "{}: NIS {} in [{}, {}]",
                self.name,
                short(self.nis),
                short(self.interval.lower),
                short(self.interval.upper)
            )?;
        } else {
            write!(f, "{}: no update inside the gate", self.name)?;
        }
        if let Some(w) = &self.window {
            write!(f, " ({w})")?;
        }
        write!(f, " {}", self.verdict.label())?;
        if self.outliers > 0 {
            write!(
                f,
                ", {} outlier{}",
                self.outliers,
                if self.outliers == 1 { "" } else { "s" }
            )?;
        }
        Ok(())
    }
}

impl fmt::Display for MonitorStatus {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        if self.updates == 0 {
            return write!(f, "waiting for updates");
        }
        write!(f, "t {} s", short(self.time))?;
        for s in &self.sensors {
            write!(f, " | {s}")?;
        }
        write!(f, " | so far: {}", self.verdict.label())
    }
}
