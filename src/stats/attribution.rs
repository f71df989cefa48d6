//! Which noise model the evidence points to: the process noise Q, the measurement noise R,
//! or both.
//!
//! A time average alone cannot tell: ANIS tests `S = H P H' + R`, and a too-small Q and a
//! too-small R both make it high. Two more pieces of evidence separate them:
//! - The whiteness of each measurement component's innovations says whether the gain is
//!   right. A gain too low (Q too small for R) leaves errors that persist from step to step,
//!   so neighbouring innovations correlate positively (ρ₁ > 0); a gain too high (Q too large
//!   for R) over-corrects, so they alternate (ρ₁ < 0). With the level of `ν_j²/S_jj`:
//!
//!   | `ν²/S` | ρ₁ > 0 (gain low) | ρ₁ < 0 (gain high) | white |
//!   |--------|-------------------|--------------------|-------|
//!   | high   | Q too small       | R too small        | Q and R both too small |
//!   | low    | R too large       | Q too large        | Q and R both too large |
//!   | at 1   | Q/R too small     | Q/R too large      | —     |
//!
//!   (S too small with a low gain: the filter believes its prediction too much, so Q is
//!   small; S too small with a high gain: it believes the measurement too much, so R is
//!   small; and likewise for the rest.)
//! - With ground truth, the state components: errors that fit P while the innovations do not
//!   fit S put the blame on R; errors off while the innovations fit put it on Q (in states
//!   the sensors do not see directly) or on the initial covariance.
//! - Before all of this, the first moment: errors that do not average zero are a bias no
//!   Q or R can model (a sensor offset, an unmodelled constant input). A bias raises the
//!   second moments too (`E[u²] = 1 + b²`), so a biased component's level says nothing about
//!   Q or R: its finding is the bias, and it comes first.
//!
//! R scales both: a too-small R makes S too small *and* (through a too-high gain the filter
//! trusts) P too small, so with R to blame, state components off in the same direction are
//! explained by R; only a state component off the other way (or off while no innovation
//! component is) leaves room for Q being off as well.

use serde::Serialize;

use super::diagnostics::{ComponentStat, WhitenessTest};
use super::interval::Verdict;

/// A noise model the evidence blames.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Suspect {
    /// The process noise Q.
    Q,
    /// The measurement noise R.
    R,
    /// Both together (the gain fits, the scale does not), or their ratio.
    QAndR,
    /// Neither: a constant bias (errors or innovations that do not average zero).
    Bias,
}

impl Suspect {
    /// What findings blame together, given whether any of them `blames` each suspect: a
    /// bias first (it explains the second moments too), then Q or R where every blame is on
    /// the same one, both otherwise; `None` when nothing is blamed.
    pub fn overall(blames: impl Fn(Suspect) -> bool) -> Option<Suspect> {
        match (
            blames(Suspect::Bias),
            blames(Suspect::Q),
            blames(Suspect::R),
            blames(Suspect::QAndR),
        ) {
            (true, ..) => Some(Suspect::Bias),
            (false, false, false, false) => None,
            (false, true, false, false) => Some(Suspect::Q),
            (false, false, true, false) => Some(Suspect::R),
            _ => Some(Suspect::QAndR),
        }
    }

    /// The noise model in words, e.g. "Q (process noise)".
    pub fn words(self) -> &'static str {
        match self {
            Suspect::Q => "Q (process noise)",
            Suspect::R => "R (measurement noise)",
            Suspect::QAndR => "Q and R together",
            Suspect::Bias => "a constant bias (a sensor offset or an unmodelled input)",
        }
    }
}

/// One piece of evidence and what it points to.
#[derive(Debug, Clone, Serialize)]
pub struct Finding {
    /// The component it is about (a measurement or state component name).
    pub component: String,
    /// What it blames; `None` for a state component off while the innovations are off too
    /// (then it is context: the innovations carry the blame).
    pub suspect: Option<Suspect>,
    /// The change the evidence asks for, in words ("increase R", "decrease Q/R").
    pub action: String,
    /// The evidence in numbers.
    pub evidence: String,
}

/// What the statistics say about Q and R.
#[derive(Debug, Clone, Serialize)]
pub struct Diagnosis {
    /// The findings, measurement components first.
    pub findings: Vec<Finding>,
    /// What they point to overall; `None` when nothing is off.
    pub suspect: Option<Suspect>,
    /// Some state components are off in a way the innovations' blame does not explain
    /// (see the module documentation): the other noise model may be off as well.
    pub states_off_too: bool,
}

