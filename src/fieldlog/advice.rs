//! What a failing sensor's evidence blames, in words: the level of its gated average and
//! the sign of its lag-1 autocorrelation (the table of [`crate::stats::blame`]), and where
//! the innovations are white, the other sensors of its estimator.

use std::collections::HashMap;

use super::report::{MeanTest, SensorReport, short};
use crate::stats::{Finding, Suspect, Verdict, blame};

impl SensorReport {
    /// The sign of the sensor's gated average: +1 above its interval, −1 below, 0 inside or
    /// untested (the outliers are judged apart: glitches are not a scale of S).
    fn level(&self) -> i32 {
        match self.nis.verdict {
            Verdict::Overconfident => 1,
            Verdict::Underconfident => -1,
            _ => 0,
        }
    }

    /// The sign of the centred lag-1 autocorrelation of the component whose centred
    /// whiteness test fails most clearly, 0 when all are white (centred, so that a bias is
    /// not read as a gain that is too low).
    fn gain(&self) -> (i32, Option<f64>) {
        self.centred_whiteness
            .iter()
            .filter(|w| w.not_white)
            .max_by(|a, b| (a.statistic / a.threshold).total_cmp(&(b.statistic / b.threshold)))
            .map_or((0, None), |w| {
                // The sign says which way the gain is off only when the lag-1 correlation
                // itself stands out; a test failed at higher lags alone does not say.
                if w.rho1.abs() > w.band {
                    (if w.rho1 > 0.0 { 1 } else { -1 }, Some(w.rho1))
                } else {
                    (0, Some(w.rho1))
                }
            })
    }

    /// The component whose mean carries the largest share of `E[ν²/S]`, when that share is
    /// at least [`BIAS_SHARE`].
    fn bias_share(&self) -> Option<&MeanTest> {
        self.mean_tests
            .iter()
            .filter(|t| t.mean_share >= BIAS_SHARE)
            .max_by(|a, b| a.mean_share.total_cmp(&b.mean_share))
    }
}

/// The share of `E[ν²/S]` carried by the mean from which a bias is named whether or not
/// the zero-mean test can be significant: no scale of Q or R makes innovations mostly an
/// offset, and a white sequence of n updates reaches it by chance with probability about
/// `P(χ²(1) ≥ n/2)`, nothing from a dozen updates on.
const BIAS_SHARE: f64 = 0.5;

/// The lag-1 autocorrelation pooled over every component of an estimator's sensors,
/// weighted by their pairs, and its band at α (`z/√pairs`).
#[derive(Debug, Clone, Copy, Default)]
struct Pooled {
    weighted: f64,
    pairs: f64,
}

impl Pooled {
    fn rho(&self) -> f64 {
        if self.pairs > 0.0 {
            self.weighted / self.pairs
        } else {
            0.0
        }
    }
}

/// Give each failing sensor its finding: the level and whiteness table of
/// [`crate::stats::blame`], and where the innovations are white, the other sensors of the
/// same estimator: a shared overconfidence points to the Q they share, a sensor off alone to
/// its own R.
///
/// When every sensor of an estimator is off the same way and no sensor's own whiteness
/// says which way its gain is off, the lag-1 autocorrelation pooled over the estimator's
/// sensors (centred, weighted by pairs) decides: a gain too high makes innovations
/// alternate (ρ₁ < 0: with the NIS too high, every R is too small), a gain too low makes
/// them persist (ρ₁ > 0: Q is too small); within its band `z/√pairs` the data cannot tell
/// Q from R. `z` is `z_{1−α/2}`.
pub(super) fn attribute(sensors: &mut [SensorReport], z: f64) {
    let tally = Tally::of(sensors);
    for s in sensors.iter_mut() {
        if s.verdict.passes() || s.verdict == Verdict::Inconclusive {
            continue;
        }
        let finding = bias_finding(s)
            .or_else(|| inconclusive_finding(s))
            .or_else(|| scale_finding(s, &tally, z));
        if finding.is_some() {
            s.finding = finding;
        }
    }
}

