//! scalpel-client: programs that talk to a scalpel server, and what they share.
//!
//! For now: the headless CPU renderer (`renderer` feature) used by `scalpel cut` and, later,
//! by the local viewer. Observer, instructor and mock-device clients follow with the server.

#[cfg(feature = "renderer")]
pub mod render;
