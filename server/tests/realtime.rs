//! The haptic tick is on the real-time path: after warm-up it must not allocate. A counting
//! global allocator watches the tick with its real hand-offs (SPSC ring, triple buffer) and
//! the scripted device playing the demo cut, the force model changing every tick. And what
//! a render frame costs the simulation thread: only iceoryx2's loan.

// A counting global allocator needs `unsafe impl GlobalAlloc`; this test crate allows it.
#![allow(unsafe_code)]

#[path = "../sim/tests/common/counting_alloc.rs"]
mod counting_alloc;

use counting_alloc::allocations;
use scalpel_proto::wire::{Action, Command, Fault, FaultSpec, Outcome, Start};
use scalpel_server::device::ScriptedDevice;
use scalpel_server::faults::{FaultBook, FaultTable};
use scalpel_server::output::OutputLimits;
use scalpel_server::station::drive_haptic_ticks;
use scalpel_sim::force::LocalForceModel;
use scalpel_sim::math::{Mat3, Vec3};
use scalpel_sim::pipeline::CutScript;
use scalpel_sim::progress::Silent;
use scalpel_sim::scene::{build_scene, builtin};

#[test]
fn haptic_ticks_do_not_allocate() {
    let scene = build_scene(&builtin("liver").unwrap(), None, &mut Silent).unwrap();
    let script = CutScript::default_for(&scalpel_sim::pipeline::start_surface(&scene)).unwrap();
    let mut device = ScriptedDevice::new(script, true);
    let limits = OutputLimits::default();
    // A stiff model pushing up: the coupling (at its 4 mm reach: 2000 N/m gives 8 N), the
    // clamp, the rate limit and passivity all act.
    let model = LocalForceModel {
        f0_n: Vec3::new(0.0, 0.0, 2.0),
        x0_m: Vec3::zeros(),
        stiffness_n_per_m: Mat3::identity() * -2000.0,
        stored_energy_j: 0.0,
    };
    // The instructor's faults that act on the haptic thread, over parts of the run: the
    // delay line, the noise generator, the spike and the cap run allocation-free too.
    let mut book = FaultBook::new();
    let faults = [
        (Fault::DeviceLatency { ms: 20.0 }, 1000, 2000),
        (Fault::PoseNoise { sigma_mm: 1.0 }, 1000, 3000),
        (Fault::ForceSpike { newtons: 50.0 }, 2000, 500),
        (Fault::ForceSaturation { max_n: 0.5 }, 2500, 500),
        (Fault::DeviceDropout, 3500, 100),
    ];
    for (seq, (fault, at, ms)) in faults.into_iter().enumerate() {
        let spec = FaultSpec {
            fault,
            start: Start::AtTick(at),
            duration_ms: ms,
        };
        let command = Command {
            seq: seq as u64 + 1,
            action: Action::Schedule(spec),
        };
        let (outcome, _) = book.command("test", &command, 0);
        assert!(matches!(outcome, Outcome::Scheduled { .. }), "{outcome:?}");
    }
    let warm_up = 10;
    let ticks = 5000;
    let mut k = 0;
    let mut start = 0;
    let force = drive_haptic_ticks(&mut device, limits, model, book.table(), ticks, || {
        k += 1;
        if k == warm_up {
            start = allocations();
        }
    });
    let during = allocations() - start;
    assert!(force.is_finite() && force > 0.0 && force <= 3.3, "{force}");
    assert_eq!(
        during,
        0,
        "{during} allocations in {} haptic ticks",
        ticks - warm_up
    );
}