impl Diagnosis {
    /// One line: what the evidence points to, or `None` when nothing is off.
    pub fn headline(&self) -> Option<String> {
        self.suspect.map(|s| {
            let also = match (self.states_off_too, s) {
                (true, Suspect::R) => "; state components are off too, so Q may be off as well",
                (true, _) => "; state components are off too",
                _ => "",
            };
            format!("the evidence points to {}{also}", s.words())
        })
    }
}

/// Direction of a component's level: +1 above its interval, −1 below, 0 inside or unknown.
fn level(c: &ComponentStat) -> i32 {
    match c.verdict {
        Verdict::Overconfident => 1,
        Verdict::Underconfident => -1,
        _ => 0,
    }
}

/// `v` with its sign and two decimals, in scientific notation when huge (the mean of an
/// overflowing filter's errors).
fn signed(v: f64) -> String {
    if v.abs() >= 1e6 && v.is_finite() {
        format!("{v:+.3e}")
    } else {
        format!("{v:+.2}")
    }
}

/// The bias finding of a component whose zero-mean test failed and explains it
/// ([`ComponentStat::bias_explains`]).
fn bias_finding(c: &ComponentStat) -> Option<Finding> {
    if !c.bias_explains() {
        return None;
    }
    let (what, on) = if c.kind == "state" {
        ("e/√P", "acting on")
    } else {
        ("ν/√S", "on")
    };
    Some(Finding {
        component: c.name.clone(),
        suspect: Some(Suspect::Bias),
        action: format!(
            "errors average {}σ: a sensor offset or unmodelled constant input {on} {}",
            signed(c.mean),
            c.name
        ),
        evidence: format!(
            "mean {what} = {} (z = {})",
            signed(c.mean),
            signed(c.mean_z)
        ),
    })
}

/// The sign of a failed whiteness test's lag-1 autocorrelation, 0 when white.
fn gain(w: Option<&WhitenessTest>) -> i32 {
    match w {
        Some(w) if w.verdict == Verdict::NotWhite && w.rho1 != 0.0 => {
            if w.rho1 > 0.0 {
                1
            } else {
                -1
            }
        }
        _ => 0,
    }
}

/// What a measurement component's level `lv` (+1 above its interval, −1 below, 0 inside)
/// and the sign `g` of its failed whiteness test's lag-1 autocorrelation (0 when white)
/// blame, and the change they ask for (the table in the module documentation). Not both 0.
pub fn blame(lv: i32, g: i32) -> (Suspect, &'static str) {
    match (lv.signum(), g.signum()) {
        (1, 1) => (Suspect::Q, "increase Q"),
        (1, -1) => (Suspect::R, "increase R"),
        (-1, -1) => (Suspect::Q, "decrease Q"),
        (-1, 1) => (Suspect::R, "decrease R"),
        (1, _) => (Suspect::QAndR, "increase Q and R in proportion"),
        (-1, _) => (Suspect::QAndR, "decrease Q and R in proportion"),
        (_, 1) => (
            Suspect::QAndR,
            "increase Q relative to R (the gain is too low)",
        ),
        _ => (
            Suspect::QAndR,
            "decrease Q relative to R (the gain is too high)",
        ),
    }
}

/// What [`super::diagnose`] reads of a report.
pub(super) struct Evidence<'a> {
    /// The state components (empty without truth).
    pub(super) states: &'a [ComponentStat],
    /// The measurement components.
    pub(super) measurements: &'a [ComponentStat],
    /// The measurement components' whiteness tests.
    pub(super) whiteness: &'a [WhitenessTest],
}

pub(super) fn diagnose_components(report: &Evidence) -> Diagnosis {
    let mut findings: Vec<Finding> = report
        .measurements
        .iter()
        .chain(report.states)
        .filter_map(bias_finding)
        .collect();
    let bias_findings = findings.len();
    let r_direction = measurement_findings(report, &mut findings);
    let innovations_fit = findings.len() == bias_findings;
    // A state component off the way R's blame explains (a too-small R makes P too small as
    // well) leaves no room for Q; one off the other way, or off while the innovations
    // blame Q or both, does.
    let states_off_too = state_findings(report.states, innovations_fit, r_direction, &mut findings);
    // A mean off zero that does not explain its component's second moment: context, not
    // the cause (a lag under too small a Q biases a nonlinear filter's errors).
    for c in report
        .measurements
        .iter()
        .chain(report.states)
        .filter(|c| c.mean_verdict == Verdict::Biased && !c.bias_explains())
    {
        let what = if c.kind == "state" {
            "e/√P"
        } else {
            "ν/√S"
        };
        findings.push(Finding {
            component: c.name.clone(),
            suspect: None,
            action: "its mean is off zero too, less than its spread is off: a symptom of the above (a lag), or an offset behind it".to_string(),
            evidence: format!("mean {what} = {} (z = {})", signed(c.mean), signed(c.mean_z)),
        });
    }
    let suspect = Suspect::overall(|s| findings.iter().any(|f| f.suspect == Some(s)));
    Diagnosis {
        findings,
        suspect,
        states_off_too,
    }
}

