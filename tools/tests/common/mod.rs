#![allow(dead_code)] // each test binary uses its part of the helpers
//! Helpers shared by the integration tests.

pub mod browser;
pub mod conformance;
pub mod lesson_session;
pub mod station;