/// The same with the shared-memory device: receiving poses over iceoryx2 and handing the
/// force to the force-out thread do not allocate (iceoryx2's `loan` does, once per sample:
/// that is why the loan is on the force-out thread). The device process's side (publishing
/// poses, draining forces) runs between the ticks; its allocations are not the haptic
/// thread's and are left out of the count.
#[test]
fn haptic_ticks_with_the_shared_memory_device_do_not_allocate() {
    use scalpel_proto::shm::{self, DevicePose, LAYOUT_VERSION};
    use scalpel_server::device_monitor::DeviceMonitor;
    use scalpel_server::shm_device::{DeviceGate, ShmDevice, ShmDeviceCounters};
    use std::sync::Arc;

    shm::quiet_logging();
    let station = format!("t-alloc-{}", std::process::id());
    let counters = Arc::new(ShmDeviceCounters::default());
    let gate = Arc::new(DeviceGate::default());
    // The station's services, made as its server makes them.
    let _monitor = DeviceMonitor::open(&station, gate.clone()).unwrap();
    let mut device = ShmDevice::open(&station, counters.clone(), gate.clone()).unwrap();
    let node = shm::node("test-device", &station).unwrap();
    // (Accepted as if it had said hello: the handshake is the monitor's, tested elsewhere.)
    gate.accept(Some(node.id().value()));
    let poses = shm::pose_service(&node, &station)
        .unwrap()
        .publisher_builder()
        .create()
        .unwrap();
    let forces = shm::force_service(&node, &station)
        .unwrap()
        .subscriber_builder()
        .create()
        .unwrap();
    let model = LocalForceModel {
        f0_n: Vec3::new(0.0, 0.0, 2.0),
        x0_m: Vec3::zeros(),
        stiffness_n_per_m: Mat3::identity() * -500.0,
        stored_energy_j: 0.0,
    };
    let warm_up = 10;
    let ticks = 3000;
    let (mut k, mut start, mut excluded, mut received) = (0, 0, 0, 0u64);
    let force = drive_haptic_ticks(
        &mut device,
        OutputLimits::default(),
        model,
        FaultTable::default(),
        ticks,
        || {
            let before = allocations();
            k += 1;
            let sample = DevicePose {
                layout_version: LAYOUT_VERSION,
                seq: k as u64,
                tip_m: [0.0, 0.0, -0.001 * (k % 7) as f64],
                orientation_xyzw: [0.0, 0.0, 0.0, 1.0],
                ..DevicePose::default()
            };
            poses.send_copy(sample).unwrap();
            // As a device at 1 kHz would: the force of this tick arrives from the force-out
            // thread within a fraction of a millisecond.
            let asked = std::time::Instant::now();
            let mut got = false;
            while !got && asked.elapsed() < std::time::Duration::from_millis(100) {
                // The force of this tick answers the pose sent before it (this one is read
                // on the next tick). (The force's `tick` is the station clock, and `pose_seq`
                // the pose it answers: waiting for `tick` ≥ k never succeeded, and every tick
                // sat out the 100 ms, 300 s for the test.)
                while let Ok(Some(f)) = forces.receive() {
                    received += 1;
                    got |= f.pose_seq as usize + 1 >= k;
                }
                if !got {
                    std::thread::sleep(std::time::Duration::from_micros(20));
                }
            }
            if k == warm_up {
                start = allocations();
                excluded = 0;
            } else {
                excluded += allocations() - before;
            }
        },
    );
    let during = allocations() - start - excluded;
    use std::sync::atomic::Ordering::Relaxed;
    assert!(force.is_finite() && force > 0.0 && force <= 3.3, "{force}");
    assert!(counters.poses.load(Relaxed) as usize >= ticks - 1);
    assert_eq!(counters.send_failures.load(Relaxed), 0);
    assert!(
        received as usize >= ticks - 10,
        "{received} forces received"
    );
    assert_eq!(
        during,
        0,
        "{during} allocations in {} haptic ticks over shared memory",
        ticks - warm_up
    );
}

