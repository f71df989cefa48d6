//! The records format of `docs/external.md` read as a field log: each run is a sequence of
//! updates, its step the time; state quantities (ground truth) are ignored.

use std::path::PathBuf;

use super::LogSource;
use super::analysis::{AnalyzerError, NisAnalyzer, SensorInfo, Update};
use crate::input::FileError;
use crate::records::{
    Layout, SensorShapeError, StepRecord, StepSink, feed_files, normalize_sensor, scan_files,
};

/// Why a record cannot be read as a field log's updates.
#[derive(Debug, thiserror::Error)]
enum LogRecordError {
    /// A sensor index the layout does not have.
    #[error("run {run}, step {step}: sensor index {index}")]
    SensorIndex {
        run: usize,
        step: usize,
        index: usize,
    },
    /// A sensor's record that does not fit its layout.
    #[error("run {run}, step {step}: {problem}")]
    Shape {
        run: usize,
        step: usize,
        problem: SensorShapeError,
    },
    /// Degrees of freedom beyond what a sensor of the analyzer may have.
    #[error(
        "run {run}, step {step}: nis_dof {dof} is not a whole number in 1..={}",
        super::ingest::MAX_DIM
    )]
    Dof { run: usize, step: usize, dof: f64 },
    /// An update the analyzer refuses.
    #[error(transparent)]
    Analyzer(#[from] AnalyzerError),
}

/// Streams records into an analyzer.
struct Sink<'a> {
    layout: Layout,
    an: &'a mut NisAnalyzer,
    ids: Vec<usize>,
    run: Option<usize>,
    stopped: bool,
    rows: usize,
    diverged: Vec<String>,
}

impl StepSink for Sink<'_> {
    type Error = LogRecordError;

    fn push(&mut self, r: StepRecord) -> Result<(), LogRecordError> {
        self.rows += 1;
        if self.run != Some(r.run) {
            self.run = Some(r.run);
            self.stopped = false;
            self.an.break_sequences();
        }
        if self.stopped {
            return Ok(());
        }
        if let Some(why) = &r.diverged {
            self.stop(r.run, r.step, why);
            return Ok(());
        }
        let (run, step) = (r.run, r.step);
        for (s, rec) in &r.sensors {
            let layout = self
                .layout
                .sensors
                .get(*s)
                .ok_or(LogRecordError::SensorIndex {
                    run,
                    step,
                    index: *s,
                })?;
            let n = match normalize_sensor(rec, layout.dim, layout.components) {
                Ok(Ok(n)) => n,
                Ok(Err(why)) => {
                    self.stop(run, step, &why.to_string());
                    return Ok(());
                }
                Err(problem) => return Err(LogRecordError::Shape { run, step, problem }),
            };
            if n.dof.fract() != 0.0 || n.dof > super::ingest::MAX_DIM as f64 {
                return Err(LogRecordError::Dof {
                    run,
                    step,
                    dof: n.dof,
                });
            }
            self.an.push(
                self.ids[*s],
                Update {
                    time: r.step as f64,
                    nis: n.nis,
                    dof: n.dof as usize,
                    u: n.u,
                    sd: None,
                },
            )?;
        }
        Ok(())
    }
}

impl Sink<'_> {
    fn stop(&mut self, run: usize, step: usize, why: &str) {
        self.stopped = true;
        if self.diverged.len() < 3 {
            self.diverged
                .push(format!("run {run} stopped at step {step} ({why})"));
        }
    }
}

/// Read records files (one source: several `.npy` files of one set of arrays, or one file).
pub(super) fn read(paths: &[PathBuf], an: &mut NisAnalyzer) -> Result<LogSource, FileError> {
    let (layout, steps) = scan_files(paths)?;
    let names = layout.default_measurement_names();
    let mut at = 0;
    let mut ids = Vec::new();
    for s in &layout.sensors {
        let components = if s.components {
            let c = names[at..at + s.dim].to_vec();
            at += s.dim;
            c
        } else {
            Vec::new()
        };
        let name = if s.name.is_empty() { "z" } else { &s.name };
        ids.push(
            an.sensor(SensorInfo {
                name: name.to_string(),
                components,
                group: String::new(),
            })
            .map_err(|e| FileError::new(&paths[0], "", e.to_string()))?,
        );
    }
    let mut sink = Sink {
        layout: layout.clone(),
        an,
        ids,
        run: None,
        stopped: false,
        rows: 0,
        diverged: Vec::new(),
    };
    feed_files(paths, &layout, steps, &mut sink)?;
    let mut source = LogSource::new(&paths[0], "records");
    source.rows = sink.rows;
    if layout.state.is_some() {
        source
            .notes
            .push("the records' ground-truth quantities are ignored: judged by the innovations alone (autotune check --records uses them)".into());
    }
    for d in &sink.diverged {
        source
            .notes
            .push(format!("{d}: its later steps are not judged"));
    }
    Ok(source)
}
