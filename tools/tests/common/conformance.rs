//! The device conformance suite: what any haptic device attached to a station must see
//! when it plays the same short cut. Run against the in-process scripted device and against
//! the mock device over shared memory (tools/tests/station.rs).

use scalpel_sim::math::Vec3;
use scalpel_sim::pipeline::{CutScript, Keyframe};

/// One device tick as the device saw it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TraceRow {
    /// Device time (s).
    pub t_s: f64,
    /// The force the device had by then (N).
    pub force_n: [f64; 3],
    /// The server's haptic tick of that force (consecutive forces differ by at most the
    /// rate limit per tick between them).
    pub server_tick: u64,
    /// The device rendered zero on its own: its newest force was older than its watchdog
    /// (the server's forces stopped coming for a while, not a force the server sent).
    pub device_zeroed: bool,
}

/// The conformance cut on the liver: from the demo cut's start, down 15 mm into the top
/// surface at 5 mm/s, 10 mm along it, then 25 mm straight up and out, and held still there.
pub struct ConformanceCut {
    /// The script.
    pub script: CutScript,
    /// While the blade is deep in the tissue and moving along (s).
    pub cutting: (f64, f64),
    /// From here on the blade is out of the tissue (s).
    pub out_from_s: f64,
    /// Unit direction of the blade's travel while cutting.
    pub travel: Vec3,
}

impl ConformanceCut {
    /// The cut for the built-in liver.
    pub fn liver() -> Self {
        let scene = scalpel_server::scene_file::load_scene("liver").unwrap();
        let demo = CutScript::default_for(&scalpel_sim::pipeline::start_surface(&scene)).unwrap();
        let at = |t: f64| demo.pose_at(t);
        let down = 3.0;
        let along = down + 2.0;
        let mut up = at(along);
        up.tip_m += Vec3::new(0.0, 0.0, 0.025);
        let script = CutScript {
            keyframes: vec![
                Keyframe {
                    t_s: 0.0,
                    pose: at(0.0),
                },
                Keyframe {
                    t_s: down,
                    pose: at(down),
                },
                Keyframe {
                    t_s: along,
                    pose: at(along),
                },
                Keyframe {
                    t_s: along + 2.0,
                    pose: up,
                },
                Keyframe {
                    t_s: along + 3.5,
                    pose: up,
                },
            ],
            description: "conformance cut".into(),
        };
        Self {
            script,
            cutting: (down + 0.5, along),
            out_from_s: along + 2.5,
            travel: (at(along).tip_m - at(down).tip_m).normalize(),
        }
    }

    /// The script as a CSV keyframe file (what the mock device reads).
    pub fn csv(&self) -> String {
        script_csv(&self.script)
    }
}

/// `script` as a CSV keyframe file (docs/CUTTING.md).
pub fn script_csv(script: &CutScript) -> String {
    let mut s = String::from(scalpel_sim::pipeline::CSV_HEADER);
    s.push('\n');
    for k in &script.keyframes {
        let p = k.pose.tip_m * 1e3;
        let e = k.pose.orientation * Vec3::z();
        s.push_str(&format!(
            "{},{},{},{},{},{},{}\n",
            k.t_s, p.x, p.y, p.z, e.x, e.y, e.z
        ));
    }
    s
}

