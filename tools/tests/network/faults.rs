//! Every fault of the vocabulary, with real processes: set up (server, mock device, viewers,
//! a renderer and observers of the test's own), scheduled by the instructor, then checked as
//! the device, each observer and the renderer saw it, and the journal replayed.

use super::*;

use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;

use scalpel_client::remote::{Credentials, Observer, Update};
use scalpel_proto::wire::EventKind;

/// What the test saw of one fault window, on the station clock (ms).
#[derive(Debug, Clone, Copy)]
struct Window {
    start: u64,
    end: u64,
}

/// A row of the mock device's recording.
#[derive(Debug, Clone, Copy)]
struct ForceRow {
    seq: u64,
    force: [f64; 3],
    force_n: f64,
    faded: bool,
    /// The station tick of the force.
    tick: u64,
    pose_seq: u64,
}

fn read_forces(csv: &Path) -> Vec<ForceRow> {
    let text = std::fs::read_to_string(csv).unwrap();
    text.lines()
        .skip(1)
        .map(|l| {
            let c: Vec<f64> = l
                .split(',')
                .map(|x| x.parse().unwrap_or(f64::NAN))
                .collect();
            ForceRow {
                seq: c[1] as u64,
                force: [c[5], c[6], c[7]],
                force_n: (c[5] * c[5] + c[6] * c[6] + c[7] * c[7]).sqrt(),
                faded: (c[9] as u32) & 1 == 1,
                tick: c[10] as u64,
                pose_seq: c[11] as u64,
            }
        })
        .filter(|r| r.tick > 0)
        .collect()
}

/// What one observer received, stamped with the station tick it arrived at.
#[derive(Debug, Default)]
struct Seen {
    /// (arrival tick, metrics).
    metrics: Vec<(u64, scalpel_proto::wire::Metrics)>,
    /// (arrival tick, tick the simulation wrote it, tool tip y in mm).
    frames: Vec<(u64, u64, Option<f64>)>,
    events: Vec<scalpel_proto::wire::Event>,
}

/// The whole set-up of the issue, with real processes: a server with the QUIC endpoint and a
/// shared-memory device, the mock device cutting, two viewers, eight observers and an
/// instructor (the `scalpel instruct` CLI). The instructor schedules every fault of the
/// vocabulary at its own station tick; each has the effect docs/PROTOCOL.md ("Faults")
/// documents, as seen by the mock device, the observers and a renderer, and the output
/// stage's limits hold throughout.
#[test]
fn every_fault_has_its_documented_effect_and_the_limits_hold() {
    let dir = station::scratch("faults");
    make_certs(&dir);
    let name = unique_station("flt");
    let journal = dir.join("faults.journal");
    let Rig {
        mut server,
        addr,
        origin_ns,
        mock,
        forces_csv,
        viewers,
        stop,
        renderer,
        seen,
        observing,
    } = set_up(&dir, &name, &journal);
    let station_now = station_clock(origin_ns);
    let (t, windows) = schedule_the_vocabulary(addr, &dir, station_now);
    // Until the last window has been over for a while.
    while station_now() < t + 8300 {
        std::thread::sleep(Duration::from_millis(50));
    }
    stop.store(true, Ordering::Relaxed);
    let frames_rendered = renderer.join().unwrap();
    observing.join().unwrap();
    // The device stops as a user stops it (Ctrl-C): it writes its recording and exits.
    let (status, _) = mock.interrupt();
    assert!(status.success(), "the mock device failed");
    for v in viewers {
        let (status, lines) = v.finish();
        assert!(status.success(), "a viewer failed: {lines:?}");
    }
    for k in 0..2 {
        assert!(dir.join(format!("viewer{k}.png")).is_file());
    }
    check_device(&read_forces(&forces_csv), &windows, t);
    for (k, log) in seen.iter().enumerate() {
        check_observer(k, &log.lock().unwrap(), &windows, t);
    }
    check_renderer(&frames_rendered, &windows);

    // The server never stopped ticking.
    server.assert_ticking();
    the_journal_replays(server, &journal);
    std::fs::remove_dir_all(&dir).ok();
}

