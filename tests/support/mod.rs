//! Test support for issues 23 and 37: a ULog writer and PX4 fixtures with known truth.
#![allow(dead_code)]

pub mod px4_fixtures;
pub mod px4_shapes;
pub mod ulog;
