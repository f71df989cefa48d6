//! Test support for issue 23: a ULog writer and PX4 fixtures with known truth.
#![allow(dead_code)]

pub mod px4_fixtures;
pub mod ulog;