/// Everything [`set_up`] started, running.
struct Rig {
    server: Running,
    addr: SocketAddr,
    /// The station clock's origin on CLOCK_MONOTONIC (ns).
    origin_ns: u64,
    mock: Running,
    /// Where the mock device writes its recording.
    forces_csv: PathBuf,
    viewers: Vec<Running>,
    /// Tells the renderer and the observers to stop.
    stop: Arc<AtomicBool>,
    /// The renderer: when each frame arrived, on the station clock (ms).
    renderer: JoinHandle<Vec<u64>>,
    seen: Vec<Arc<Mutex<Seen>>>,
    observing: JoinHandle<()>,
}

/// The station clock (ms) of the server whose clock starts at `origin_ns`.
fn station_clock(origin_ns: u64) -> impl Fn() -> u64 + Copy + Send + 'static {
    move || scalpel_client::frame_reader::monotonic_ns().saturating_sub(origin_ns) / 1_000_000
}

/// The server, the mock device, the viewers, the renderer and the observers, started; returns
/// once the cut is steady.
fn set_up(dir: &Path, name: &str, journal: &Path) -> Rig {
    let (mut server, addr) = start_with(
        dir,
        name,
        "[device]\nkind = \"shared_memory\"\n",
        &["--journal", journal.to_str().unwrap()],
    );
    let clock = server.wait_for(Duration::from_secs(10), |l| {
        json(l)["event"]
            .as_str()
            .is_some_and(|e| e.starts_with("clock:"))
    });
    let origin_ns: u64 = json(&clock)["event"]
        .as_str()
        .unwrap()
        .split("CLOCK_MONOTONIC ")
        .nth(1)
        .and_then(|s| s.split(' ').next())
        .unwrap()
        .parse()
        .unwrap();
    let (mock, forces_csv) = start_device(dir, name, &mut server);
    // Two viewers, headless, attached all along.
    let viewers: Vec<Running> = (0..2)
        .map(|k| {
            let mut v = scalpel();
            v.args([
                "view",
                "--station",
                name,
                "--after",
                "700",
                "--timeout",
                "60",
            ])
            .arg("--snapshot")
            .arg(dir.join(format!("viewer{k}.png")));
            Running::start(v)
        })
        .collect();
    let stop = Arc::new(AtomicBool::new(false));
    let renderer = start_renderer(name, &stop, origin_ns);
    let (seen, observing) = start_observers(addr, dir, &stop, origin_ns);
    wait_for_steady_cutting(&seen[0]);
    Rig {
        server,
        addr,
        origin_ns,
        mock,
        forces_csv,
        viewers,
        stop,
        renderer,
        seen,
        observing,
    }
}

/// The mock device, connected to `server`; returns it and where it writes its recording.
fn start_device(dir: &Path, name: &str, server: &mut Running) -> (Running, PathBuf) {
    // The device: the liver's demo stroke at 3 mm/s (20 s of steady cutting, room for the
    // ten windows), recorded.
    let liver = scalpel_sim::scene::build_scene(
        &scalpel_sim::scene::builtin("liver").unwrap(),
        None,
        &mut scalpel_sim::progress::Silent,
    )
    .unwrap();
    let stroke = scalpel_sim::pipeline::CutScript::stroke_for(
        &scalpel_sim::pipeline::start_surface(&liver),
        0.06,
        0.01,
        0.003,
    )
    .unwrap();
    let script = dir.join("stroke.csv");
    std::fs::write(&script, common::conformance::script_csv(&stroke)).unwrap();
    let forces_csv = dir.join("forces.csv");
    let mut mock = scalpel();
    mock.args([
        "mock-device",
        "--station",
        name,
        "--duration",
        "26",
        "--script",
    ])
    .arg(&script)
    .arg("--out")
    .arg(&forces_csv);
    let mock = Running::start(mock);
    server.wait_for(Duration::from_secs(20), |l| {
        json(l)["event"]
            .as_str()
            .is_some_and(|e| e.starts_with("device connected"))
    });
    (mock, forces_csv)
}