/// The measurement components a bias does not explain, each blamed on Q or R from its
/// level and its innovations' whiteness (on R outright where the state errors fit P); the
/// direction in which they blame R (+1: R too small, −1: too large, 0: they do not).
fn measurement_findings(report: &Evidence, findings: &mut Vec<Finding>) -> i32 {
    let biased = |c: &ComponentStat| c.bias_explains();
    let states_fit = report.states.iter().all(|c| level(c) == 0 || biased(c));
    let has_truth = !report.states.is_empty();
    let mut r_direction = 0;
    for c in report.measurements.iter().filter(|c| !biased(c)) {
        let w = report.whiteness.iter().find(|w| w.component == c.name);
        let (lv, g) = (level(c), gain(w));
        if lv == 0 && g == 0 {
            continue;
        }
        let rho = w.map_or(String::new(), |w| format!(", ρ₁ = {:+.3}", w.rho1));
        let evidence = format!("ν²/S = {:.3}{rho}", c.value);
        let (suspect, action) = if lv != 0 && has_truth && states_fit {
            // The state errors fit P: the mismatch is in the measurement model.
            (Suspect::R, if lv > 0 { "increase R" } else { "decrease R" })
        } else {
            blame(lv, g)
        };
        if suspect == Suspect::R {
            r_direction = if action.starts_with("increase") {
                1
            } else {
                -1
            };
        }
        findings.push(Finding {
            component: c.name.clone(),
            suspect: Some(suspect),
            action: action.to_string(),
            evidence,
        });
    }
    r_direction
}

/// The state components off their target that a bias does not explain: Q acting on them
/// where the innovations fit, else their variance in P. Whether one of them is off while
/// the innovations blame something else and not the way their blame of R explains.
fn state_findings(
    states: &[ComponentStat],
    innovations_fit: bool,
    r_direction: i32,
    findings: &mut Vec<Finding>,
) -> bool {
    let mut unexplained_state = false;
    for c in states.iter().filter(|c| !c.bias_explains()) {
        let lv = level(c);
        if lv == 0 {
            continue;
        }
        if !innovations_fit && lv != r_direction {
            unexplained_state = true;
        }
        let (suspect, action) = match (innovations_fit, lv > 0) {
            (true, true) => (
                Some(Suspect::Q),
                "increase Q acting on it (or its initial variance)",
            ),
            (true, false) => (
                Some(Suspect::Q),
                "decrease Q acting on it (or its initial variance)",
            ),
            (false, true) => (None, "its variance in P is too small"),
            (false, false) => (None, "its variance in P is too large"),
        };
        findings.push(Finding {
            component: c.name.clone(),
            suspect,
            action: action.to_string(),
            evidence: format!("e²/P = {:.3}", c.value),
        });
    }
    unexplained_state
}

#[cfg(test)]
mod tests {
    use super::super::Interval;
    use super::*;

    /// A component whose second moment `value` is judged against [0.9, 1.1] and whose mean
    /// is zero.
    fn component(name: &str, kind: &'static str, value: f64) -> ComponentStat {
        let verdict = match value {
            v if v > 1.1 => Verdict::Overconfident,
            v if v < 0.9 => Verdict::Underconfident,
            _ => Verdict::Consistent,
        };
        ComponentStat {
            name: name.to_string(),
            kind,
            value,
            interval: Interval {
                lower: 0.9,
                upper: 1.1,
            },
            samples: 1000.0,
            verdict,
            mean: 0.0,
            mean_z: 0.0,
            mean_verdict: Verdict::Consistent,
        }
    }

    /// A failed whiteness test of `component` with lag-1 autocorrelation `rho1`.
    fn not_white(component: &str, rho1: f64) -> WhitenessTest {
        WhitenessTest {
            component: component.to_string(),
            statistic: 50.0,
            dof: 5,
            threshold: 11.07,
            rho1,
            verdict: Verdict::NotWhite,
        }
    }

