//! What ranks send each other: rank 0's requests and the ranks' answers, as bytes.

use super::super::SumsShape;
use crate::experiment::Experiment;
use crate::montecarlo::{Engine, McConfig};
use crate::stats::{Accumulator, GateMode};

/// Why a rank's answer does not decode (it is refused, with the rank named).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub(super) enum AnswerError {
    #[error("it ends early")]
    EndsEarly,
    #[error("a count out of range")]
    CountOutOfRange,
    #[error("chunk {0} is beyond the evaluation's runs")]
    BeyondRuns(usize),
    #[error("run {0} is beyond the evaluation's runs")]
    RunBeyondRuns(usize),
    #[error(transparent)]
    Wire(#[from] crate::records::WireError),
}

/// An evaluation as rank 0 asks for it.
pub(super) struct Request {
    pub(super) tag: i32,
    pub(super) theta: Vec<f64>,
    pub(super) mc: McConfig,
    pub(super) engine: Engine,
    /// Shared by runs within every chunk rather than by chunks ([`super::super::deal_by_runs`]).
    pub(super) by_runs: bool,
}

impl Request {
    pub(super) fn encode(&self) -> Vec<u8> {
        let mut out = Vec::new();
        let mut u = |x: u64| out.extend_from_slice(&x.to_le_bytes());
        u(self.tag as u64);
        u(self.theta.len() as u64);
        for t in &self.theta {
            u(t.to_bits());
        }
        let mc = &self.mc;
        for x in [mc.runs(), mc.steps(), mc.lags()] {
            u(x as u64);
        }
        u(mc.seed());
        u(mc.alpha().to_bits());
        u(match mc.gate() {
            GateMode::Full => 0,
            GateMode::Mean => 1,
        });
        u(match self.engine {
            Engine::Auto => 0,
            Engine::Linear => 1,
            Engine::Generic => 2,
        });
        u(u64::from(self.by_runs));
        out
    }

    pub(super) fn decode(bytes: &[u8]) -> Option<Request> {
        let mut words = bytes
            .chunks_exact(8)
            .map(|b| u64::from_le_bytes(b.try_into().expect("8 bytes")));
        let mut next = || words.next();
        let tag = i32::try_from(next()?).ok()?;
        let n = usize::try_from(next()?).ok()?;
        let theta = (0..n)
            .map(|_| next().map(f64::from_bits))
            .collect::<Option<Vec<f64>>>()?;
        let (runs, steps, lags) = (next()?, next()?, next()?);
        let (seed, alpha) = (next()?, f64::from_bits(next()?));
        let gate = [GateMode::Full, GateMode::Mean]
            .get(next()? as usize)
            .copied()?;
        let engine = [Engine::Auto, Engine::Linear, Engine::Generic]
            .get(next()? as usize)
            .copied()?;
        let by_runs = [false, true].get(next()? as usize).copied()?;
        let mc = McConfig::new(runs, steps)
            .and_then(|m| m.with_alpha(alpha))
            .and_then(|m| m.with_lags(lags))
            .ok()?
            .with_seed(seed)
            .with_gate(gate);
        Some(Request {
            tag,
            theta,
            mc,
            engine,
            by_runs,
        })
    }
}

/// A rank's sums into `out` (cleared first, so a rank reuses one buffer for its answers
/// rather than faulting in fresh pages each evaluation): the count, then each piece's index
/// (a chunk's, or a run's when shared by runs), length and sums format bytes.
pub(super) fn encode_answer_into(
    out: &mut Vec<u8>,
    parts: &[(usize, Accumulator)],
    mc: &McConfig,
    e: &dyn Experiment,
    by_runs: bool,
) {
    let shape = SumsShape::of(e, mc);
    out.clear();
    out.extend_from_slice(&(parts.len() as u64).to_le_bytes());
    for (c, sums) in parts {
        out.extend_from_slice(&(*c as u64).to_le_bytes());
        let at = out.len();
        out.extend_from_slice(&[0; 8]);
        shape.encode_packed_into(out, *c, sums, by_runs);
        let len = (out.len() - at - 8) as u64;
        out[at..at + 8].copy_from_slice(&len.to_le_bytes());
    }
}

/// A rank's answer into `pieces`, whose first n entries it fills and whose sums it reuses
/// (rank 0 reads thousands of runs' sums a tune): n, the answer's count of pieces.
pub(super) fn decode_answer_into(
    bytes: &[u8],
    mc: &McConfig,
    e: &dyn Experiment,
    by_runs: bool,
    pieces: &mut Vec<(usize, Accumulator)>,
) -> Result<usize, AnswerError> {
    let mut at = 0;
    fn word(bytes: &[u8], at: &mut usize) -> Result<usize, AnswerError> {
        let b = bytes.get(*at..*at + 8).ok_or(AnswerError::EndsEarly)?;
        *at += 8;
        usize::try_from(u64::from_le_bytes(b.try_into().expect("8 bytes")))
            .map_err(|_| AnswerError::CountOutOfRange)
    }
    let shape = SumsShape::of(e, mc);
    let n = word(bytes, &mut at)?;
    for k in 0..n {
        let c = word(bytes, &mut at)?;
        let len = word(bytes, &mut at)?;
        let body = bytes
            .get(at..at.saturating_add(len))
            .ok_or(AnswerError::EndsEarly)?;
        at += len;
        if by_runs && c >= mc.runs() {
            return Err(AnswerError::RunBeyondRuns(c));
        }
        if !by_runs && c >= shape.chunks() {
            return Err(AnswerError::BeyondRuns(c));
        }
        if k == pieces.len() {
            pieces.push((c, shape.empty()));
        }
        let (index, sums) = &mut pieces[k];
        *index = c;
        shape.decode_packed_into(c, body, by_runs, sums)?;
    }
    Ok(n)
}
