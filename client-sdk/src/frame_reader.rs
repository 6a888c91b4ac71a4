//! Reading a station's render frames from shared memory (docs/PROTOCOL.md): attach at any
//! time, wait for the new-frame event, take the newest frame. A frame whose header does not
//! describe its payload (another layout version, inconsistent offsets) is refused with
//! what is wrong, never drawn.

use std::time::Duration;

use iceoryx2::port::listener::Listener;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::prelude::*;
use scalpel_proto::shm::{self, FrameHeader, FrameLayout, ShmError};

/// A render frame, copied out of shared memory.
#[derive(Debug, Clone, PartialEq)]
pub struct Frame {
    /// The header as sent.
    pub header: FrameHeader,
    /// Vertex positions (m).
    pub positions: Vec<[f32; 3]>,
    /// Vertex normals.
    pub normals: Vec<[f32; 3]>,
    /// Triangles.
    pub triangles: Vec<[u32; 3]>,
    /// Material of each triangle (`shm::MATERIAL_*`).
    pub materials: Vec<u8>,
    /// When this reader took the frame from shared memory (CLOCK_MONOTONIC, ns; 0 for a
    /// frame decoded from bytes): with the header's `pose_received_ns`, the frame's
    /// pose-to-renderer latency.
    pub received_ns: u64,
}

impl Frame {
    /// Decodes a frame from its header and payload bytes.
    pub fn decode(header: &FrameHeader, bytes: &[u8]) -> Result<Self, ShmError> {
        let layout = FrameLayout::of(header, bytes.len())?;
        let f32s = |offset: usize, n: usize| -> Vec<[f32; 3]> {
            bytes[offset..offset + 12 * n]
                .chunks_exact(12)
                .map(|c| {
                    let f = |i: usize| f32::from_le_bytes([c[i], c[i + 1], c[i + 2], c[i + 3]]);
                    [f(0), f(4), f(8)]
                })
                .collect()
        };
        let triangles: Vec<[u32; 3]> = bytes
            [layout.triangles..layout.triangles + 12 * layout.n_triangles]
            .chunks_exact(12)
            .map(|c| {
                let u = |i: usize| u32::from_le_bytes([c[i], c[i + 1], c[i + 2], c[i + 3]]);
                [u(0), u(4), u(8)]
            })
            .collect();
        if let Some((t, v)) = triangles.iter().enumerate().find_map(|(t, tri)| {
            tri.iter()
                .find(|&&v| v as usize >= layout.n_vertices)
                .map(|&v| (t, v))
        }) {
            return Err(ShmError::Layout {
                detail: format!(
                    "frame {}: triangle {t} names vertex {v} of {}",
                    header.frame, layout.n_vertices
                ),
            });
        }
        Ok(Self {
            header: *header,
            positions: f32s(layout.positions, layout.n_vertices),
            normals: f32s(layout.normals, layout.n_vertices),
            triangles,
            materials: bytes[layout.materials..layout.materials + layout.n_triangles].to_vec(),
            received_ns: 0,
        })
    }
}

/// CLOCK_MONOTONIC now (ns), the clock the server stamps frames with.
pub fn monotonic_ns() -> u64 {
    let t = rustix::time::clock_gettime(rustix::time::ClockId::Monotonic);
    t.tv_sec as u64 * 1_000_000_000 + t.tv_nsec as u64
}

/// A renderer's attachment to a station's frames.
pub struct FrameReader {
    frames: Subscriber<ipc::Service, [u8], FrameHeader>,
    events: Listener<ipc::Service>,
    _node: Node<ipc::Service>,
}

impl FrameReader {
    /// Attaches to `station`'s frames (the server need not run yet).
    pub fn open(station: &str) -> Result<Self, ShmError> {
        Self::open_as("scalpel-viewer", station)
    }

    /// Attaches as `role` (the node's name is `role.station`).
    pub fn open_as(role: &str, station: &str) -> Result<Self, ShmError> {
        let node = shm::node(role, station)?;
        let frames = shm::frame_service(&node, station)?
            .subscriber_builder()
            .create()
            .map_err(|e| shm::iceoryx("subscribing to frames of station", station, e))?;
        let events = shm::frame_events(&node, station)?
            .listener_builder()
            .create()
            .map_err(|e| shm::iceoryx("listening for frames of station", station, e))?;
        Ok(Self {
            frames,
            events,
            _node: node,
        })
    }

    /// The newest frame waiting, if any (older ones are skipped).
    pub fn latest(&mut self) -> Result<Option<Frame>, ShmError> {
        let mut newest = None;
        loop {
            match self.frames.receive() {
                Ok(Some(sample)) => {
                    let received_ns = monotonic_ns();
                    let mut frame = Frame::decode(sample.user_header(), sample.payload())?;
                    frame.received_ns = received_ns;
                    newest = Some(frame);
                }
                Ok(None) => return Ok(newest),
                Err(e) => return Err(shm::iceoryx("receiving", "a frame", e)),
            }
        }
    }

    /// Waits up to `timeout` for a new frame and returns the newest.
    pub fn wait(&mut self, timeout: Duration) -> Result<Option<Frame>, ShmError> {
        if let Some(frame) = self.latest()? {
            return Ok(Some(frame));
        }
        self.events
            .timed_wait(|_| {}, timeout)
            .map_err(|e| shm::iceoryx("waiting for", "a frame", e))?;
        self.latest()
    }
}
