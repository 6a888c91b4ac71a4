//! scalpel-sim: the physics core of scalpel, sans-IO.
//!
//! No threads, clocks, files or sockets: callers hand in bytes and time, and read results.

pub mod geometry;
pub mod math;
