//! The decoders of untrusted input, one entry point each, shared by the cargo-fuzz targets
//! (fuzz_targets/) and the corpus replay test that CI runs on stable
//! (tools/tests/fuzz_corpus.rs includes this file). Every entry point must return —
//! an error is fine — for any bytes: no panic, no abort, no unbounded allocation.

use std::path::Path;

use scalpel_proto::codec::{CLIENT_LIMIT, SERVER_LIMIT, decode};
use scalpel_proto::shm::FrameHeader;
use scalpel_proto::wire::{ClientMessage, FrameDecoder, ServerMessage};

/// A framed client message as the server reads it: a 4-byte length, then the payload.
pub fn client_message(data: &[u8]) {
    let _ = decode::<ClientMessage, CLIENT_LIMIT>(data);
    if data.len() >= 4 {
        let len = u32::from_le_bytes([data[0], data[1], data[2], data[3]]) as usize;
        if len <= CLIENT_LIMIT && data.len() >= 4 + len {
            let _ = decode::<ClientMessage, CLIENT_LIMIT>(&data[4..4 + len]);
        }
    }
}

/// A server message as a client reads it, and a frame through a client's decoder.
pub fn server_message(data: &[u8]) {
    if let Ok(ServerMessage::Frame(frame)) = decode::<ServerMessage, SERVER_LIMIT>(data) {
        let mut decoder = FrameDecoder::new();
        let _ = decoder.decode(&frame);
        let _ = decoder.decode(&frame);
    }
}

fn u32_at(b: &[u8], at: usize) -> u32 {
    u32::from_le_bytes([b[at], b[at + 1], b[at + 2], b[at + 3]])
}

fn u64_at(b: &[u8], at: usize) -> u64 {
    u64::from(u32_at(b, at)) | u64::from(u32_at(b, at + 4)) << 32
}

fn f32_at(b: &[u8], at: usize) -> f32 {
    f32::from_bits(u32_at(b, at))
}

/// A render frame from shared memory (another process wrote it): 120 header bytes as
/// docs/PROTOCOL.md lays them out, then the payload.
pub fn shm_frame(data: &[u8]) {
    if data.len() < 120 {
        return;
    }
    let (h, payload) = data.split_at(120);
    let header = FrameHeader {
        layout_version: u32_at(h, 0),
        flags: u32_at(h, 4),
        frame: u64_at(h, 8),
        sim_tick: u64_at(h, 16),
        server_time_ns: u64_at(h, 24),
        pose_seq: u64_at(h, 32),
        pose_received_ns: u64_at(h, 40),
        n_vertices: u32_at(h, 48),
        n_triangles: u32_at(h, 52),
        positions_offset: u32_at(h, 56),
        normals_offset: u32_at(h, 60),
        triangles_offset: u32_at(h, 64),
        materials_offset: u32_at(h, 68),
        tool_tip_m: [f32_at(h, 72), f32_at(h, 76), f32_at(h, 80)],
        blade_length_m: f32_at(h, 84),
        tool_orientation_xyzw: [f32_at(h, 88), f32_at(h, 92), f32_at(h, 96), f32_at(h, 100)],
        force_n: [f32_at(h, 104), f32_at(h, 108), f32_at(h, 112)],
        cut_length_mm: f32_at(h, 116),
    };
    let _ = scalpel_client::frame_reader::Frame::decode(&header, payload);
}

/// A mesh file; the first byte picks the format.
pub fn mesh(data: &[u8]) {
    use scalpel_sim::geometry::{ImportLimits, LengthUnit, MeshFormat, import_mesh};
    let Some((&which, bytes)) = data.split_first() else {
        return;
    };
    let format = match which % 4 {
        0 => MeshFormat::Obj,
        1 => MeshFormat::Stl,
        2 => MeshFormat::Ply,
        _ => MeshFormat::Vtk,
    };
    let limits = ImportLimits {
        max_file_bytes: 1 << 20,
        max_triangles: 20_000,
    };
    let _ = import_mesh(bytes, format, "fuzz", LengthUnit::Mm, &limits);
}

/// A text file a user hands the server or the tools; the first byte picks which.
pub fn text_config(data: &[u8]) {
    let Some((&which, bytes)) = data.split_first() else {
        return;
    };
    let Ok(text) = std::str::from_utf8(bytes) else {
        return;
    };
    match which % 4 {
        0 => {
            let _ = scalpel_server::config::ServerConfig::from_toml(text, Path::new("fuzz.toml"));
        }
        1 => {
            let _ = scalpel_sim::scene::SceneSpec::from_toml(text, Path::new("fuzz.toml"));
        }
        2 => {
            let _ = scalpel_sim::pipeline::CutScript::from_toml(text, "fuzz.toml");
        }
        _ => {
            let _ = scalpel_sim::pipeline::CutScript::from_csv(text, "fuzz.csv");
        }
    }
}