/// What the sensors say together, counted once: a scan of the others for each failing
/// sensor is quadratic in thousands of channels.
struct Tally {
    /// Per estimator: its sensors, how many sit at each level, and the pooled lag-1
    /// correlation.
    groups: HashMap<String, (usize, HashMap<i32, usize>, Pooled)>,
    /// Per estimator: how many of its sensors pass (a sensor at its level but inconclusive,
    /// not white or biased does not fit, and says nothing for or against a shared Q).
    fits: HashMap<String, usize>,
    /// The axes of one sensor (`ekf1.gnss_pos[0]`, `ekf1.gnss_pos[1]`) share its R: off
    /// together while the other sensors fit, they blame that sensor, not the estimator.
    families: Families,
    /// Per sensor: its estimator, family, level and deviation.
    devs: Vec<(String, String, i32, f64)>,
}

impl Tally {
    fn of(sensors: &[SensorReport]) -> Tally {
        let mut groups: HashMap<String, (usize, HashMap<i32, usize>, Pooled)> = HashMap::new();
        let mut families: Families = HashMap::new();
        let mut fits: HashMap<String, usize> = HashMap::new();
        for s in sensors {
            if s.verdict.passes() {
                *fits.entry(s.group.clone()).or_default() += 1;
            }
            let g = groups.entry(s.group.clone()).or_default();
            g.0 += 1;
            *g.1.entry(s.level()).or_default() += 1;
            for c in &s.centred_whiteness {
                g.2.weighted += c.pairs * c.rho1;
                g.2.pairs += c.pairs;
            }
            let f = families
                .entry((s.group.clone(), family(&s.name)))
                .or_default();
            f.0 += 1;
            *f.1.entry(s.level()).or_default() += 1;
        }
        let devs = sensors
            .iter()
            .map(|s| (s.group.clone(), family(&s.name), s.level(), deviation(s)))
            .collect();
        Tally {
            groups,
            fits,
            families,
            devs,
        }
    }
}

/// A bias, where it explains the NIS level (it adds Σ_j b_j² to it) or carries most of
/// E[ν²/S]: no Q or R models it, so it comes first. A small mean beside a NIS far off is a
/// symptom instead.
fn bias_finding(s: &SensorReport) -> Option<Finding> {
    let bias_sq: f64 = s.mean_tests.iter().map(|t| t.mean * t.mean).sum();
    let explained = s.level() == 0 || s.nis.interval.contains(s.nis.mean - bias_sq);
    if let Some(t) = s
        .mean_tests
        .iter()
        .filter(|t| t.verdict == Verdict::Biased && explained)
        // Persistent innovations (a gain too low: Q too small) wander, and over one log
        // their mean need not be 0 though nothing is constant; a mean that is a small
        // share of E[u²] beside them is that wander, not an offset.
        .filter(|t| {
            let persistent = s
                .centred_whiteness
                .iter()
                .any(|c| c.component == t.component && c.rho1 > c.band);
            !(persistent && t.mean_share < WANDER_SHARE)
        })
        .max_by(|a, b| (a.z.abs() / a.threshold).total_cmp(&(b.z.abs() / b.threshold)))
    {
        return Some(Finding {
            component: s.name.clone(),
            suspect: Some(Suspect::Bias),
            action: format!(
                "innovations average {}σ: a sensor offset or unmodelled constant input on {}",
                signed(t.mean),
                t.component
            ),
            evidence: format!(
                "mean ν/√S = {} (z = {}, effective samples {})",
                signed(t.mean),
                signed(t.z),
                short(t.n_eff)
            ),
        });
    }
    let t = s.bias_share()?;
    let mut evidence = format!(
        "mean ν/√S = {} (z = {}, effective samples {})",
        signed(t.mean),
        signed(t.z),
        short(t.n_eff)
    );
    if let Some(r) = &s.inconclusive_reason {
        evidence.push_str(&format!("; the NIS level: {r}"));
    }
    Some(Finding {
        component: s.name.clone(),
        suspect: Some(Suspect::Bias),
        action: format!(
            "the mean innovation carries {:.0} % of E[ν²/S]{}: a sensor offset or an unmodelled constant input, not a scale of Q or R",
            100.0 * t.mean_share,
            // A scalar channel's component is the channel itself.
            if t.component == s.name {
                String::new()
            } else {
                format!(" on {}", t.component)
            }
        ),
        evidence,
    })
}

