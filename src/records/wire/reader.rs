//! Reading the sums format: every read bounds-checked, a refusal rather than a panic.

use super::error::WireError;
use super::packing;

/// Reads the encoded bytes in order, every read checked.
pub(super) struct Reader<'a> {
    pub(super) bytes: &'a [u8],
    pub(super) at: usize,
}

impl Reader<'_> {
    pub(super) fn take(&mut self, n: usize) -> Result<&[u8], WireError> {
        let end = self
            .at
            .checked_add(n)
            .filter(|&e| e <= self.bytes.len())
            .ok_or(WireError::Truncated(self.bytes.len()))?;
        let s = &self.bytes[self.at..end];
        self.at = end;
        Ok(s)
    }

    pub(super) fn u64(&mut self) -> Result<u64, WireError> {
        let b = self.take(8)?;
        Ok(u64::from_le_bytes(b.try_into().expect("8 bytes")))
    }

    pub(super) fn f64(&mut self) -> Result<f64, WireError> {
        self.u64().map(f64::from_bits)
    }

    /// `v`'s values packed as `tag` (`square_of`: the vector before it, for
    /// [`packing::SQUARE`]). A vector at a time, not a value at a time: rank 0 of an MPI job
    /// reads every run's sums of every rank, and the bounds are checked once a vector.
    pub(super) fn vector(
        &mut self,
        tag: u8,
        square_of: Option<&[f64]>,
        v: &mut [f64],
    ) -> Result<(), WireError> {
        let bytes = |width: usize| v.len().checked_mul(width);
        let truncated = WireError::Truncated(self.bytes.len());
        match (tag, square_of) {
            (packing::SQUARE, Some(b)) => v.iter_mut().zip(b).for_each(|(x, b)| *x = b * b),
            (packing::BYTES, _) => {
                let src = self.take(v.len())?;
                v.iter_mut().zip(src).for_each(|(x, &b)| *x = f64::from(b));
            }
            (packing::PAIRS, _) => {
                let src = self.take(bytes(2).ok_or(truncated)?)?;
                v.iter_mut()
                    .zip(src.chunks_exact(2))
                    .for_each(|(x, p)| *x = f64::from(u16::from_le_bytes([p[0], p[1]])));
            }
            _ => {
                let src = self.take(bytes(8).ok_or(truncated)?)?;
                v.iter_mut().zip(src.chunks_exact(8)).for_each(|(x, p)| {
                    *x = f64::from_le_bytes(p.try_into().expect("chunks of 8 bytes"));
                });
            }
        }
        Ok(())
    }

    /// A size or count: anything above `limit` is refused as `what`.
    pub(super) fn size(&mut self, what: &'static str, limit: usize) -> Result<usize, WireError> {
        let x = self.u64()?;
        usize::try_from(x)
            .ok()
            .filter(|&x| x <= limit)
            // Made only when refused: its value is formatted.
            .ok_or_else(|| WireError::Impossible {
                what,
                value: x.to_string(),
            })
    }
}