    fn diagnosis(
        states: &[ComponentStat],
        measurements: &[ComponentStat],
        whiteness: &[WhitenessTest],
    ) -> Diagnosis {
        diagnose_components(&Evidence {
            states,
            measurements,
            whiteness,
        })
    }

    fn actions(d: &Diagnosis) -> Vec<(&str, &str)> {
        d.findings
            .iter()
            .map(|f| (f.component.as_str(), f.action.as_str()))
            .collect()
    }

    #[test]
    fn a_state_off_the_way_the_blame_of_r_explains_leaves_no_room_for_q() {
        // ν²/S high with alternating innovations: R too small, which makes P too small too,
        // so a state error above P is R's doing.
        let d = diagnosis(
            &[component("x", "state", 1.5)],
            &[component("z", "measurement", 1.4)],
            &[not_white("z", -0.3)],
        );
        assert_eq!(d.suspect, Some(Suspect::R));
        assert_eq!(actions(&d)[0], ("z", "increase R"));
        assert!(!d.states_off_too, "a too-small R explains e²/P above 1");
        assert_eq!(
            d.headline().unwrap(),
            "the evidence points to R (measurement noise)"
        );
        // And mirrored: ν²/S low with persistent innovations, R too large, P too large.
        let d = diagnosis(
            &[component("x", "state", 0.6)],
            &[component("z", "measurement", 0.7)],
            &[not_white("z", 0.3)],
        );
        assert_eq!(actions(&d)[0], ("z", "decrease R"));
        assert!(!d.states_off_too, "a too-large R explains e²/P below 1");
    }

    #[test]
    fn a_state_off_against_the_blame_of_r_says_q_may_be_off_as_well() {
        for (state, meas, rho1) in [(0.6, 1.4, -0.3), (1.5, 0.7, 0.3)] {
            let d = diagnosis(
                &[component("x", "state", state)],
                &[component("z", "measurement", meas)],
                &[not_white("z", rho1)],
            );
            assert_eq!(d.suspect, Some(Suspect::R), "{state} {meas}");
            assert!(d.states_off_too, "{state} {meas}");
            assert!(
                d.headline().unwrap().ends_with("so Q may be off as well"),
                "{:?}",
                d.headline()
            );
            assert_eq!(d.findings[1].suspect, None, "the state is context");
        }
    }

    #[test]
    fn states_that_fit_put_a_white_innovation_misfit_on_r_and_without_truth_on_both() {
        let meas = [component("z", "measurement", 1.4)];
        let d = diagnosis(&[component("x", "state", 1.0)], &meas, &[]);
        assert_eq!(actions(&d), [("z", "increase R")]);
        assert_eq!(d.suspect, Some(Suspect::R));
        let d = diagnosis(&[], &meas, &[]);
        assert_eq!(actions(&d), [("z", "increase Q and R in proportion")]);
        assert_eq!(d.suspect, Some(Suspect::QAndR));
    }

    #[test]
    fn innovations_that_fit_put_a_state_misfit_on_q() {
        let d = diagnosis(
            &[component("x", "state", 1.5), component("v", "state", 0.5)],
            &[component("z", "measurement", 1.0)],
            &[],
        );
        assert_eq!(
            actions(&d),
            [
                ("x", "increase Q acting on it (or its initial variance)"),
                ("v", "decrease Q acting on it (or its initial variance)")
            ]
        );
        assert_eq!(d.suspect, Some(Suspect::Q));
        assert!(!d.states_off_too);
    }

    #[test]
    fn a_state_whose_bias_explains_it_is_the_bias_finding_alone() {
        // e/√P averages 0.7σ: E[u²] = 1 + 0.7² explains e²/P = 1.5, so there is nothing left
        // for Q (1.5 − 0.49 is inside the interval).
        let mut biased = component("x", "state", 1.5);
        biased.mean = 0.7;
        biased.mean_z = 20.0;
        biased.mean_verdict = Verdict::Biased;
        assert!(biased.bias_explains());
        let d = diagnosis(
            &[biased, component("v", "state", 1.5)],
            &[component("z", "measurement", 1.0)],
            &[],
        );
        let found: Vec<_> = d
            .findings
            .iter()
            .map(|f| (f.component.as_str(), f.suspect))
            .collect();
        assert_eq!(
            found,
            [("x", Some(Suspect::Bias)), ("v", Some(Suspect::Q))],
            "{:?}",
            actions(&d)
        );
        assert_eq!(d.suspect, Some(Suspect::Bias));
    }
}
