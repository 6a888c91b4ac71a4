//! The haptic tick is on the real-time path: after warm-up it must not allocate. A counting
//! global allocator watches the tick with its real hand-offs (SPSC ring, triple buffer) and
//! the scripted device playing the demo cut, the force model changing every tick.

// A counting global allocator needs `unsafe impl GlobalAlloc`; this test crate allows it.
#![allow(unsafe_code)]

#[path = "../sim/tests/common/counting_alloc.rs"]
mod counting_alloc;

use counting_alloc::allocations;
use scalpel_server::device::ScriptedDevice;
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
    let script = CutScript::default_for(&scene.model.surface).unwrap();
    let mut device = ScriptedDevice::new(script, true);
    let limits = OutputLimits::default();
    // A stiff model pushing up: the coupling, clamp, rate limit and passivity all act.
    let model = LocalForceModel {
        f0_n: Vec3::new(0.0, 0.0, 2.0),
        x0_m: Vec3::zeros(),
        stiffness_n_per_m: Mat3::identity() * -500.0,
    };
    let warm_up = 10;
    let ticks = 5000;
    let mut k = 0;
    let mut start = 0;
    let force = drive_haptic_ticks(&mut device, limits, model, ticks, || {
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
