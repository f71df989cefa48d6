//! The commands as library functions: what `autotune check`, `tune`, `estimate`,
//! `simulate`, `init` and `nis` do, with their options as plain values (the same structs the
//! command line parses into) and their results returned. The files a command writes are
//! checked before its work and written together, atomically (`crate::output`), before it
//! returns; what it prints is rendered by [`crate::report`] from what it returns.
//!
//! [`crate::app`] is the command line over these: it parses, calls one of them, prints and
//! maps the result to an exit code. A Rust program gets the same behaviour by calling them
//! directly.

pub mod check;
mod error;
pub mod estimate;
pub mod init;
pub mod nis;
mod options;
pub mod simulate;
pub mod tune;

pub use crate::input::OneOf;
pub use error::CommandError;
pub use options::McOverrides;
