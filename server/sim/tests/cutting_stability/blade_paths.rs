//! Blades that start, stop, turn back, leave and re-enter, cross an earlier cut or cut
//! through a thin part; presses that back out or slide; several wounds in one session.

use super::*;

#[test]
fn blade_that_starts_and_stops_inside() {
    let scene = scene("liver");
    let z = top_mm(&scene, 0.0, 0.0) - 8.0;
    // Appears 8 mm deep, cuts 15 mm, stands still for half a second, then the tool is gone.
    let s = script(&[
        (0.0, [-10.0, 0.0, z]),
        (3.0, [5.0, 0.0, z]),
        (3.5, [5.0, 0.0, z]),
    ]);
    let (mut sim, trace) = calm_run(&scene, &s, 300);
    // Appearing inside, it presses the way it first moves: it ruptures and cuts.
    assert_eq!(trace.ruptures, 1, "{trace:?}");
    assert!(trace.cutting_ticks > 2000, "{trace:?}");
    // With the blade gone the force is gone and the dent released.
    let r = sim.tick(TICK_S, &mut NoClock);
    assert_eq!(r.tool_force_n, Vec3::zeros());
    assert_dent_released(&sim);
    assert_sound_surface(&sim);
}

#[test]
fn a_press_that_backs_out_before_rupture() {
    let scene = scene("liver");
    let top = top_mm(&scene, -30.0, 0.0);
    let spec = &scene.spec.force;
    // Down at 5 mm/s to 2.5 mm past the surface (rupture takes 3.17), half a second held,
    // back up the same way.
    let press = top - 0.8 * spec.rupture_displacement_m * 1e3;
    let s = script(&[
        (0.0, [-30.0, 0.0, top + 5.0]),
        (1.5, [-30.0, 0.0, press]),
        (2.0, [-30.0, 0.0, press]),
        (3.5, [-30.0, 0.0, top + 5.0]),
    ]);
    let (sim, trace) = calm_run(&scene, &s, 0);
    // The capsule holds, and its force eases off the way it came: backing out neither
    // ruptures it nor makes it push harder (it did both when loading counted path length
    // and the averaged direction could not turn round).
    assert_eq!((trace.ruptures, trace.cutting_ticks), (0, 0), "{trace:?}");
    assert!(trace.peak_n < spec.rupture_force_n, "{trace:?}");
    // Out again at the end, and the dent let go.
    assert_eq!(trace.phase_at_end, Some(CutPhase::Free), "{trace:?}");
    assert_dent_released(&sim);
    // The press pushed the tissue in (the force is the tissue's: a tenth of a newton on
    // the soft liver at 2.5 mm).
    assert!(trace.work_in_j > 5e-5, "{trace:?}");
    // Elastic: what the press put in comes back, and no more.
    assert!(
        trace.work_out_j <= 1.02 * trace.work_in_j && trace.work_out_j >= 0.8 * trace.work_in_j,
        "{trace:?}"
    );
    assert_sound_surface(&sim);
}

/// While the blade dents the capsule, every point the tissue it touches follows is
/// integrated, and so are their neighbours. (With the old displacement-controlled dent,
/// neighbours left asleep beside the held patch took its whole strain at its rim: on the
/// small tumour scan they sprang out inverted at 1.7 m/s when rupture woke them,
/// docs/CUTTING-DECISIONS.md "Displacement-controlled dent"; a point the blade's samples
/// follow but that is asleep cannot be pushed at all.)
#[test]
fn a_pressing_blade_keeps_the_tissue_it_touches_integrated() {
    let scene = scene("cerebroma");
    let top = top_mm(&scene, 0.0, 0.0);
    let press = top - 0.9 * scene.spec.force.rupture_displacement_m * 1e3;
    let s = script(&[
        (0.0, [0.0, 0.0, top + 1.0]),
        (0.8, [0.0, 0.0, press]),
        (1.0, [0.0, 0.0, press]),
    ]);
    let mut sim = Simulation::new(&scene);
    let ticks = (s.duration_s() / TICK_S) as usize;
    let (mut pressed_ticks, mut most_touching) = (0, 0);
    for k in 0..=ticks {
        sim.handle_tool_pose(Some(s.pose_at(k as f64 * TICK_S)));
        sim.tick(TICK_S, &mut NoClock);
        let solver = sim.solver();
        let blade = solver.blade().unwrap();
        if blade.touching() == 0 {
            continue;
        }
        pressed_ticks += 1;
        most_touching = most_touching.max(blade.touching());
        // The press begins at the end of a tick; its points are integrated from the next.
        if pressed_ticks == 1 {
            continue;
        }
        let body = solver.material_points();
        let mut active = vec![false; solver.positions().len()];
        for &i in solver.active_points() {
            active[i as usize] = true;
        }
        for &i in blade.reached() {
            assert!(
                active[i as usize],
                "tick {k}: point {i}, under the blade, is frozen"
            );
            for &j in solver.operator().neighbours(i as usize) {
                // Nodes after the body's points are virtual points (slaved).
                assert!(
                    active[j as usize] || j as usize >= body,
                    "tick {k}: point {j}, a neighbour of the pressed point {i}, is frozen"
                );
            }
        }
    }
    // The blade pressed from first contact on several samples, until the tissue under it
    // was crushed past half its volume and the capsule failed (about 2 mm in, on this
    // fine lattice), then let it go.
    assert!(
        pressed_ticks > 400 && most_touching >= 3,
        "{pressed_ticks} {most_touching}"
    );
}