/// What a device (re)connecting costs the haptic thread: iceoryx2 maps the new publisher's
/// segment in the first receive after it appears, which allocates (37 times with 0.10.0);
/// every receive after that is allocation-free again. A reconnect is an event, not the
/// steady state; this pins both halves.
#[test]
fn a_reconnecting_device_costs_one_receive_of_allocations_then_none() {
    use scalpel_proto::shm::{self, DevicePose, LAYOUT_VERSION};
    use scalpel_server::device::HapticDevice;
    use scalpel_server::device_monitor::DeviceMonitor;
    use scalpel_server::shm_device::{DeviceGate, ShmDevice};

    shm::quiet_logging();
    let station = format!("t-reconnect-{}", std::process::id());
    let gate = std::sync::Arc::new(DeviceGate::default());
    let _monitor = DeviceMonitor::open(&station, gate.clone()).unwrap();
    let mut device = ShmDevice::open(&station, Default::default(), gate.clone()).unwrap();
    for round in 0..3 {
        let node = shm::node(&format!("test-device-{round}"), &station).unwrap();
        gate.accept(Some(node.id().value()));
        let poses = shm::pose_service(&node, &station)
            .unwrap()
            .publisher_builder()
            .create()
            .unwrap();
        let mut counts = Vec::new();
        for k in 0..50 {
            let sample = DevicePose {
                layout_version: LAYOUT_VERSION,
                seq: k,
                orientation_xyzw: [0.0, 0.0, 0.0, 1.0],
                ..DevicePose::default()
            };
            poses.send_copy(sample).unwrap();
            let before = allocations();
            assert!(device.sample(0.0).is_some());
            counts.push(allocations() - before);
        }
        assert!(
            counts[0] > 0 && counts[0] < 100,
            "round {round}: the connecting receive made {} allocations",
            counts[0]
        );
        assert!(
            counts[1..].iter().all(|&c| c == 0),
            "round {round}: {counts:?}"
        );
    }
}

/// What a render frame costs the simulation thread, which writes the surface straight into
/// a loaned shared-memory sample (no copy of the vertex data: docs/PROTOCOL.md): one
/// allocation, iceoryx2's own (0.10.0 makes a reference-counted state for each loaned
/// sample). The frame's own work — the header, the normals into their kept buffer, the
/// vertices, triangles and materials — allocates nothing, with a renderer attached or not,
/// on a cut surface too. Frames go out at the frame rate (60 Hz), not every tick.
#[test]
fn a_render_frame_costs_the_simulation_thread_only_iceoryx2s_loan() {
    use scalpel_client::frame_reader::FrameReader;
    use scalpel_proto::shm;
    use scalpel_server::render_frames::{FrameInfo, FramePublisher};
    use scalpel_sim::pipeline::{NoClock, Simulation};

    shm::quiet_logging();
    let station = format!("t-frame-cost-{}", std::process::id());
    let liver = scalpel_server::scene_file::load_scene("liver").unwrap();
    let script = CutScript::default_for(&scalpel_sim::pipeline::start_surface(&liver)).unwrap();
    let mut sim = Simulation::new(&liver);
    // The station's services, made as its server makes them.
    let _services =
        scalpel_server::device_monitor::DeviceMonitor::open(&station, Default::default()).unwrap();
    let mut publisher = FramePublisher::open(&station, &sim).unwrap();
    // Through the press and seconds of cutting: the surface the frames carry is incised.
    let uncut = sim.current_surface().mesh.triangles.len();
    for k in 0..8000 {
        sim.handle_tool_pose(Some(script.pose_at(k as f64 * 1e-3)));
        sim.tick(1e-3, &mut NoClock);
    }
    assert!(sim.current_surface().mesh.triangles.len() > uncut);
    let info = FrameInfo {
        sim_tick: 8000,
        tool: Some(script.pose_at(8.0)),
        pose_seq: 1,
        pose_received_ns: 1,
        force_n: Vec3::new(0.0, 0.0, 1.0),
        cutting: true,
        cut_length_mm: 10.0,
    };
    for reader in [None, Some(FrameReader::open(&station).unwrap())] {
        // Warm-up: the shared memory sized, the normals' buffer grown to the surface.
        for _ in 0..5 {
            publisher.publish(&sim, &info).unwrap();
        }
        let frames = 100;
        let before = allocations();
        for _ in 0..frames {
            publisher.publish(&sim, &info).unwrap();
        }
        let during = allocations() - before;
        assert_eq!(
            during,
            frames,
            "{during} allocations in {frames} frames (reader attached: {})",
            reader.is_some()
        );
    }
}
