//! A station with real processes: the server, the mock device over shared memory, the
//! viewer. The device conformance suite runs against the in-process scripted device and
//! the mock device; kill -9 of the device, the viewer and the server mid-run.

mod common;

use std::sync::atomic::AtomicBool;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use common::conformance::{self, ConformanceCut, TraceRow};
use common::station::{
    self, Running, json, scalpel, start_server, start_server_with, unique_station,
};
use scalpel_server::device::{
    DeviceFactory, DeviceSample, ForceStatus, HapticDevice, ScriptedDevice,
};
use scalpel_server::output::OutputLimits;
use scalpel_server::station::{StationParams, prepare_simulation, run};
use scalpel_sim::math::Vec3;

/// The liver's force limit (scene default) and the output stage's rate limit per tick.
const MAX_FORCE_N: f64 = 3.3;
const RATE_LIMIT_N: f64 = 0.5;

/// The scripted device, recording what it is sent.
struct Recording {
    device: ScriptedDevice,
    now_s: f64,
    sampled: bool,
    ticks: u64,
    trace: Arc<Mutex<Vec<TraceRow>>>,
    /// Script time at which the device stops the run (s).
    end_s: f64,
    stop: Arc<AtomicBool>,
}

impl HapticDevice for Recording {
    fn sample(&mut self, now_s: f64) -> Option<DeviceSample> {
        self.now_s = now_s;
        if now_s >= self.end_s {
            self.stop.store(true, std::sync::atomic::Ordering::Relaxed);
        }
        self.sampled = true;
        self.device.sample(now_s)
    }

    fn send_force(&mut self, force_n: Vec3, status: ForceStatus) {
        self.device.send_force(force_n, status);
        self.ticks += 1;
        // The wind-down after the stop sends without sampling: not part of the cut.
        if !std::mem::take(&mut self.sampled) {
            return;
        }
        self.trace.lock().unwrap().push(TraceRow {
            t_s: self.now_s,
            force_n: force_n.into(),
            server_tick: self.ticks,
            device_zeroed: false,
        });
    }
}

#[test]
fn conformance_of_the_in_process_scripted_device() {
    let _serial = one_at_a_time();
    let cut = ConformanceCut::liver();
    let scene = scalpel_server::scene_file::load_scene("liver").unwrap();
    let trace = Arc::new(Mutex::new(Vec::with_capacity(20_000)));
    let script = cut.script.clone();
    let recorder = trace.clone();
    let stop = Arc::new(AtomicBool::new(false));
    let done = stop.clone();
    let factory: DeviceFactory = Box::new(move || {
        Ok(Box::new(Recording {
            end_s: script.duration_s() + 0.01,
            stop: done,
            device: ScriptedDevice::new(script, false),
            now_s: 0.0,
            sampled: false,
            ticks: 0,
            trace: recorder,
        }) as Box<dyn HapticDevice>)
    });
    let params = StationParams {
        lesson: None,
        haptic_hz: 1000.0,
        fifo_priority: 80,
        sim_fifo_priority: 0,
        lock_memory: false,
        haptic_cpu: None,
        sim_threads: 2,
        sim_nice: 0,
        limits: OutputLimits {
            max_force_n: MAX_FORCE_N,
            rate_limit_n_per_ms: RATE_LIMIT_N,
            ..OutputLimits::default()
        },
        status_interval_s: 0.5,
        station: unique_station("inproc"),
        frame_hz: 0.0,
        monitor_device: false,
        device_gate: Default::default(),
        haptics: true,
        network: None,
    };
    // The device ends the run when its script is done: a timer started here would also
    // count the station's start-up (scene, solver, threads), which a busy machine
    // stretches (seen: 0.45 s, 5 % of the ticks). A long backstop ends a run whose
    // device never got that far.
    let backstop = stop.clone();
    let duration = cut.script.duration_s();
    std::thread::spawn(move || {
        std::thread::sleep(Duration::from_secs_f64(duration + 60.0));
        backstop.store(true, std::sync::atomic::Ordering::Relaxed);
    });
    let sim = prepare_simulation(&scene);
    let summary = run(&scene, sim, factory, &params, None, stop, |_| {}).unwrap();
    assert!(summary.haptic_ticks > 0);
    let trace = trace.lock().unwrap();
    conformance::check(&trace, &cut, MAX_FORCE_N, RATE_LIMIT_N);
}

