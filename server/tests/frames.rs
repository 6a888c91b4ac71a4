//! Render frames over shared memory, written by the server's frame publisher and read back
//! by the client SDK's reader: the surface arrives as it is in the simulation, and a surface
//! larger than the shared memory first set aside (cuts add vertices) still goes through.

use std::time::Duration;

use scalpel_client::frame_reader::FrameReader;
use scalpel_proto::shm::{self, FRAME_TOOL_PRESENT, MATERIAL_SURFACE};
use scalpel_server::render_frames::{FrameInfo, FramePublisher};
use scalpel_sim::cut::ToolPose;
use scalpel_sim::math::Vec3;
use scalpel_sim::pipeline::Simulation;

#[test]
fn frames_arrive_whole_and_grow_past_their_first_room() {
    shm::quiet_logging();
    let station = format!("t-frames-{}", std::process::id());
    let liver = scalpel_server::scene_file::load_scene("liver").unwrap();
    let sim = Simulation::new(&liver);
    let surface = &sim.current_surface().mesh;
    // Room for 10 vertices: the liver's 256 need the shared memory to grow.
    // The station's services, made as its server makes them.
    let _services =
        scalpel_server::device_monitor::DeviceMonitor::open(&station, Default::default()).unwrap();
    let mut publisher = FramePublisher::open_with_room(&station, &sim, 10, 16).unwrap();
    let mut reader = FrameReader::open(&station).unwrap();
    let tool = ToolPose::pointing(Vec3::new(0.0, 0.0, 0.03), Vec3::z());
    for k in 1..=3u64 {
        publisher
            .publish(
                &sim,
                &FrameInfo {
                    sim_tick: k,
                    tool: Some(tool),
                    pose_seq: k,
                    pose_received_ns: 1000 * k,
                    force_n: Vec3::new(0.0, 0.0, 1.5),
                    cutting: false,
                    cut_length_mm: 0.0,
                },
            )
            .unwrap();
    }
    let frame = reader
        .wait(Duration::from_secs(2))
        .unwrap()
        .expect("a frame");
    assert_eq!(frame.header.frame, 3, "the newest frame");
    assert_eq!(frame.header.sim_tick, 3);
    assert_eq!(frame.header.pose_seq, 3);
    assert_eq!(frame.header.pose_received_ns, 3000);
    assert_eq!(frame.positions.len(), surface.positions.len());
    assert_eq!(frame.triangles.len(), surface.triangles.len());
    for (got, want) in frame.positions.iter().zip(&surface.positions) {
        for c in 0..3 {
            assert!((f64::from(got[c]) - want[c]).abs() < 1e-6);
        }
    }
    for (got, want) in frame.triangles.iter().zip(&surface.triangles) {
        assert_eq!(got, want);
    }
    assert!(frame.materials.iter().all(|&m| m == MATERIAL_SURFACE));
    for n in &frame.normals {
        let len = n.iter().map(|c| c * c).sum::<f32>().sqrt();
        assert!((len - 1.0).abs() < 1e-4, "{n:?}");
    }
    assert_ne!(frame.header.flags & FRAME_TOOL_PRESENT, 0);
    assert!((frame.header.tool_tip_m[2] - 0.03).abs() < 1e-6);
    assert!((frame.header.force_n[2] - 1.5).abs() < 1e-6);
    // A renderer that attaches late is connected by the publisher's next send and gets
    // the newest frame from then on.
    let mut late = FrameReader::open(&station).unwrap();
    assert!(late.latest().unwrap().is_none());
    let info = FrameInfo {
        sim_tick: 4,
        tool: None,
        pose_seq: 0,
        pose_received_ns: 0,
        force_n: Vec3::zeros(),
        cutting: false,
        cut_length_mm: 0.0,
    };
    publisher.publish(&sim, &info).unwrap();
    let next = late
        .wait(Duration::from_secs(2))
        .unwrap()
        .expect("the next frame");
    assert_eq!(next.header.frame, 4);
    assert_eq!(next.header.flags & FRAME_TOOL_PRESENT, 0);
}