/// A renderer on a thread of its own, until `stop`; the thread returns when each frame
/// arrived.
fn start_renderer(name: &str, stop: &Arc<AtomicBool>, origin_ns: u64) -> JoinHandle<Vec<u64>> {
    let station_now = station_clock(origin_ns);
    // A renderer of the test's own, to see exactly when frames stop and start.
    let (name, stop) = (name.to_string(), stop.clone());
    std::thread::spawn(move || {
        let mut reader = scalpel_client::frame_reader::FrameReader::open(&name).unwrap();
        let mut arrivals = Vec::new();
        while !stop.load(Ordering::Relaxed) {
            if let Ok(Some(_)) = reader.wait(Duration::from_millis(50)) {
                arrivals.push(station_now());
            }
        }
        arrivals
    })
}

/// Eight observers on a thread of their own, until `stop`; returns what each has seen so far
/// and the thread.
fn start_observers(
    addr: SocketAddr,
    dir: &Path,
    stop: &Arc<AtomicBool>,
    origin_ns: u64,
) -> (Vec<Arc<Mutex<Seen>>>, JoinHandle<()>) {
    let station_now = station_clock(origin_ns);
    // Eight observers, frames at 30 Hz, on a thread of their own.
    let seen: Vec<Arc<Mutex<Seen>>> = (0..8)
        .map(|_| Arc::new(Mutex::new(Seen::default())))
        .collect();
    let observing = {
        let (seen, stop, dir) = (seen.clone(), stop.clone(), dir.to_path_buf());
        std::thread::spawn(move || {
            let runtime = tokio::runtime::Builder::new_current_thread()
                .enable_all()
                .build()
                .unwrap();
            runtime.block_on(async move {
                for (k, log) in seen.into_iter().enumerate() {
                    let who = if k % 2 == 0 { "obs1" } else { "obs2" };
                    let mut o = Observer::connect(
                        addr,
                        "localhost",
                        &Credentials::from_dir(&dir, who),
                        who,
                    )
                    .await
                    .unwrap();
                    o.0.subscribe(30.0).await.unwrap();
                    tokio::spawn(async move {
                        while let Some(u) = o.0.next().await {
                            let at = station_now();
                            let mut s = log.lock().unwrap();
                            match u {
                                Update::Metrics(m) => s.metrics.push((at, m)),
                                Update::Frame(f) => s.frames.push((
                                    at,
                                    f.server_time_ns.saturating_sub(origin_ns) / 1_000_000,
                                    f.tool.map(|t| f64::from(t.tip_m[1]) * 1e3),
                                )),
                                Update::Event(e) => s.events.push(e),
                                // This station runs no lesson.
                                Update::Lesson(_) | Update::Score(_) => {}
                            }
                        }
                    });
                }
                while !stop.load(Ordering::Relaxed) {
                    tokio::time::sleep(Duration::from_millis(20)).await;
                }
            });
        })
    };
    (seen, observing)
}

/// Waits until the observer's last ten metrics show the blade cutting.
fn wait_for_steady_cutting(seen: &Mutex<Seen>) {
    // Wait for steady cutting (the demo cut ruptures about a second after entry).
    let steady = || {
        let s = seen.lock().unwrap();
        s.metrics.len() > 10
            && s.metrics[s.metrics.len() - 10..]
                .iter()
                .all(|(_, m)| m.force_n > 1.0 && m.cut_length_mm > 2.0)
    };
    let waited = std::time::Instant::now();
    while !steady() {
        assert!(waited.elapsed() < Duration::from_secs(20), "no steady cut");
        std::thread::sleep(Duration::from_millis(50));
    }
}

