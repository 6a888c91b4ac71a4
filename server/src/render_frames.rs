//! Render frames over shared memory: the simulation thread writes the current surface
//! straight into a loaned shared-memory sample (no intermediate copy of the vertex data),
//! sends it on `scalpel/<station>/render/frames` and announces it on `.../render/events`
//! (docs/PROTOCOL.md). Renderers attach and detach at any time; a new one is connected by
//! the next send (within one frame period) and handed the last frame too (history 1). The
//! sample is a byte slice whose shared memory grows in powers of two, so cuts that add
//! vertices never hit a fixed capacity (tests/frames.rs starts it with room for 10).

use iceoryx2::port::notifier::Notifier;
use iceoryx2::port::publisher::Publisher;
use iceoryx2::prelude::*;
use scalpel_proto::shm::{self, FrameHeader, FrameLayout, LAYOUT_VERSION};
use scalpel_sim::cut::{FaceKind, ToolPose};
use scalpel_sim::math::Vec3;
use scalpel_sim::pipeline::Simulation;

/// What a frame says besides the surface.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FrameInfo {
    /// Simulation ticks so far.
    pub sim_tick: u64,
    /// The tool, if the device has reported one.
    pub tool: Option<ToolPose>,
    /// The device's sample counter of that pose (0: none).
    pub pose_seq: u64,
    /// When the haptic thread took that pose (CLOCK_MONOTONIC, ns; 0: none).
    pub pose_received_ns: u64,
    /// The simulation's force on the tool (N).
    pub force_n: Vec3,
    /// The blade is cutting.
    pub cutting: bool,
    /// Blade travel while cutting (mm).
    pub cut_length_mm: f64,
}

/// The frame end of a station's render services.
pub struct FramePublisher {
    publisher: Publisher<ipc::Service, [u8], FrameHeader>,
    notifier: Notifier<ipc::Service>,
    frame: u64,
    normals: Vec<Vec3>,
    blade_length_m: f64,
    _node: Node<ipc::Service>,
}

impl FramePublisher {
    /// Opens (or creates) the station's render services, sized for `sim`'s surface four
    /// times over before the shared memory has to grow.
    pub fn open(station: &str, sim: &Simulation) -> Result<Self, shm::ShmError> {
        let surface = &sim.current_surface().mesh;
        Self::open_with_room(
            station,
            sim,
            4 * surface.positions.len(),
            4 * surface.triangles.len(),
        )
    }

    /// Opens the render services with shared memory for a surface of `vertices` and
    /// `triangles` at first (it grows when a frame needs more).
    pub fn open_with_room(
        station: &str,
        sim: &Simulation,
        vertices: usize,
        triangles: usize,
    ) -> Result<Self, shm::ShmError> {
        let node = shm::node("scalpel-server.frames", station)?;
        let room = FrameLayout::new(vertices, triangles);
        let publisher = shm::frame_service(&node, station)?
            .publisher_builder()
            .initial_max_slice_len(room.len)
            .allocation_strategy(AllocationStrategy::PowerOfTwo)
            .create()
            .map_err(|e| shm::iceoryx("publishing frames of station", station, e))?;
        let notifier = shm::frame_events(&node, station)?
            .notifier_builder()
            .default_event_id(shm::new_frame_event())
            .create()
            .map_err(|e| shm::iceoryx("announcing frames of station", station, e))?;
        Ok(Self {
            publisher,
            notifier,
            frame: 0,
            normals: Vec::with_capacity(room.n_vertices),
            blade_length_m: sim.spec().tool.blade_length_m,
            _node: node,
        })
    }

    /// Frames sent so far.
    pub fn frames(&self) -> u64 {
        self.frame
    }

