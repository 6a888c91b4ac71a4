//! Frames for remote observers. The network thread reads the station's own shared-memory
//! render frames like any local renderer (no extra hand-off from the simulation thread),
//! and each observer's encoder turns the newest one into an [`ObserverFrame`]: a keyframe
//! (topology, positions quantized to 16 bits over the surface's box) when the observer
//! has none, when the topology changed (a cut) or once a second; otherwise the positions as
//! differences from the keyframe's codes (mostly one byte each in the varint encoding).

use std::sync::Arc;

use scalpel_client::frame_reader::Frame;
use scalpel_proto::wire::{ObserverFrame, ToolState, Topology, quantize, quantize_one};

/// A keyframe at least this often (frames).
pub const KEYFRAME_EVERY: u64 = 30;

/// A frame read from shared memory, shared by every observer's encoder.
#[derive(Debug)]
pub struct SourceFrame {
    /// The frame.
    pub frame: Frame,
    /// Hash of its triangles and materials: equal hashes, same topology.
    pub topology: u64,
}

impl SourceFrame {
    /// Wraps a frame read from shared memory.
    pub fn new(frame: Frame) -> Arc<Self> {
        let topology = topology_hash(&frame);
        Arc::new(Self { frame, topology })
    }
}

/// FNV-1a over the triangles and materials.
fn topology_hash(frame: &Frame) -> u64 {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    let mut eat = |x: u32| {
        for b in x.to_le_bytes() {
            h ^= u64::from(b);
            h = h.wrapping_mul(0x0000_0100_0000_01b3);
        }
    };
    eat(frame.positions.len() as u32);
    for t in &frame.triangles {
        t.iter().for_each(|&v| eat(v));
    }
    for &m in &frame.materials {
        eat(u32::from(m));
    }
    h
}

/// The keyframe an observer has.
struct Key {
    frame: u64,
    topology: u64,
    origin: [f32; 3],
    step: f32,
    codes: Vec<[i16; 3]>,
}

/// One observer's frame encoder.
#[derive(Default)]
pub struct FrameEncoder {
    next: u64,
    key: Option<Key>,
}

impl FrameEncoder {
    /// A new observer's encoder (it starts with a keyframe).
    pub fn new() -> Self {
        Self::default()
    }

    /// Forget the keyframe (the one sent may not have arrived): the next frame is one.
    pub fn reset(&mut self) {
        self.key = None;
    }

    /// The observer frame for `source`.
    pub fn encode(&mut self, source: &SourceFrame) -> ObserverFrame {
        self.next += 1;
        let f = &source.frame;
        let h = &f.header;
        let tool = (h.flags & scalpel_proto::shm::FRAME_TOOL_PRESENT != 0).then_some(ToolState {
            tip_m: h.tool_tip_m,
            orientation_xyzw: h.tool_orientation_xyzw,
            force_n: h.force_n,
        });
        let stale = match &self.key {
            None => true,
            Some(k) => {
                k.topology != source.topology
                    || k.codes.len() != f.positions.len()
                    || self.next - k.frame >= KEYFRAME_EVERY
            }
        };
        if stale {
            let (origin, step, codes) = quantize(&f.positions);
            self.key = Some(Key {
                frame: self.next,
                topology: source.topology,
                origin,
                step,
                codes: codes.clone(),
            });
            return ObserverFrame {
                frame: self.next,
                keyframe: self.next,
                sim_tick: h.sim_tick,
                server_time_ns: h.server_time_ns,
                topology: Some(Topology {
                    triangles: f.triangles.clone(),
                    materials: f.materials.clone(),
                }),
                origin_m: origin,
                step_m: step,
                positions: codes,
                tool,
            };
        }
        let key = self.key.as_ref().expect("checked above");
        // Differences wrap: the observer adds them back with the same wrapping, exactly.
        let positions = f
            .positions
            .iter()
            .zip(&key.codes)
            .map(|(p, k)| {
                [0, 1, 2].map(|c| quantize_one(p[c], key.origin[c], key.step).wrapping_sub(k[c]))
            })
            .collect();
        ObserverFrame {
            frame: self.next,
            keyframe: key.frame,
            sim_tick: h.sim_tick,
            server_time_ns: h.server_time_ns,
            topology: None,
            origin_m: key.origin,
            step_m: key.step,
            positions,
            tool,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use scalpel_proto::shm::FrameHeader;
    use scalpel_proto::wire::FrameDecoder;

    fn frame(positions: Vec<[f32; 3]>, triangles: Vec<[u32; 3]>) -> Arc<SourceFrame> {
        let n = triangles.len();
        SourceFrame::new(Frame {
            header: FrameHeader::default(),
            normals: vec![[0.0, 0.0, 1.0]; positions.len()],
            positions,
            triangles,
            materials: vec![0; n],
            received_ns: 0,
        })
    }

    #[test]
    fn keyframes_and_differences_decode_to_the_positions() {
        let tri = vec![[0, 1, 2], [0, 2, 3]];
        let base: Vec<[f32; 3]> = vec![
            [0.0, 0.0, 0.0],
            [0.1, 0.0, 0.0],
            [0.1, 0.05, 0.0],
            [0.0, 0.05, 0.02],
        ];
        let mut encoder = FrameEncoder::new();
        let mut decoder = FrameDecoder::new();
        let mut sizes = Vec::new();
        for k in 0..65 {
            let t = k as f32 * 1e-3;
            let moved: Vec<[f32; 3]> = base
                .iter()
                .map(|p| [p[0] + 0.2 * t, p[1], p[2] - 0.5 * t])
                .collect();
            // A cut changes the topology at frame 40.
            let (positions, triangles) = if k >= 40 {
                let mut p = moved.clone();
                p.push([0.05, 0.02, 0.0]);
                (p, vec![[0, 1, 4], [1, 2, 4], [0, 2, 3]])
            } else {
                (moved.clone(), tri.clone())
            };
            let source = frame(positions.clone(), triangles.clone());
            let message = encoder.encode(&source);
            assert_eq!(
                message.topology.is_some(),
                k == 0 || k == 30 || k == 40,
                "frame {k}: keyframe only at the start, a second later and on the cut"
            );
            sizes.push(
                scalpel_proto::codec::encode::<_, { scalpel_proto::codec::SERVER_LIMIT }>(&message)
                    .unwrap()
                    .len(),
            );
            let decoded = decoder.decode(&message).expect("decodes");
            assert_eq!(decoded.topology.triangles, triangles);
            for (got, want) in decoded.positions.iter().zip(&positions) {
                for c in 0..3 {
                    assert!((got[c] - want[c]).abs() <= 0.51 * message.step_m);
                }
            }
        }
        // Difference frames are smaller than keyframes.
        assert!(sizes[5] < sizes[0], "{sizes:?}");
        // A difference frame without its keyframe is dropped, not misread.
        let mut late = FrameDecoder::new();
        let mut last = base.clone();
        last.push([0.05, 0.02, 0.0]);
        let message = encoder.encode(&frame(last, vec![[0, 1, 4], [1, 2, 4], [0, 2, 3]]));
        assert!(message.topology.is_none() && late.decode(&message).is_none());
    }
}