/// The instructor schedules the ten faults, 5 s ahead, and lists them; returns when the
/// first starts (station clock, ms) and each fault's window.
fn schedule_the_vocabulary(
    addr: SocketAddr,
    dir: &Path,
    station_now: impl Fn() -> u64,
) -> (u64, Vec<Window>) {
    // The instructor schedules the vocabulary, one window each, with the CLI (ten runs,
    // each with a TLS handshake; a debug build's too: five seconds is room enough on a
    // busy machine).
    let t = station_now() + 5000;
    let plan: [(&[&str], u64, u64); 10] = [
        (
            &["tissue-stiffness", "--factor", "3", "--ramp-ms", "100"],
            0,
            700,
        ),
        (&["force-spike", "--newtons", "100"], 1000, 400),
        (&["force-saturation", "--max-n", "1"], 1700, 400),
        (&["device-latency", "--ms", "50"], 2400, 500),
        (&["pose-noise", "--sigma-mm", "2"], 3200, 500),
        (&["device-dropout"], 4000, 400),
        (&["sim-stall"], 4700, 400),
        (&["sim-slowdown", "--factor", "4"], 5400, 800),
        (&["renderer-freeze"], 6500, 400),
        (&["observer-stream-loss"], 7200, 400),
    ];
    let mut windows = Vec::new();
    for (args, offset, ms) in plan {
        let out = scalpel()
            .args(["instruct", &addr.to_string(), "--certs"])
            .arg(dir)
            .args(["--name", "ann", "fault"])
            .args(args)
            .args(["--at", &(t + offset).to_string()])
            .args(["--duration-ms", &ms.to_string()])
            .output()
            .unwrap();
        let text = String::from_utf8_lossy(&out.stdout);
        assert!(
            out.status.success() && text.starts_with("scheduled: fault"),
            "{args:?}: {text}{}",
            String::from_utf8_lossy(&out.stderr)
        );
        windows.push(Window {
            start: t + offset,
            end: t + offset + ms,
        });
    }
    assert!(
        station_now() < t,
        "scheduling took too long to test the first window"
    );
    let listed = scalpel()
        .args(["instruct", &addr.to_string(), "--certs"])
        .arg(dir)
        .args(["--name", "ann", "--json", "list"])
        .output()
        .unwrap();
    let listed = json(String::from_utf8_lossy(&listed.stdout).trim());
    assert_eq!(
        listed["faults"].as_array().map(Vec::len),
        Some(10),
        "{listed}"
    );
    assert!(
        listed["faults"]
            .as_array()
            .unwrap()
            .iter()
            .all(|f| f["by"] == "ann")
    );
    (t, windows)
}

