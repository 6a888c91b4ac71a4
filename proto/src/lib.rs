//! `scalpel-proto`: what scalpel's processes exchange.
//!
//! - [`shm`]: the shared-memory services of a station (iceoryx2): device pose in, device
//!   force out, render frames and their event. The layouts are `#[repr(C)]` with a version
//!   field so that a client in any language can read them; docs/PROTOCOL.md describes them
//!   byte by byte.
//! - [`wire`] and [`codec`]: the QUIC protocol's messages and their one codec (bincode 2
//!   with size limits, length-prefixed frames).

pub mod codec;
pub mod shm;
pub mod wire;