#[test]
fn a_pressed_blade_that_slides_slices() {
    let scene = scene("liver");
    let top = top_mm(&scene, -30.0, 0.0);
    let spec = &scene.spec.force;
    // 1.5 mm into the capsule (half the rupture displacement), then 10 mm sideways.
    let s = script(&[
        (0.0, [-30.0, 0.0, top + 5.0]),
        (1.3, [-30.0, 0.0, top - 1.5]),
        (3.3, [-20.0, 0.0, top - 1.5]),
    ]);
    let (sim, trace) = calm_run(&scene, &s, 0);
    // It slices: the capsule ruptures within the rupture displacement of sliding, at a
    // force well under the rupture force, and the blade cuts on.
    assert_eq!(trace.ruptures, 1, "{trace:?}");
    assert!(trace.peak_n < 0.8 * spec.rupture_force_n, "{trace:?}");
    assert!(trace.cutting_ticks > 1000, "{trace:?}");
    assert_sound_surface(&sim);
}

#[test]
fn a_blade_that_turns_back_along_its_cut() {
    let scene = scene("liver");
    let top = top_mm(&scene, -30.0, 0.0);
    let spec = &scene.spec.force;
    let z = top - 10.0;
    // Down 10 mm, 30 mm forward, 20 mm back the same way, out.
    let s = script(&[
        (0.0, [-30.0, 0.0, top + 5.0]),
        (3.0, [-30.0, 0.0, z]),
        (9.0, [0.0, 0.0, z]),
        (13.0, [-20.0, 0.0, z]),
        (16.0, [-20.0, 0.0, top + 5.0]),
    ]);
    // The turn is smooth: the resistance passes through zero instead of flipping by twice
    // its size in one tick (5.5 N when the direction was a blend of unit vectors).
    let (sim, trace) = calm_run(&scene, &s, 0);
    assert_eq!(trace.ruptures, 1, "{trace:?}");
    // Forward it cuts: fracture and friction (J_c·d ≥ 1.9 N at 10 mm).
    let forward = trace.ticks.force[8500];
    assert!(forward.x < -2.0, "{forward:?}");
    // Back along its own cut it opens nothing: friction only, against the motion, from
    // 3 mm after the turn on; Σ does not grow.
    let friction = (1.0 + spec.ripple_amplitude) * spec.friction_n;
    for (k, f) in trace.ticks.force[9600..13000].iter().enumerate() {
        assert!(
            f.x > 0.0 && f.norm() <= friction + 1e-9,
            "tick {}: {f:?}",
            9600 + k
        );
    }
    assert_eq!(trace.ticks.sigma[9500], trace.ticks.sigma[13000]);
    // What the tissue did on the hand around the turn is a sliver of what the cut took:
    // the averaged direction's lag (0.67 mJ), and the steady motion's — the heading holds
    // until the smoothed tip is a deadband behind where it last moved to, 2 × (0.1 mm +
    // 10 ms at 5 mm/s) of the way back at the full 2.6 N of cutting, ≈ 0.8 mJ.
    assert!(trace.work_out_j < 0.02 * trace.work_in_j, "{trace:?}");
    assert_sound_surface(&sim);
}

