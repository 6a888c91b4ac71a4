#![allow(dead_code)] // each test binary uses its part of the helpers
//! Helpers shared by the integration tests.

pub mod conformance;
pub mod station;