/// Innovations so correlated that their level cannot be judged: no suspect yet.
fn inconclusive_finding(s: &SensorReport) -> Option<Finding> {
    let r = s.inconclusive_reason.as_ref()?;
    let (_, rho1) = s.gain();
    let mut evidence = format!(
        "NIS {} ({} expected, interval [{}, {}] widened for the correlation)",
        short(s.nis.mean),
        short(s.nis.target),
        short(s.nis.interval.lower),
        short(s.nis.interval.upper)
    );
    if let Some(r1) = rho1 {
        evidence.push_str(&format!(", centred ρ₁ = {r1:+.3}"));
    }
    Some(Finding {
        component: s.name.clone(),
        suspect: None,
        action: format!(
            "{r}: the innovations are strongly correlated, so their level says nothing about Q or R yet"
        ),
        evidence,
    })
}

/// Q, R or both by the level, the whiteness and the other sensors of the estimator; glitches
/// apart; components that disagree while their sum fits. `None` when nothing is off.
fn scale_finding(s: &SensorReport, tally: &Tally, z: f64) -> Option<Finding> {
    let lv = s.level();
    let (g, rho1) = s.gain();
    let heavy = s.outliers_verdict == Verdict::Overconfident;
    let components_off: Vec<(String, i32)> = s
        .component_stats
        .iter()
        .filter_map(|c| match c.verdict {
            Verdict::Overconfident => Some((c.name.clone(), 1)),
            Verdict::Underconfident => Some((c.name.clone(), -1)),
            _ => None,
        })
        .collect();
    let (suspect, action) = if heavy && lv <= 0 && g == 0 {
        // Glitches beyond the gate while the core is at or below its target: scaling Q
        // or R up or down would not fix them, and lowering S would make them worse.
        let core = if lv < 0 {
            "the updates inside the gate say S is too large"
        } else {
            "the average fits"
        };
        (
            None,
            format!(
                "{core}, but the tails are heavier than S allows: find the glitches the filter should reject (a gate on its innovations, a fault detector) before changing Q or R"
            ),
        )
    } else if lv == 0 && g == 0 && !components_off.is_empty() {
        components_disagree(&components_off)
    } else if lv == 0 && g == 0 {
        return None;
    } else if g == 0 && lv != 0 {
        among_peers(s, lv, tally, z)
    } else {
        let (sus, act) = blame(lv, g);
        (Some(sus), act.to_string())
    };
    let mut evidence = if s.nis.mean.is_finite() {
        format!(
            "NIS {} ({} expected, interval [{}, {}])",
            short(s.nis.mean),
            short(s.nis.target),
            short(s.nis.interval.lower),
            short(s.nis.interval.upper)
        )
    } else {
        "no update inside the gate".to_string()
    };
    if s.outliers_verdict == Verdict::Overconfident {
        evidence.push_str(&format!(
            ", {} outlier{} where {} expected",
            s.outliers,
            if s.outliers == 1 { "" } else { "s" },
            short(s.outliers_expected)
        ));
    }
    if let Some(r) = rho1 {
        evidence.push_str(&format!(", ρ₁ = {r:+.3}"));
    }
    Some(Finding {
        component: s.name.clone(),
        suspect,
        action,
        evidence,
    })
}

/// Components off in opposite directions (`(name, +1 or −1)`) while their sum fits: R
/// rescaled between them.
fn components_disagree(components_off: &[(String, i32)]) -> (Option<Suspect>, String) {
    let up: Vec<&str> = components_off
        .iter()
        .filter(|c| c.1 > 0)
        .map(|c| c.0.as_str())
        .collect();
    let down: Vec<&str> = components_off
        .iter()
        .filter(|c| c.1 < 0)
        .map(|c| c.0.as_str())
        .collect();
    let mut parts = Vec::new();
    if !up.is_empty() {
        parts.push(format!("increase it for {}", up.join(", ")));
    }
    if !down.is_empty() {
        parts.push(format!("decrease it for {}", down.join(", ")));
    }
    (
        Some(Suspect::R),
        format!(
            "the components disagree while their sum fits: rescale R between them ({}), or the Q that feeds them",
            parts.join("; ")
        ),
    )
}