#[test]
fn blade_that_leaves_and_reenters() {
    let scene = scene("liver");
    let top = top_mm(&scene, 0.0, 0.0);
    let (up, down) = (top + 10.0, top - 8.0);
    let s = script(&[
        (0.0, [-30.0, 0.0, up]),
        (3.6, [-30.0, 0.0, down]),
        (6.6, [-15.0, 0.0, down]),
        (10.2, [-15.0, 0.0, up]),
        (13.2, [15.0, 0.0, up]),
        (16.8, [15.0, 0.0, down]),
        (19.8, [30.0, 0.0, down]),
        (23.4, [30.0, 0.0, up]),
    ]);
    let (sim, trace) = calm_run(&scene, &s, 0);
    assert_eq!(
        trace.ruptures, 2,
        "one rupture per entry into intact capsule"
    );
    let stats = sim.incisions().unwrap();
    println!("{stats:?}");
    assert!(stats.incisions >= 2);
    assert!(stats.min_angle_deg >= 15.0);
    assert_sound_surface(&sim);
}

#[test]
fn two_crossing_cuts() {
    let scene = scene("liver");
    let top = top_mm(&scene, 0.0, 0.0);
    let (up, down) = (top + 10.0, top - 8.0);
    let s = script(&[
        (0.0, [-25.0, 0.0, up]),
        (3.6, [-25.0, 0.0, down]),
        (13.6, [25.0, 0.0, down]),
        (17.2, [25.0, 0.0, up]),
        (19.2, [0.0, -25.0, up]),
        (22.8, [0.0, -25.0, down]),
        (32.8, [0.0, 25.0, down]),
        (36.4, [0.0, 25.0, up]),
    ]);
    let (sim, _) = calm_run(&scene, &s, 0);
    let stats = sim.incisions().unwrap();
    println!("{stats:?}");
    assert!(stats.incisions >= 2, "{stats:?}");
    assert!(stats.min_angle_deg >= 15.0);
    assert_sound_surface(&sim);
}

/// Three wounds made one after the other across the liver's top, 60 mm apart (one of the
/// endurance scripts of docs/CUTTING-DECISIONS.md, "Virtual points slaved to the points they join"): the virtual points on the
/// earlier walls, moved once a tick to where their wall vertices went, drove the tissue
/// that carries those vertices, a loop with a tick's lag that pumped energy into the walls
/// during the second stroke — from then on the guard rolled ticks back, doubling their
/// sub-steps up to 32 768 (0.5–3.8 s per tick), and 223 ticks diverged. Slaved to the
/// points around them, the nodes close no loop: every tick is calm and none is rolled back.
#[test]
fn several_wounds_in_one_session_stay_calm() {
    let scene = scene("liver");
    let mut frames: Vec<(f64, [f64; 3])> = Vec::new();
    let mut t = 0.0;
    // (x, first y, last y, depth mm): along −y, 10 mm/s down, 8 mm/s along.
    for (x, y0, y1, depth) in [
        (-58.5, 42.8, 12.8, 7.5),
        (-8.1, 25.2, -0.9, 5.1),
        (53.7, 7.1, -17.9, 7.2),
    ] {
        let above = top_mm(&scene, x, y0) + 10.0;
        if !frames.is_empty() {
            t += 1.0;
        }
        frames.push((t, [x, y0, above]));
        t += (10.0 + depth) / 10.0;
        let steps = 10;
        for k in 0..=steps {
            let y = y0 + (y1 - y0) * k as f64 / steps as f64;
            if k > 0 {
                t += (y1 - y0).abs() / steps as f64 / 8.0;
            }
            frames.push((t, [x, y, top_mm(&scene, x, y) - depth]));
        }
        t += (10.0 + depth) / 10.0;
        frames.push((t, [x, y1, top_mm(&scene, x, y1) + 10.0]));
    }
    // Upright, facing along the strokes (−y).
    let mut s = script(&frames);
    for k in &mut s.keyframes {
        k.pose = ToolPose::facing(k.pose.tip_m, Vec3::z(), -Vec3::y());
    }
    let (sim, trace) = calm_run(&scene, &s, 500);
    assert_eq!(trace.rolled_back_ticks, 0, "{trace:?}");
    let stats = sim.incisions().unwrap();
    println!("{stats:?}");
    assert!(stats.incisions >= 3, "{stats:?}");
    assert!(stats.min_angle_deg >= 15.0);
    let vp = sim.virtual_points().expect("the liver uses virtual points");
    assert!(vp.stats.placed > 20, "{:?}", vp.stats);
    assert_sound_surface(&sim);
}