/// Runs the mock device on `script` at `station`, recording to `out`.
fn start_mock(station: &str, script: &std::path::Path, out: &std::path::Path) -> Running {
    let mut command = scalpel();
    command
        .args(["mock-device", "--station", station, "--json", "--script"])
        .arg(script)
        .arg("--out")
        .arg(out);
    Running::start(command)
}

fn read_trace(csv: &std::path::Path) -> Vec<TraceRow> {
    let text = std::fs::read_to_string(csv).unwrap();
    let mut lines = text.lines();
    assert_eq!(
        lines.next(),
        Some(FORCE_CSV_HEADER),
        "the recording's header"
    );
    lines
        .map(|l| {
            let c: Vec<f64> = l
                .split(',')
                .map(|x| x.parse().unwrap_or(f64::NAN))
                .collect();
            // The row's time is the script time of the sample; the device woke
            // `lateness_ms` after it.
            TraceRow {
                t_s: c[0] + c[12] * 1e-3,
                force_n: [c[5], c[6], c[7]],
                server_tick: c[10] as u64,
                // Once a force has come (tick 0: none yet, zero anyway).
                device_zeroed: c[10] > 0.0 && scalpel_client::mock_device::too_old(c[8] * 1e-3),
            }
        })
        .collect()
}

/// The mock device's recording header (tools/src/mock_cmd.rs).
const FORCE_CSV_HEADER: &str = "t_s,seq,tip_x_mm,tip_y_mm,tip_z_mm,fx_n,fy_n,fz_n,force_age_ms,force_flags,server_tick,pose_seq,lateness_ms,latency_ms";

/// Nodes of `station` named `role.station`, alive or dead.
fn nodes_named(station: &str, role: &str) -> usize {
    let name = format!("{role}.{station}");
    scalpel_proto::shm::station_nodes(station)
        .unwrap()
        .iter()
        .filter(|n| n.name == name)
        .count()
}

/// A running server with the in-process scripted device on a station of its own, once it
/// reports; its scratch folder and station name.
fn scripted_station(label: &str) -> (std::path::PathBuf, String, Running) {
    let dir = station::scratch(label);
    let name = unique_station(label);
    let mut server = start_server_with(&name, &dir, 60.0, "scripted");
    server.wait_for(Duration::from_secs(60), |l| l.contains("\"haptic\""));
    (dir, name, server)
}

/// The tests of this file start servers with simulations; on two cores, one at a time.
static ONE_AT_A_TIME: Mutex<()> = Mutex::new(());

fn one_at_a_time() -> std::sync::MutexGuard<'static, ()> {
    ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner())
}