    /// Writes the current surface and `info` into a new frame and sends it.
    pub fn publish(&mut self, sim: &Simulation, info: &FrameInfo) -> Result<(), shm::ShmError> {
        let surface = sim.current_surface();
        let mesh = &surface.mesh;
        let drawn = surface
            .kinds
            .iter()
            .filter(|k| **k != FaceKind::Lid)
            .count();
        let layout = FrameLayout::new(mesh.positions.len(), drawn);
        vertex_normals(sim, &mut self.normals);

        let mut sample = self
            .publisher
            .loan_slice(layout.len)
            .map_err(|e| shm::iceoryx("loaning", "a frame", e))?;
        self.frame += 1;
        let header = sample.user_header_mut();
        *header = FrameHeader {
            layout_version: LAYOUT_VERSION,
            flags: if info.tool.is_some() {
                shm::FRAME_TOOL_PRESENT
            } else {
                0
            } | if info.cutting { shm::FRAME_CUTTING } else { 0 },
            frame: self.frame,
            sim_tick: info.sim_tick,
            server_time_ns: (crate::realtime::monotonic_s() * 1e9) as u64,
            pose_seq: info.pose_seq,
            pose_received_ns: info.pose_received_ns,
            blade_length_m: self.blade_length_m as f32,
            force_n: info.force_n.map(|c| c as f32).into(),
            cut_length_mm: info.cut_length_mm as f32,
            ..FrameHeader::default()
        };
        if let Some(tool) = info.tool {
            header.tool_tip_m = tool.tip_m.map(|c| c as f32).into();
            let q = tool.orientation.coords;
            header.tool_orientation_xyzw = [q.x as f32, q.y as f32, q.z as f32, q.w as f32];
        }
        layout.describe(header);

        let bytes = sample.payload_mut();
        let (positions, rest) = bytes[layout.positions..].split_at_mut(layout.normals);
        put_vectors(positions, &mesh.positions);
        let (normals, rest) = rest.split_at_mut(layout.triangles - layout.normals);
        put_vectors(normals, &self.normals);
        let (triangles, materials) = rest.split_at_mut(layout.materials - layout.triangles);
        let faces = mesh
            .triangles
            .iter()
            .zip(&surface.kinds)
            .filter(|(_, k)| **k != FaceKind::Lid);
        for (((t, k), out), material) in faces
            .zip(triangles.chunks_exact_mut(12))
            .zip(materials.iter_mut())
        {
            for (c, v) in out.chunks_exact_mut(4).zip(t) {
                c.copy_from_slice(&v.to_le_bytes());
            }
            *material = match k {
                FaceKind::Wall => shm::MATERIAL_WOUND,
                _ => shm::MATERIAL_SURFACE,
            };
        }
        sample
            .send()
            .map_err(|e| shm::iceoryx("sending", "a frame", e))?;
        // Nobody listening is not an error: renderers come and go.
        let _ = self.notifier.notify();
        Ok(())
    }
}

/// Writes vectors as little-endian f32 triples.
fn put_vectors(out: &mut [u8], vectors: &[Vec3]) {
    for (chunk, v) in out.chunks_exact_mut(12).zip(vectors) {
        for (c, x) in chunk.chunks_exact_mut(4).zip(v.iter()) {
            c.copy_from_slice(&(*x as f32).to_le_bytes());
        }
    }
}

/// Area-weighted vertex normals of the drawn surface (skin and walls).
fn vertex_normals(sim: &Simulation, normals: &mut Vec<Vec3>) {
    let surface = sim.current_surface();
    let p = &surface.mesh.positions;
    normals.clear();
    normals.resize(p.len(), Vec3::zeros());
    for (t, k) in surface.mesh.triangles.iter().zip(&surface.kinds) {
        if *k == FaceKind::Lid {
            continue;
        }
        let [a, b, c] = t.map(|i| i as usize);
        let n = (p[b] - p[a]).cross(&(p[c] - p[a]));
        for i in [a, b, c] {
            normals[i] += n;
        }
    }
    for n in normals.iter_mut() {
        *n = n.try_normalize(1e-30).unwrap_or_else(Vec3::z);
    }
}