/// What the mock device recorded: the output stage's limits, and each fault that acts on
/// the force.
fn check_device(forces: &[ForceRow], windows: &[Window], t: u64) {
    let w = |i: usize| windows[i];
    let rows = |from: u64, to: u64| forces.iter().filter(move |r| (from..to).contains(&r.tick));
    let mean = |from: u64, to: u64| {
        let v: Vec<f64> = rows(from, to).map(|r| r.force_n).collect();
        v.iter().sum::<f64>() / v.len().max(1) as f64
    };

    // The output stage's limits hold over the whole run, every fault included (to the
    // recording's five decimals).
    const CSV: f64 = 1e-4;
    // Each force sample once (a row repeats the last sample until a new one comes; the
    // device zeroes a sample that is 10 ms old by itself, which is its own safety, not the
    // server's output).
    let mut samples = forces.to_vec();
    samples.dedup_by_key(|r| r.tick);
    for pair in samples.windows(2) {
        let (a, b) = (pair[0], pair[1]);
        assert!(b.force_n <= 3.3 + CSV, "{b:?}");
        // The change of the force vector, direction included.
        let step = (0..3)
            .map(|i| (b.force[i] - a.force[i]).powi(2))
            .sum::<f64>()
            .sqrt();
        let ticks = b.tick.saturating_sub(a.tick).max(1) as f64;
        assert!(step <= 0.5 * ticks + CSV, "{a:?} -> {b:?}");
    }
    let baseline = mean(t - 500, t);
    assert!(
        baseline > 1.0,
        "cutting force before the faults: {baseline} N"
    );

    // Tissue stiffness ×3: the blade rubs on stiffer walls, the force rises.
    let stiff = mean(w(0).start + 150, w(0).end);
    assert!(
        stiff > baseline * 1.15,
        "stiffness ×3: {stiff} N against {baseline} N"
    );
    // Force spike of 100 N: the device gets F_max, no more (checked above), rate-limited.
    let peak = rows(w(1).start, w(1).end)
        .map(|r| r.force_n)
        .fold(0.0, f64::max);
    assert!(peak > 3.2, "the spike should reach F_max: {peak} N");
    // Saturation at 1 N: after the rate-limited descent, at most 1 N.
    let sat = rows(w(2).start + 20, w(2).end)
        .map(|r| r.force_n)
        .fold(0.0, f64::max);
    assert!(sat <= 1.0 + CSV, "saturated at 1 N: {sat} N");
    // Latency of 50 ms: the force answers a pose 50 samples old.
    let lag = |from: u64, to: u64| {
        let mut v: Vec<u64> = rows(from, to)
            .map(|r| r.seq.saturating_sub(r.pose_seq))
            .collect();
        v.sort_unstable();
        v[v.len() / 2]
    };
    assert!(
        (45..=56).contains(&lag(w(3).start + 80, w(3).end)),
        "{}",
        lag(w(3).start + 80, w(3).end)
    );
    assert!(lag(t - 500, t) <= 3, "{}", lag(t - 500, t));
    eprintln!(
        "device: baseline {baseline:.3} N, stiffness ×3 {stiff:.3} N, spike peak {peak:.3} N, saturated {sat:.3} N, lag {} samples",
        lag(w(3).start + 80, w(3).end)
    );
    // Dropout: the force fades to zero within the watchdog's 5 ms and its 5 ms fade.
    assert!(rows(w(5).start + 15, w(5).end).all(|r| r.faded && r.force_n == 0.0));
    // Stall: no new force model; the watchdog fades the force after its 100 ms.
    assert!(rows(w(6).start + 120, w(6).end).all(|r| r.faded && r.force_n == 0.0));
    // And it all came back after the last window.
    assert!(
        mean(t + 7800, t + 8100) > 0.5,
        "force after the faults: {}",
        mean(t + 7800, t + 8100)
    );
}

