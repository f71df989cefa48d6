//! Fingerprints of a worker's runs, taken as their records stream by: what the seed-contract
//! check compares when it asks for the first chunk's runs again.

use std::collections::BTreeMap;

use crate::records::{RecordError, RecordSink, StepRecord, StepSink};

/// Fingerprints of runs' records, by run: equal records give equal fingerprints.
#[derive(Debug, Default)]
pub(super) struct Fingerprints(pub(super) BTreeMap<usize, u64>);

impl Fingerprints {
    pub(super) fn new() -> Self {
        Self::default()
    }
}

/// A sink that fingerprints each record (all but its run number) on its way to `sink`.
pub(super) struct Fingerprinting<'a> {
    pub(super) sink: &'a mut RecordSink,
    pub(super) prints: &'a mut Fingerprints,
}

impl StepSink for Fingerprinting<'_> {
    type Error = RecordError;

    fn push(&mut self, r: StepRecord) -> Result<(), RecordError> {
        let print = crate::records::fingerprint(self.prints.0.get(&r.run).copied(), &r);
        self.prints.0.insert(r.run, print);
        self.sink.push(r)
    }
}