/// A level off (`lv`) with white innovations, judged by the other sensors of the estimator:
/// all off the same way (the pooled lag-1 correlation tells Q from every R), this one off
/// alone (its R), or neither (the table of [`blame`]).
fn among_peers(s: &SensorReport, lv: i32, tally: &Tally, z: f64) -> (Option<Suspect>, String) {
    // The other sensors of its estimator: how many, how many at its level, and how many
    // fit (pass: a level of 0 alone may be an inconclusive or biased sensor).
    let (peers, at_own, fit, pooled) = match tally.groups.get(&s.group) {
        Some((n, by_level, pooled)) => {
            let own = by_level.get(&lv).copied().unwrap_or(0).saturating_sub(1);
            let fit = tally.fits.get(&s.group).copied().unwrap_or(0);
            let fit = fit.saturating_sub(usize::from(s.verdict.passes()));
            (n.saturating_sub(1), own, fit, *pooled)
        }
        None => (0, 0, 0, Pooled::default()),
    };
    if peers == 0 {
        let (sus, act) = blame(lv, 0);
        return (Some(sus), act.to_string());
    }
    let dir = if lv > 0 { "increase" } else { "decrease" };
    if at_own == peers {
        // Every R off the same way looks like Q in the NIS level: the sign of the pooled
        // lag-1 correlation tells them apart (see `blame`'s table).
        let (rho, band) = (pooled.rho(), z / pooled.pairs.max(1.0).sqrt());
        let words = format!(
            "every sensor of this estimator is off the same way; ρ₁ pooled over them = {rho:+.3}, band ±{}",
            short(band)
        );
        if rho.abs() > band {
            let (sus, _) = blame(lv, if rho > 0.0 { 1 } else { -1 });
            let why = if rho > 0.0 {
                "the innovations persist: the gain is too low"
            } else {
                "the innovations alternate: the gain is too high"
            };
            match sus {
                Suspect::R => (
                    Some(Suspect::R),
                    format!("{dir} every sensor's R ({words}: {why})"),
                ),
                _ => (Some(Suspect::Q), format!("{dir} Q ({words}: {why})")),
            }
        } else {
            (
                Some(Suspect::QAndR),
                format!(
                    "{dir} Q or every sensor's R: the data cannot tell which ({words}, not significant)"
                ),
            )
        }
    } else if off_alone(s, lv, peers, fit, &tally.families, &tally.devs) {
        (
            Some(Suspect::R),
            format!("{dir} this sensor's R (the other sensors of this estimator fit)"),
        )
    } else {
        let (sus, act) = blame(lv, 0);
        (Some(sus), act.to_string())
    }
}

/// Below this share of E[u²], a significant mean of persistent innovations is read as their
/// wander rather than an offset.
const WANDER_SHARE: f64 = 0.25;

/// Per (estimator, sensor family): how many sensors, and how many at each level.
type Families = HashMap<(String, String), (usize, HashMap<i32, usize>)>;

/// Whether sensor `s` (at level `lv`, with `peers` others in its estimator of which `fit`
/// pass) is off alone: no other sensor (its own axes aside) off the same way by more than a
/// third of its log-ratio, and most of them fit. A Q they share would move them too, so its
/// own R is blamed; one other sensor failing slightly (1 in 20 do at α) does not make it
/// shared. Sensors that are inconclusive or fail otherwise do not count as fitting.
fn off_alone(
    s: &SensorReport,
    lv: i32,
    peers: usize,
    fit: usize,
    families: &Families,
    devs: &[(String, String, i32, f64)],
) -> bool {
    let fam = family(&s.name);
    let axes = families
        .get(&(s.group.clone(), fam.clone()))
        .map_or(0, |(n, _)| n.saturating_sub(1));
    let others = peers.saturating_sub(axes);
    let dev = deviation(s);
    let alike = devs
        .iter()
        .filter(|(g, f, l, d)| *g == s.group && *f != fam && *l == lv && *d > dev / 3.0)
        .count();
    others > 0 && alike == 0 && fit * 2 >= others && fit > 0
}

/// How far a sensor's gated NIS average is from its target, `|ln(mean / target)|` (0 when
/// either is not a positive number).
fn deviation(s: &SensorReport) -> f64 {
    let r = s.nis.mean / s.nis.target;
    if r.is_finite() && r > 0.0 {
        r.ln().abs()
    } else {
        0.0
    }
}

/// A sensor's family: its name without the axis index (`ekf1.gnss_pos[0]` → `ekf1.gnss_pos`).
fn family(name: &str) -> String {
    name.split('[').next().unwrap_or(name).to_string()
}

/// `v` in 4 significant digits with its sign.
fn signed(v: f64) -> String {
    if v >= 0.0 {
        format!("+{}", short(v))
    } else {
        short(v)
    }
}