/// What observer `k` received: every fault announced, and the effects of those that show in
/// the metrics and frames.
fn check_observer(k: usize, s: &Seen, windows: &[Window], t: u64) {
    let w = |i: usize| windows[i];
    // What arrived when (delivery), and what was made when (the metrics' station
    // tick, the frames' write time): under load a message made before a window can
    // arrive inside it.
    let metrics_in = |from: u64, to: u64| {
        s.metrics
            .iter()
            .filter(move |(at, _)| (from..to).contains(at))
    };
    let frames_in = |from: u64, to: u64| {
        s.frames
            .iter()
            .filter(move |(at, _, _)| (from..to).contains(at))
    };
    let metrics_made = |from: u64, to: u64| {
        s.metrics
            .iter()
            .filter(move |(_, m)| (from..to).contains(&m.station_tick))
    };
    let frames_made = |from: u64, to: u64| {
        s.frames
            .iter()
            .filter(move |(_, made, _)| (from..to).contains(made))
    };
    // Every fault announced, applied and ended.
    let applied = s
        .events
        .iter()
        .filter(|e| e.kind == EventKind::FaultApplied)
        .count();
    let ended = s
        .events
        .iter()
        .filter(|e| e.kind == EventKind::FaultCleared)
        .count();
    assert_eq!((applied, ended), (10, 10), "observer {k}: {:?}", s.events);
    // Pose noise of 2 mm: the blade in the frames shakes across the stroke (it follows
    // the noisy pose at most 2 mm a tick, so its spread is about 1.2 mm, not 2).
    let spread = |from: u64, to: u64| {
        let y: Vec<f64> = frames_made(from, to).filter_map(|(_, _, y)| *y).collect();
        let m = y.iter().sum::<f64>() / y.len().max(1) as f64;
        (y.iter().map(|v| (v - m).powi(2)).sum::<f64>() / y.len().max(1) as f64).sqrt()
    };
    assert!(
        spread(w(4).start + 50, w(4).end) > 0.5,
        "observer {k}: noise {}",
        spread(w(4).start + 50, w(4).end)
    );
    assert!(
        spread(t - 500, t) < 0.2,
        "observer {k}: {}",
        spread(t - 500, t)
    );
    // Stall: the simulation tick stands still.
    let ticks: Vec<u64> = metrics_made(w(6).start + 15, w(6).end)
        .map(|(_, m)| m.sim_tick)
        .collect();
    assert!(
        ticks.len() >= 2 && ticks.last().unwrap() - ticks[0] <= 1,
        "observer {k}: {ticks:?}"
    );
    // Slowdown ×4: a quarter of the ticks.
    let during: Vec<(u64, u64)> = metrics_made(w(7).start + 50, w(7).end)
        .map(|(_, m)| (m.station_tick, m.sim_tick))
        .collect();
    let (first, last) = (during[0], during[during.len() - 1]);
    let rate = (last.1 - first.1) as f64 / (last.0 - first.0) as f64;
    assert!(
        (0.18..0.33).contains(&rate),
        "observer {k}: {rate} simulated ms per ms"
    );
    // Renderer freeze: no frames reach the observers either (they come from the same
    // shared memory).
    assert_eq!(
        frames_made(w(8).start + 20, w(8).end).count(),
        0,
        "observer {k}"
    );
    // Stream loss: none of the metrics and frames made while it lasts arrive (the
    // station notices within its 10 ms round), but for the latest of each, which goes
    // out when the stream resumes (metrics are sent every 100 ms, frames as they are
    // read, up to 33 ms apart); both are back after it.
    let leaked: Vec<(u64, u64)> = metrics_made(w(9).start + 15, w(9).end - 120)
        .map(|(at, m)| (*at, m.station_tick))
        .collect();
    assert!(
        leaked.is_empty(),
        "observer {k}: metrics (arrived, made) {leaked:?} in {:?}",
        w(9)
    );
    assert_eq!(
        frames_made(w(9).start + 15, w(9).end - 40).count(),
        0,
        "observer {k}"
    );
    assert!(
        metrics_in(w(9).end + 100, w(9).end + 800).count() >= 4,
        "observer {k}"
    );
    assert!(
        frames_in(w(9).end + 100, w(9).end + 800).count() >= 5,
        "observer {k}"
    );
}

/// When the test's own renderer got frames, around the renderer freeze.
fn check_renderer(frames_rendered: &[u64], windows: &[Window]) {
    let w = |i: usize| windows[i];
    // Renderer freeze, as a renderer sees it: no frame within the window, frames around it.
    let rendered = |from: u64, to: u64| {
        frames_rendered
            .iter()
            .filter(|&&at| (from..to).contains(&at))
            .count()
    };
    assert_eq!(rendered(w(8).start + 20, w(8).end), 0);
    assert!(rendered(w(8).start - 300, w(8).start) >= 10);
    assert!(rendered(w(8).end + 50, w(8).end + 350) >= 10);
}

/// The server stopped, and its journal replayed.
fn the_journal_replays(server: Running, journal: &Path) {
    // Stopped as an operator stops it, its journal replays bit for bit, with every
    // command and who sent it.
    let (status, _) = server.interrupt();
    assert!(status.success());
    let out = scalpel()
        .arg("replay")
        .arg(journal)
        .arg("--json")
        .output()
        .unwrap();
    let replay = json(String::from_utf8_lossy(&out.stdout).trim());
    assert_eq!(replay["identical"], true, "{replay}");
    let commands = replay["commands"].as_array().unwrap();
    assert_eq!(commands.len(), 11, "ten faults and a list: {replay}");
    assert!(commands.iter().all(|c| c["by"] == "ann"));
    assert!(
        replay["stiffness_changes"].as_u64().unwrap() >= 2,
        "{replay}"
    );
}
