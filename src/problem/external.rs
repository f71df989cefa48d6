//! An external problem: `[external]` names the worker program whose records the
//! experiment reads (docs/external.md) and becomes an [`ExternalExperiment`].

use std::time::Duration;

use super::spec::{ExternalSpec, ProblemSpec};
use super::validate::{VResult, Validator};
use crate::experiment::{Definition, Info};
use crate::external::{ExternalExperiment, WorkerCommand};
use crate::montecarlo::McConfig;
use crate::params::{ParamSpace, Target};
use crate::records::{Layout, SensorLayout, StateLayout};

/// Most workers a problem may ask for.
const MAX_WORKERS: i64 = 256;
/// Longest timeout accepted, s (a day).
const MAX_TIMEOUT: f64 = 86_400.0;

impl Validator<'_> {
    /// Build the external experiment of `[external]`, with the file's parameters in file
    /// order.
    pub(super) fn external_problem(
        &self,
        s: &ProblemSpec,
        e: &ExternalSpec,
        info: Info,
        mc: McConfig,
    ) -> VResult<ExternalExperiment> {
        if e.command.is_empty() || e.command[0].trim().is_empty() {
            return self.err(
                "external.command",
                "empty: give the program and its arguments, e.g. [\"python3\", \"worker.py\"]",
            );
        }
        if s.measurement_names.is_some() {
            return self.err(
                "measurement_names",
                "an external problem names its measurements in [external.sensors]",
            );
        }
        if e.sensors.is_empty() && s.state_names.is_none() {
            return self.err(
                "external.sensors",
                "missing: name the sensors and their components (and state_names, with ground truth)",
            );
        }
        let (sensors, measurement_names) = self.external_sensors(e)?;
        let state_names = s.state_names.clone().unwrap_or_default();
        if s.state_names.as_ref().is_some_and(Vec::is_empty) {
            return self.err(
                "state_names",
                "empty: leave it out for a problem without ground truth",
            );
        }
        let layout = Layout {
            state: (!state_names.is_empty()).then_some(StateLayout {
                dim: state_names.len(),
                components: true,
            }),
            sensors,
        };
        let (workers, timeout) = self.external_workers(e)?;
        let params = self.params(&s.params)?;
        if params.params.is_empty() {
            return self.err(
                "params",
                "missing: an external problem's parameters are what the worker is given",
            );
        }
        let truth = match &e.truth {
            None => None,
            Some(t) => Some(self.external_truth(t, &params)?),
        };
        let targets = self.external_targets(e, &params, &state_names, &measurement_names)?;
        let dir = match self.file.parent() {
            Some(d) if !d.as_os_str().is_empty() => d.to_path_buf(),
            _ => std::path::PathBuf::from("."),
        };
        if let Some(hint) = bare_command_hint(&e.command[0], &dir) {
            return self.err("external.command", hint);
        }
        // The worker's program and the files its arguments name (worker.py) are inputs of
        // every command on this problem: no output may replace them.
        for arg in &e.command {
            let p = dir.join(arg);
            if p.is_file() {
                crate::input::note_input(&p);
            }
        }
        let command = WorkerCommand {
            command: e.command.clone(),
            dir,
            workers,
            timeout: Duration::from_secs_f64(timeout),
            check_seed_contract: e.check_seed_contract.unwrap_or(true),
        };
        let definition = Definition {
            info,
            params,
            state_names,
            measurement_names,
            mc,
        };
        Ok(ExternalExperiment::new(definition, layout, command, truth).with_targets(targets))
    }

    /// The sensors of `[external.sensors]` and their measurement components' names
    /// (`<sensor>_<component>`).
    fn external_sensors(&self, e: &ExternalSpec) -> VResult<(Vec<SensorLayout>, Vec<String>)> {
        let mut sensors = Vec::new();
        let mut measurement_names = Vec::new();
        for (name, comps) in &e.sensors {
            if !crate::records::valid_sensor(name) {
                return self.err(
                    format!("external.sensors.{name}"),
                    "a sensor name is a letter, then letters, digits and _ (not 'dof')",
                );
            }
            if comps.is_empty() {
                return self.err(format!("external.sensors.{name}"), "no components");
            }
            measurement_names.extend(comps.iter().map(|c| format!("{name}_{c}")));
            sensors.push(SensorLayout {
                name: name.clone(),
                dim: comps.len(),
                components: true,
            });
        }
        Ok((sensors, measurement_names))
    }

    /// The number of workers (the machine's parallelism by default) and the timeout of one
    /// answer, s (300 by default).
    fn external_workers(&self, e: &ExternalSpec) -> VResult<(usize, f64)> {
        let workers = match e.workers {
            None => std::thread::available_parallelism().map_or(1, |n| n.get()),
            Some(n) if (1..=MAX_WORKERS).contains(&n) => n as usize,
            Some(n) => {
                return self.err(
                    "external.workers",
                    format!("{n}: must be 1 to {MAX_WORKERS}"),
                );
            }
        };
        let timeout = match e.timeout {
            None => 300.0,
            Some(t) if t.is_finite() && t > 0.0 && t <= MAX_TIMEOUT => t,
            Some(t) => {
                return self.err(
                    "external.timeout",
                    // `{:?}`: 1e300 as written, not its 301 digits.
                    format!("{t:?}: must be a number of seconds in (0, {MAX_TIMEOUT}]"),
                );
            }
        };
        Ok((workers, timeout))
    }

    /// `[external.truth]`'s value of every parameter, in parameter order.
    fn external_truth(
        &self,
        t: &indexmap::IndexMap<String, f64>,
        params: &ParamSpace,
    ) -> VResult<Vec<f64>> {
        for name in t.keys() {
            if params.index(name).is_none() {
                return self.err(format!("external.truth.{name}"), "not one of [params]");
            }
        }
        let mut v = Vec::new();
        for p in &params.params {
            match t.get(&p.name) {
                Some(&x) if x.is_finite() && x > 0.0 => v.push(x),
                Some(&x) => {
                    return self.err(
                        format!("external.truth.{}", p.name),
                        format!("{x}: must be > 0"),
                    );
                }
                None => {
                    return self.err("external.truth", format!("no value for {}", p.name));
                }
            }
        }
        Ok(v)
    }

    /// What each parameter drives, from `[external.drives]` (`None` where not declared).
    fn external_targets(
        &self,
        e: &ExternalSpec,
        params: &ParamSpace,
        state_names: &[String],
        measurement_names: &[String],
    ) -> VResult<Vec<Option<Target>>> {
        let mut targets = vec![None; params.params.len()];
        for (name, comps) in e.drives.iter().flatten() {
            let field = format!("external.drives.{name}");
            let Some(i) = params.index(name) else {
                return self.err(field, "not one of [params]");
            };
            if comps.is_empty() {
                return self.err(
                    field,
                    "empty: name the state or measurement components it drives",
                );
            }
            let find = |list: &[String], c: &str| list.iter().position(|n| n == c);
            let states: Option<Vec<usize>> = comps.iter().map(|c| find(state_names, c)).collect();
            let meas: Option<Vec<usize>> =
                comps.iter().map(|c| find(measurement_names, c)).collect();
            targets[i] = Some(match (states, meas) {
                (Some(s), _) => Target::process(&s),
                (None, Some(m)) => Target::measurement(&m),
                (None, None) => {
                    return self.err(
                        field,
                        unknown_component(comps, state_names, measurement_names, &e.sensors),
                    );
                }
            });
        }
        Ok(targets)
    }
}

