//! How `autotune nis` tests a log: the family-wise level, the outlier gate, the moving window
//! and the whiteness lags, each refused by its setter when out of range.

use serde::Serialize;

use crate::input::SettingError;

/// The moving window of the running NIS average.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Window {
    /// The last this many (non-outlier) updates of a sensor.
    Updates(usize),
    /// The updates of a sensor within this many seconds of its latest.
    Seconds(f64),
}

impl Window {
    /// Parse `50` (updates) or `10s` (seconds).
    pub fn parse(text: &str) -> Result<Window, SettingError> {
        let t = text.trim();
        let bad = || {
            SettingError::new(
                "window",
                format!(
                    "'{text}' is not a window: a number of updates (e.g. 50) or of seconds (e.g. 10s)"
                ),
            )
        };
        if let Some(secs) = t.strip_suffix('s') {
            let s: f64 = secs.trim().parse().map_err(|_| bad())?;
            if !(s.is_finite() && s > 0.0) {
                return Err(SettingError::new(
                    "window",
                    format!("window of {s} s: must be a number of seconds > 0"),
                ));
            }
            Ok(Window::Seconds(s))
        } else {
            let n: usize = t.parse().map_err(|_| bad())?;
            if !(2..=1_000_000).contains(&n) {
                return Err(SettingError::new(
                    "window",
                    format!("window of {n} updates: must be in 2..=1000000"),
                ));
            }
            Ok(Window::Updates(n))
        }
    }

    /// "50 updates" or "10 s".
    pub fn describe(&self) -> String {
        match self {
            Window::Updates(n) => format!("{n} updates"),
            Window::Seconds(s) => format!("{s} s"),
        }
    }
}

/// Settings of the field-log tests.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct NisSettings {
    alpha: f64,
    gate: f64,
    window: Window,
    lags: usize,
}

impl Default for NisSettings {
    fn default() -> Self {
        NisSettings {
            alpha: 0.05,
            gate: 1e-5,
            window: Window::Updates(50),
            lags: 10,
        }
    }
}

impl NisSettings {
    /// Family-wise significance level α in (0, 0.5]: a consistent filter's log fails with
    /// probability at most α.
    pub fn alpha(&self) -> f64 {
        self.alpha
    }

    /// Tail probability of the outlier gate: an update whose NIS a consistent filter would
    /// exceed with probability below this is counted as an outlier, not averaged.
    pub fn gate(&self) -> f64 {
        self.gate
    }

    /// The moving window.
    pub fn window(&self) -> Window {
        self.window
    }

    /// Whiteness lags L (in updates of the sensor).
    pub fn lags(&self) -> usize {
        self.lags
    }

    /// Set α.
    pub fn with_alpha(mut self, alpha: f64) -> Result<Self, SettingError> {
        if !(alpha > 0.0 && alpha <= 0.5) {
            return Err(SettingError::new(
                "alpha",
                format!("{alpha} is not in (0, 0.5]"),
            ));
        }
        self.alpha = alpha;
        Ok(self)
    }

    /// Set the outlier gate's tail probability, in [1e-12, 0.01].
    pub fn with_gate(mut self, gate: f64) -> Result<Self, SettingError> {
        if !(1e-12..=0.01).contains(&gate) {
            return Err(SettingError::new(
                "gate",
                format!("{gate} is not a tail probability in [1e-12, 0.01]"),
            ));
        }
        self.gate = gate;
        Ok(self)
    }

    /// Set the moving window: 2 to 10⁶ updates, or a finite number of seconds > 0.
    pub fn with_window(mut self, window: Window) -> Result<Self, SettingError> {
        let ok = match window {
            Window::Updates(n) => (2..=1_000_000).contains(&n),
            Window::Seconds(s) => s.is_finite() && s > 0.0,
        };
        if !ok {
            return Err(SettingError::new(
                "window",
                format!(
                    "{} is not a window (2 to 1000000 updates, or seconds > 0)",
                    window.describe()
                ),
            ));
        }
        self.window = window;
        Ok(self)
    }

    /// Set the whiteness lags, 1..=100.
    pub fn with_lags(mut self, lags: usize) -> Result<Self, SettingError> {
        if !(1..=100).contains(&lags) {
            return Err(SettingError::new(
                "lags",
                format!("{lags} is not in 1..=100"),
            ));
        }
        self.lags = lags;
        Ok(self)
    }
}