#[test]
fn cut_through_a_thin_part() {
    // The 10 mm beam: the blade goes down right through it (the tip comes out underneath),
    // then cuts across to the side and out.
    let scene = scene("beam");
    let bbox = scene.model.surface.bbox();
    let (z0, z1) = (bbox.min[2] * 1e3, bbox.max[2] * 1e3);
    let y1 = bbox.max[1] * 1e3;
    let s = script(&[
        (0.0, [0.0, 0.0, z1 + 5.0]),
        (4.0, [0.0, 0.0, z0 - 5.0]),
        (6.0, [0.0, y1 + 5.0, z0 - 5.0]),
        (9.0, [0.0, y1 + 5.0, z1 + 5.0]),
    ]);
    let (sim, trace) = calm_run(&scene, &s, 200);
    // One rupture, and the blade read the whole thickness of the part while through it.
    assert_eq!(trace.ruptures, 1, "{trace:?}");
    assert!(
        (trace.max_depth_m * 1e3 - (z1 - z0)).abs() < 1.0,
        "{trace:?}"
    );
    assert_sound_surface(&sim);
}

/// A re-cut runner that runs each job on the calling thread (as `InlineRecuts`) and notes
/// the tick of every start and finish.
struct NotingRunner {
    inline: scalpel_sim::pipeline::InlineRecuts,
    tick: std::sync::Arc<std::sync::atomic::AtomicU64>,
    noted: std::sync::Arc<std::sync::Mutex<Vec<(&'static str, u64)>>>,
}

impl scalpel_sim::pipeline::RecutRunner for NotingRunner {
    fn start(&mut self, job: scalpel_sim::pipeline::RecutJob) {
        let t = self.tick.load(std::sync::atomic::Ordering::Relaxed);
        self.noted.lock().unwrap().push(("start", t));
        self.inline.start(job);
    }

    fn finish(&mut self, waited: &mut bool) -> Option<scalpel_sim::pipeline::RecutResult> {
        let t = self.tick.load(std::sync::atomic::Ordering::Relaxed);
        self.noted.lock().unwrap().push(("finish", t));
        self.inline.finish(waited)
    }
}

/// Out of its cut and straight back in, the blade starts a stroke while the last one's
/// final re-cut is still out: the new stroke's ticks are held until that re-cut is due,
/// not the re-cut waited for (every result is taken exactly the hand-over after it was
/// asked for), and both strokes are still drawn.
#[test]
fn a_quick_re_entry_takes_no_re_cut_early() {
    use scalpel_sim::pipeline::RECUT_HANDOVER_TICKS;
    use std::sync::atomic::Ordering;
    let scene = scene("liver");
    let top = top_mm(&scene, 0.0, 0.0);
    let (down, out) = (top - 8.0, top + 1.0);
    let s = script(&[
        (0.0, [-30.0, 0.0, top + 10.0]),
        (3.6, [-30.0, 0.0, down]),
        (6.6, [-15.0, 0.0, down]),
        (6.65, [-15.0, 0.0, out]),
        (6.66, [-14.0, 0.0, out]),
        (6.71, [-14.0, 0.0, down]),
        (9.0, [0.0, 0.0, down]),
        (12.0, [0.0, 0.0, top + 10.0]),
    ]);
    let mut sim = Simulation::new(&scene);
    let tick = std::sync::Arc::new(std::sync::atomic::AtomicU64::new(0));
    let noted = std::sync::Arc::default();
    sim.set_recut_runner(Box::new(NotingRunner {
        inline: scalpel_sim::pipeline::InlineRecuts::new(),
        tick: tick.clone(),
        noted: std::sync::Arc::clone(&noted),
    }));
    for k in 0..s.tick_count(TICK_S) {
        tick.store(k as u64, Ordering::Relaxed);
        sim.handle_tool_pose(Some(s.pose_at(k as f64 * TICK_S)));
        let r = sim.tick(TICK_S, &mut NoClock);
        assert!(r.tool_force_n.iter().all(|f| f.is_finite()));
        assert_nodes_joined(&sim, k);
    }
    let stats = sim.incisions().unwrap().clone();
    println!("{stats:?}");
    assert_eq!(stats.strokes, 2, "out and back in is a second stroke");
    assert!(
        stats.held_ticks > 0,
        "the second stroke began with a re-cut out"
    );
    assert!(stats.incisions >= 2);
    let noted = noted.lock().unwrap();
    let mut last_start = None;
    for &(what, t) in noted.iter() {
        match what {
            "start" => last_start = Some(t),
            _ => assert_eq!(
                Some(t),
                last_start.map(|s| s + RECUT_HANDOVER_TICKS),
                "a result taken early: {noted:?}"
            ),
        }
    }
    sim.settle_incision();
    assert_sound_surface(&sim);
}
