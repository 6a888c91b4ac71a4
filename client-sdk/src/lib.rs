//! scalpel-client: programs that talk to a scalpel station, and what they share.
//!
//! - `render` (feature `renderer`): the headless CPU renderer used by `scalpel cut` and the
//!   viewer.
//! - `mock_device` (feature `mock-device`): the scripted haptic device over shared memory.
//! - `frame_reader` (feature `frames`): reading a station's render frames from shared memory.
//! - `remote` (feature `remote`): async `Observer` and `Instructor` over QUIC.

#[cfg(feature = "frames")]
pub mod frame_reader;
#[cfg(feature = "mock-device")]
pub mod mock_device;
#[cfg(feature = "remote")]
pub mod remote;
#[cfg(feature = "renderer")]
pub mod render;
