//! How a packed vector is sent: its tag byte, then its values.

/// Every value, 8 bytes each.
pub const WHOLE: u8 = 0;
/// Nothing: each value is the square of the vector before it, to the bit.
pub const SQUARE: u8 = 1;
/// Whole numbers in 0..=255, a byte each.
pub const BYTES: u8 = 2;
/// Whole numbers in 0..=65535, two bytes each.
pub const PAIRS: u8 = 3;