/// Checks a device's trace of the conformance cut. `max_force_n` is the station's limit,
/// `rate_limit_n` the largest change per haptic tick.
pub fn check(trace: &[TraceRow], cut: &ConformanceCut, max_force_n: f64, rate_limit_n: f64) {
    let duration = cut.script.duration_s();
    // The whole script, at the device's 1 kHz. A device that wakes a whole period late
    // skips the samples it missed (a real device does not replay the past); a 2-vCPU VM
    // makes it do so in bursts — seen in CI: 241 wake-ups 1–5 ms late in one 8.5 s run
    // (93 % of the ticks), and 84 % in another on this machine. The rate is the loop
    // benchmark's business (`scalpel bench loop`); this catches a device that is not
    // ticking at 1 kHz at all (half the rate, say).
    let expected = (duration * 1000.0) as usize;
    assert!(
        trace.len() as f64 >= 0.8 * expected as f64,
        "{} ticks for {duration} s at 1 kHz",
        trace.len()
    );
    let last = trace.last().map_or(0.0, |r| r.t_s);
    assert!(
        last >= duration - 0.05,
        "the trace ends at {last} s of a {duration} s script"
    );
    // Ticks in order, and hardly a gap the output stage's watchdog (5 ms) has to cover:
    // the device process itself never sleeps that long, but a 2-vCPU VM running the
    // other tests beside this one stalls a vCPU for a few milliseconds now and then (seen:
    // one of 8 ms; four of 5–9 ms in one 5 s run in CI; once, both processes at once for
    // 56 ms; in another run 60 gaps of 5–49 ms, 6.4 % of the run). Timing is the
    // benchmarks' business; this bounds it loosely: each gap under 100 ms, together under
    // 10 % of the run.
    let mut gaps = Vec::new();
    for w in trace.windows(2) {
        let dt = w[1].t_s - w[0].t_s;
        assert!(
            dt > 0.0 && dt < 0.1,
            "device ticks {dt} s apart at {}",
            w[0].t_s
        );
        if dt >= 0.005 {
            gaps.push((w[0].t_s, dt));
        }
    }
    let stalled: f64 = gaps.iter().map(|(_, dt)| dt).sum();
    assert!(
        stalled <= 0.1 * duration,
        "gaps of 5 ms or more (at, length) add up to {stalled} s of {duration} s: {gaps:?}"
    );
    let magnitude = |f: [f64; 3]| Vec3::from(f).norm();
    // Always finite and within the limit; never faster than the rate limit.
    for r in trace {
        assert!(
            r.force_n.iter().all(|c| c.is_finite()) && magnitude(r.force_n) <= max_force_n + 1e-9,
            "force {:?} at {} s",
            r.force_n,
            r.t_s
        );
    }
    // The device's own watchdog zeroes the force when none has come for 10 ms: the
    // server's haptic thread stalled by the VM (seen in CI: one 2.2 N cutting force,
    // zeroed by the device, then the server's next tick with the same force). That is
    // the device keeping itself safe, bounded here like the gaps; the rate limit holds on
    // what the server sent, from one force it sent to the next.
    let zeroed = trace.iter().filter(|r| r.device_zeroed).count();
    assert!(
        zeroed as f64 <= 0.1 * expected as f64,
        "the device zeroed a stale force on {zeroed} of {} ticks",
        trace.len()
    );
    let sent: Vec<&TraceRow> = trace.iter().filter(|r| !r.device_zeroed).collect();
    for w in sent.windows(2) {
        let ticks = w[1].server_tick.saturating_sub(w[0].server_tick).max(1) as f64;
        let step = (Vec3::from(w[1].force_n) - Vec3::from(w[0].force_n)).norm();
        assert!(
            step <= rate_limit_n * ticks + 1e-9,
            "force changed {step} N over {ticks} tick(s) at {} s",
            w[1].t_s
        );
    }
    // The cut is felt, and it resists the blade's travel.
    let cutting: Vec<&TraceRow> = trace
        .iter()
        .filter(|r| (cut.cutting.0..cut.cutting.1).contains(&r.t_s))
        .collect();
    let peak = cutting
        .iter()
        .map(|r| magnitude(r.force_n))
        .fold(0.0, f64::max);
    assert!(peak > 0.5, "the cut was not felt: peak {peak} N");
    let along = cutting
        .iter()
        .map(|r| Vec3::from(r.force_n).dot(&cut.travel))
        .sum::<f64>()
        / cutting.len().max(1) as f64;
    assert!(
        along < -0.1,
        "the force does not resist the cut: mean {along} N along the travel"
    );
    // Out of the tissue: nothing.
    let after: Vec<&TraceRow> = trace.iter().filter(|r| r.t_s >= cut.out_from_s).collect();
    assert!(!after.is_empty(), "the trace ends before the blade is out");
    for r in after {
        assert!(
            magnitude(r.force_n) < 0.05,
            "force {:?} at {} s with the blade out of the tissue",
            r.force_n,
            r.t_s
        );
    }
}