#[test]
fn conformance_of_the_mock_device_over_shared_memory() {
    let _serial = one_at_a_time();
    let dir = station::scratch("conformance");
    let name = unique_station("mock");
    let cut = ConformanceCut::liver();
    let script = dir.join("cut.csv");
    std::fs::write(&script, cut.csv()).unwrap();
    let forces = dir.join("forces.csv");
    let mut server = start_server(&name, &dir, 60.0);
    server.wait_for(Duration::from_secs(60), |l| l.contains("\"haptic\""));
    let mock = start_mock(&name, &script, &forces);
    let (status, out) = mock.finish();
    assert!(status.success(), "{out:?}");
    let summary = json(out.last().unwrap());
    assert_eq!(summary["forces_rejected"], 0, "{summary}");
    // One force per server tick while the device is there: 8500 on a calm machine, fewer
    // when the VM stalls the server (the conformance check says how much is allowed).
    assert!(
        summary["forces_received"].as_u64().unwrap() as f64
            > 0.8 * 1000.0 * cut.script.duration_s(),
        "{summary}"
    );
    server.wait_for(Duration::from_secs(5), |l| {
        json(l)["event"]
            .as_str()
            .is_some_and(|e| e.starts_with("device lost"))
    });
    let trace = read_trace(&forces);
    // The server answers from its first tick after the device's first pose; the first
    // rows carry no force yet.
    conformance::check(&trace, &cut, MAX_FORCE_N, RATE_LIMIT_N);
    server.kill_9();
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn a_killed_device_fades_the_force_and_a_restarted_one_reconnects() {
    let _serial = one_at_a_time();
    let dir = station::scratch("killdevice");
    let name = unique_station("kill");
    // The demo cut, looped: the blade is in the tissue from about 1 s.
    let forces = dir.join("forces.csv");
    let mut server = start_server(&name, &dir, 120.0);
    server.wait_for(Duration::from_secs(60), |l| l.contains("\"haptic\""));
    let mut command = scalpel();
    command
        .args(["mock-device", "--station", &name, "--loop", "--out"])
        .arg(&forces);
    let mut mock = Running::start(command);
    server.wait_for(Duration::from_secs(10), |l| {
        json(l)["event"]
            .as_str()
            .is_some_and(|e| e.starts_with("device connected"))
    });
    // Wait until the device feels the cut.
    server.wait_for(Duration::from_secs(20), |l| {
        json(l)["haptic"]["force_n"]
            .as_f64()
            .is_some_and(|f| f > 0.5)
    });
    mock.kill_9();
    let killed = std::time::Instant::now();
    server.wait_for(Duration::from_secs(5), |l| {
        json(l)["event"]
            .as_str()
            .is_some_and(|e| e.starts_with("device lost"))
    });
    // The dead node is cleaned within 1 s (its publisher goes only with the clean-up), and
    // the force is faded to zero.
    assert!(
        killed.elapsed() < Duration::from_secs(1),
        "lost after {:?}",
        killed.elapsed()
    );
    assert_eq!(nodes_named(&name, "scalpel-mock-device"), 0);
    let line = server.wait_for(Duration::from_secs(2), |l| json(l).get("haptic").is_some());
    let line = json(&line);
    assert_eq!(line["haptic"]["force_n"], 0.0, "{line}");
    assert_eq!(line["haptic"]["watchdog_faded"], true, "{line}");
    // The server keeps ticking at 1 kHz with nobody attached.
    server.assert_ticking();
    // A restarted device is taken as a new connection and feels the cut again.
    let mut command = scalpel();
    command.args([
        "mock-device",
        "--station",
        &name,
        "--loop",
        "--duration",
        "20",
    ]);
    let _mock = Running::start(command);
    server.wait_for(Duration::from_secs(10), |l| {
        json(l)["event"]
            .as_str()
            .is_some_and(|e| e.starts_with("device connected"))
    });
    server.wait_for(Duration::from_secs(20), |l| {
        json(l)["haptic"]["force_n"]
            .as_f64()
            .is_some_and(|f| f > 0.5)
    });
    server.kill_9();
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn a_killed_viewer_is_cleaned_up_and_a_killed_server_restarts_on_the_same_station() {
    let _serial = one_at_a_time();
    let dir = station::scratch("killserver");
    let name = unique_station("srv");
    let mut server = start_server(&name, &dir, 120.0);
    server.wait_for(Duration::from_secs(60), |l| l.contains("\"haptic\""));
    // Viewers attached and killed mid-wait (each waits for a million frames), five times
    // over: each dead node is cleaned within a second, the server keeps ticking without a
    // deadline miss, and a new viewer still gets frames.
    for round in 0..5 {
        let png = dir.join("never.png");
        let mut command = scalpel();
        command
            .args([
                "view",
                "--station",
                &name,
                "--after",
                "1000000",
                "--snapshot",
            ])
            .arg(&png);
        let mut viewer = Running::start(command);
        let attached = std::time::Instant::now();
        while nodes_named(&name, "scalpel-viewer") == 0 {
            assert!(
                attached.elapsed() < Duration::from_secs(10),
                "round {round}: the viewer never attached"
            );
            std::thread::sleep(Duration::from_millis(20));
        }
        std::thread::sleep(Duration::from_millis(100));
        viewer.kill_9();
        let killed = std::time::Instant::now();
        while nodes_named(&name, "scalpel-viewer") > 0 {
            assert!(
                killed.elapsed() < Duration::from_secs(1),
                "round {round}: the dead viewer's node is still there after 1 s"
            );
            std::thread::sleep(Duration::from_millis(20));
        }
    }
    server.assert_ticking();
    let out = scalpel()
        .args(["view", "--station", &name, "--after", "3", "--snapshot"])
        .arg(dir.join("after-kills.png"))
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    // The server itself killed: its shared memory stays behind; a new server on the same
    // station cleans it up and runs. A viewer attached across the kill picks up the new
    // server's frames (it wants 150: the first server dies before sending them all).
    let across = dir.join("across.png");
    let mut command = scalpel();
    command
        .args(["view", "--station", &name, "--after", "150", "--snapshot"])
        .arg(&across);
    let survivor = Running::start(command);
    while nodes_named(&name, "scalpel-viewer") == 0 {
        std::thread::sleep(Duration::from_millis(20));
    }
    std::thread::sleep(Duration::from_millis(500));
    server.kill_9();
    // Its nodes stay behind, dead, until someone cleans up ...
    let dead = scalpel_proto::shm::station_nodes(&name)
        .unwrap()
        .into_iter()
        .filter(|n| n.name.starts_with("scalpel-server.") && !n.alive)
        .count();
    assert!(dead >= 3, "{dead} dead server nodes");
    // ... which the new server on the station does as it starts.
    let mut again = start_server(&name, &dir, 120.0);
    again.wait_for(Duration::from_secs(60), |l| l.contains("\"haptic\""));
    let left = scalpel_proto::shm::station_nodes(&name).unwrap();
    assert!(left.iter().all(|n| n.alive), "stale nodes left: {left:?}");
    let (status, out) = survivor.finish();
    assert!(status.success() && across.exists(), "{out:?}");
    let png = dir.join("view.png");
    let out = scalpel()
        .args(["view", "--station", &name, "--after", "3", "--snapshot"])
        .arg(&png)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(stdout.contains("vertices") && png.exists(), "{stdout}");
    again.kill_9();
    std::fs::remove_dir_all(&dir).ok();
}

/// A non-Rust renderer reads a frame from the running server with the iceoryx2 Python
/// wheel of the same release, from docs/PROTOCOL.md alone (tools/tests/python/). Needs
/// `pip install -r tools/tests/python/requirements.txt`; `.ci/run` does that in a venv and
/// names its interpreter in SCALPEL_PYTHON.
#[test]
#[ignore = "needs the iceoryx2 Python wheel; .ci/run installs it and runs this"]
fn python_reads_a_frame_from_the_running_server() {
    let _serial = one_at_a_time();
    let (dir, name, mut server) = scripted_station("py");
    let frame = station::run_python("read_frame.py", &[name.clone(), "20".into()]);
    let nv = frame["n_vertices"].as_u64().unwrap();
    let nt = frame["n_triangles"].as_u64().unwrap();
    assert!(
        nv > 200 && frame["max_index"].as_u64().unwrap() < nv,
        "{frame}"
    );
    // Uncut, the liver is a closed genus-0 surface: T = 2V − 4 (the demo cut opens it
    // later; a cut surface has its walls as well).
    assert!(
        nt == 2 * nv - 4 || frame["wound_triangles"].as_u64().unwrap() > 0,
        "{frame}"
    );
    assert_eq!(frame["unit_normals"], true, "{frame}");
    // The liver's 250 × 150 × 50 mm box, centred.
    let bbox = &frame["bbox_mm"];
    for (axis, half) in [(0, 125.0), (1, 75.0), (2, 25.0)] {
        let lo = bbox[0][axis].as_f64().unwrap();
        let hi = bbox[1][axis].as_f64().unwrap();
        assert!(
            (lo + half).abs() < 5.0 && (hi - half).abs() < 5.0,
            "{frame}"
        );
    }
    server.kill_9();
    std::fs::remove_dir_all(&dir).ok();
}

/// The viewer's window mode draws live frames (under a virtual X server: `xvfb-run`, which
/// `.ci/run` installs).
#[test]
#[ignore = "needs xvfb-run; .ci/run installs it and runs this"]
fn xvfb_the_viewer_window_draws_live_frames() {
    let _serial = one_at_a_time();
    let (dir, name, mut server) = scripted_station("win");
    let out = std::process::Command::new("xvfb-run")
        .args(["-a", env!("CARGO_BIN_EXE_scalpel")])
        .args(["view", "--station", &name, "--exit-after", "30"])
        .output()
        .expect("xvfb-run");
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success() && stdout.contains("drew 30 frames"),
        "{stdout}{}",
        String::from_utf8_lossy(&out.stderr)
    );
    server.kill_9();
    std::fs::remove_dir_all(&dir).ok();
}

/// Two stations side by side on one machine, isolated by name: each server sees only its
/// own device, and a second server on a taken station name is refused.
#[test]
fn stations_run_side_by_side_isolated_by_name() {
    let _serial = one_at_a_time();
    let dir = station::scratch("twostations");
    let a = unique_station("a");
    let b = unique_station("b");
    let mut server_a = start_server(&a, &dir, 120.0);
    let mut server_b = start_server(&b, &dir, 120.0);
    server_a.wait_for(Duration::from_secs(60), |l| l.contains("\"haptic\""));
    server_b.wait_for(Duration::from_secs(60), |l| l.contains("\"haptic\""));
    // A device for station a only.
    let mut command = scalpel();
    command.args(["mock-device", "--station", &a, "--loop", "--duration", "60"]);
    let mut mock_a = Running::start(command);
    server_a.wait_for(Duration::from_secs(10), |l| {
        json(l)["event"]
            .as_str()
            .is_some_and(|e| e.starts_with("device connected"))
    });
    // Station b has seen no device all along.
    let line =
        json(&server_b.wait_for(Duration::from_secs(2), |l| json(l).get("haptic").is_some()));
    assert_eq!(line["device_connected"], false, "{line}");
    assert!(
        !server_b.seen.iter().any(|l| json(l)["event"]
            .as_str()
            .is_some_and(|e| e.starts_with("device connected"))),
        "station b saw station a's device"
    );
    // Its own device next; then station a's device dies, and only station a notices.
    let mut command = scalpel();
    command.args(["mock-device", "--station", &b, "--loop", "--duration", "60"]);
    let _mock_b = Running::start(command);
    server_b.wait_for(Duration::from_secs(10), |l| {
        json(l)["event"]
            .as_str()
            .is_some_and(|e| e.starts_with("device connected"))
    });
    mock_a.kill_9();
    server_a.wait_for(Duration::from_secs(5), |l| {
        json(l)["event"]
            .as_str()
            .is_some_and(|e| e.starts_with("device lost"))
    });
    let line =
        json(&server_b.wait_for(Duration::from_secs(2), |l| json(l).get("haptic").is_some()));
    assert_eq!(line["device_connected"], true, "{line}");
    assert!(
        !server_b.seen.iter().any(|l| json(l)["event"]
            .as_str()
            .is_some_and(|e| e.starts_with("device lost"))),
        "station b lost a device it never had"
    );
    // A second server on a taken station name is refused, and says why.
    let config = dir.join(format!("{a}.toml"));
    let out = std::process::Command::new(station::server_binary())
        .arg(&config)
        .args(["--duration", "5"])
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{stderr}");
    assert!(stderr.contains("already has a running server"), "{stderr}");
    server_a.kill_9();
    server_b.kill_9();
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn malformed_poses_from_a_device_are_said_and_counted() {
    let _serial = one_at_a_time();
    let dir = station::scratch("badposes");
    let name = unique_station("badposes");
    let mut server = start_server(&name, &dir, 60.0);
    server.wait_for(Duration::from_secs(60), |l| l.contains("\"haptic\""));
    // A device that sends nothing but NaN tips.
    let node = scalpel_proto::shm::node("scalpel-test-device", &name).unwrap();
    scalpel_proto::shm::connect::hello(&node, &name, "nan-device", Duration::from_secs(2)).unwrap();
    let poses = scalpel_proto::shm::pose_service(&node, &name)
        .unwrap()
        .publisher_builder()
        .create()
        .unwrap();
    for seq in 1..=40 {
        let pose = scalpel_proto::shm::DevicePose {
            layout_version: scalpel_proto::shm::LAYOUT_VERSION,
            flags: 0,
            seq,
            device_time_ns: scalpel_client::frame_reader::monotonic_ns(),
            tip_m: [f64::NAN, 0.0, 0.0],
            orientation_xyzw: [0.0, 0.0, 0.0, 1.0],
        };
        poses.send_copy(pose).unwrap();
        std::thread::sleep(Duration::from_millis(1));
    }
    let said = server.wait_for(Duration::from_secs(5), |l| {
        json(l)["event"]
            .as_str()
            .is_some_and(|e| e.contains("poses rejected as malformed"))
    });
    let said = json(&said);
    let count: u64 = said["event"]
        .as_str()
        .unwrap()
        .split_whitespace()
        .nth(1)
        .unwrap()
        .parse()
        .unwrap();
    assert!((1..=40).contains(&count), "{said}");
    drop(poses);
    drop(node);
    let (status, lines) = server.interrupt();
    assert!(status.success());
    let summary = json(lines.last().unwrap());
    let rejected = summary["device"]["poses_rejected"].as_u64().unwrap();
    // The haptic thread drains the newest pose each tick and counts every one it drops.
    assert!((count..=40).contains(&rejected), "{summary}");
    std::fs::remove_dir_all(&dir).ok();
}