/// Why the components `comps` of a `drives` entry are not all states or all measurements:
/// the first that is neither, and, when it names a sensor the file does not declare, the
/// sensors that are declared (a sensor named differently here and in `[external.sensors]`
/// is the usual cause).
fn unknown_component(
    comps: &[String],
    states: &[String],
    measurements: &[String],
    sensors: &indexmap::IndexMap<String, Vec<String>>,
) -> String {
    let declared: Vec<String> = sensors
        .iter()
        .map(|(s, c)| format!("{s} = [{}]", c.join(", ")))
        .collect();
    let known = || {
        let all: Vec<&str> = states
            .iter()
            .chain(measurements)
            .map(String::as_str)
            .collect();
        all.join(", ")
    };
    let unknown = comps
        .iter()
        .find(|c| !states.contains(c) && !measurements.contains(c));
    match unknown {
        Some(c) => {
            let sensor = c.rsplit_once('_').map(|(s, _)| s);
            match sensor {
                Some(s) if !sensors.contains_key(s) && !states.contains(c) => format!(
                    "'{c}' is neither a state nor a measurement component: no sensor '{s}' in [external] sensors, which declares {} (a measurement component is <sensor>_<component>)",
                    if declared.is_empty() {
                        "none".to_string()
                    } else {
                        declared.join(", ")
                    }
                ),
                _ => format!(
                    "'{c}' is neither a state nor a measurement component; known: {}",
                    known()
                ),
            }
        }
        None => format!(
            "give state components (process noise) or measurement components (measurement noise), all of one kind, from: {}",
            known()
        ),
    }
}

/// For a command given as a bare name (no `/`) that is not found on `PATH` but names a file
/// in the problem's directory `dir`: the one-line hint to write `./name` (a bare name is
/// looked up on `PATH` only, as a shell does, never in the problem's directory).
fn bare_command_hint(program: &str, dir: &std::path::Path) -> Option<String> {
    if program.contains('/') || program.contains(std::path::MAIN_SEPARATOR) {
        return None;
    }
    let path = std::env::var_os("PATH").unwrap_or_default();
    let on_path = std::env::split_paths(&path).any(|d| {
        let candidate = if d.as_os_str().is_empty() {
            std::path::PathBuf::from(program)
        } else {
            d.join(program)
        };
        candidate.is_file()
    });
    if on_path {
        return None;
    }
    // A name found nowhere is left to the start of the worker, which says so.
    dir.join(program).is_file().then(|| {
        format!(
            "'{program}' is looked up on PATH, where it is not; write \"./{program}\" for the program in the problem's directory"
        )
    })
}
