//! `scalpel bench loop [--seconds S] [--viewers N] [--haptic-cpu C] [--json]`: the station's real-time loop as
//! a device and renderers see it. Starts the release server (`scalpel-server`, beside this
//! binary) on a station of its own with a shared-memory device (and the simulation thread at
//! SCHED_FIFO 60: the liver's ticks keep well inside 1 ms in release), plays the demo cut with the
//! mock device (phase-locked, measuring pose → force at the device), and attaches a
//! measuring frame subscriber (pose → frame received). Two phases of S seconds: no viewers,
//! then N viewers that receive, decode and render every frame (the CPU renderer at
//! 480×360), as local renderers would. Reports per phase the haptic loop's wake-up
//! jitter (p50/p99/p99.9/max over the phase's one-second windows: the median of the p50s,
//! the largest p99, p99.9 and max) and deadline misses from the server's status lines.

use std::io::{BufRead, BufReader};
use std::path::PathBuf;
use std::process::{Command, Stdio};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use anyhow::{Context, bail};
use scalpel_client::frame_reader::FrameReader;
use scalpel_client::mock_device::{MockDevice, MockOptions};
use scalpel_client::render::RenderOptions;
use scalpel_sim::pipeline::CutScript;
use serde::Serialize;

use crate::stats::Quantiles;

/// Targets of issue 5 on this machine, with SCHED_FIFO.
const JITTER_P999_TARGET_MS: f64 = 0.100;
/// See [`JITTER_P999_TARGET_MS`].
const POSE_TO_FRAME_P99_TARGET_MS: f64 = 0.200;

/// Quantiles of samples in seconds, in ms.
fn quantiles(samples: &[f64]) -> Quantiles {
    let ms: Vec<f64> = samples.iter().map(|s| s * 1e3).collect();
    Quantiles::or_zero(&ms)
}

#[derive(Debug, Serialize, Default)]
struct HapticFigures {
    windows: usize,
    ticks: u64,
    /// Ticks that woke 0.1 ms or more late: the phase's p99.9 is under 0.1 ms when these
    /// are at most one in a thousand.
    ticks_late_over_0_1_ms: u64,
    jitter_p50_ms: f64,
    jitter_p99_ms: f64,
    jitter_p999_ms: f64,
    jitter_max_ms: f64,
    deadline_misses: u64,
    rate_hz_min: f64,
}

#[derive(Debug, Serialize)]
struct Phase {
    viewers: usize,
    haptic: HapticFigures,
    pose_to_force_ms: Quantiles,
    pose_to_frame_ms: Quantiles,
    /// The first part of it: from the haptic thread taking the pose to the simulation
    /// thread stamping the frame's header (its wake-up, the normals and the loan).
    pose_to_frame_stamped_ms: Quantiles,
    /// The rest: writing the payload, sending, and the subscriber's wake-up.
    frame_stamped_to_received_ms: Quantiles,
    frames_rendered_by_viewers: u64,
}

#[derive(Debug, Serialize)]
struct LoopBench {
    station: String,
    seconds_per_phase: f64,
    /// The haptic thread's own CPU (`--haptic-cpu`; the simulation and the network
    /// threads then run on the others), or none.
    haptic_cpu: Option<usize>,
    phases: Vec<Phase>,
    jitter_p999_target_ms: f64,
    pose_to_frame_p99_target_ms: f64,
    jitter_p999_met: bool,
    pose_to_frame_p99_met: bool,
    viewers_add_no_misses: bool,
}

/// Status lines of the server as (uptime, line).
type Lines = Arc<std::sync::Mutex<Vec<(f64, serde_json::Value)>>>;

/// The release server beside this binary.
fn server_binary() -> anyhow::Result<PathBuf> {
    let exe = std::env::current_exe()?;
    let path = exe.with_file_name("scalpel-server");
    if !path.exists() {
        bail!(
            "{} is missing: build it with `cargo build --release --bin scalpel-server`",
            path.display()
        );
    }
    Ok(path)
}

/// Starts the release server on `config` for `duration_s` with JSON output; returns it and
/// its stdout.
pub(crate) fn spawn_server(
    config: &std::path::Path,
    duration_s: f64,
) -> anyhow::Result<(std::process::Child, std::process::ChildStdout)> {
    let mut server = Command::new(server_binary()?)
        .arg(config)
        .args(["--json", "--duration", &format!("{duration_s}")])
        .stdout(Stdio::piped())
        .stderr(Stdio::inherit())
        .spawn()
        .context("cannot start scalpel-server")?;
    let stdout = server.stdout.take().context("server stdout")?;
    Ok((server, stdout))
}

/// Runs the benchmark.
pub fn run(
    seconds: f64,
    viewers: usize,
    haptic_cpu: Option<usize>,
    json: bool,
) -> anyhow::Result<()> {
    if !(seconds.is_finite() && (2.0..=3600.0).contains(&seconds)) {
        bail!("--seconds must be between 2 and 3600, got {seconds}");
    }
    if viewers > 7 {
        bail!("--viewers: at most 7 (the frame service takes 8 subscribers, one measures)");
    }
    if let Some(c) = haptic_cpu {
        let cpus = scalpel_server::realtime::allowed_cpus();
        scalpel_server::realtime::cpus_besides(c, &cpus)
            .map_err(|e| anyhow::anyhow!("--haptic-cpu: {e}"))?;
    }
    scalpel_proto::shm::quiet_logging();
    let station = format!("bench-loop-{}", std::process::id());
    let dir = std::env::temp_dir().join(&station);
    std::fs::create_dir_all(&dir)?;
    let config = dir.join("server.toml");
    std::fs::write(
        &config,
        format!(
            "station = \"{station}\"\n[device]\nkind = \"shared_memory\"\n[rates]\nstatus_interval_s = 1.0\nframe_hz = 60.0\n[realtime]\nsim_fifo_priority = 60\nhaptic_cpu = {}\n",
            haptic_cpu.map_or(-1, |c| c as i64)
        ),
    )?;
    let total = 2.0 * seconds + 4.0;
    let (mut server, stdout) = spawn_server(&config, total + 2.0)?;
    let lines: Lines = Arc::default();
    let (started_tx, started_rx) = std::sync::mpsc::channel();
    {
        let lines = lines.clone();
        std::thread::spawn(move || {
            for line in BufReader::new(stdout).lines().map_while(Result::ok) {
                let v: serde_json::Value = serde_json::from_str(&line).unwrap_or_default();
                if v.get("haptic").is_some() {
                    let t = v["uptime_s"].as_f64().unwrap_or(0.0);
                    if let Ok(mut l) = lines.lock() {
                        l.push((t, v));
                    }
                    let _ = started_tx.send(());
                }
            }
        });
    }
    let result = measure(&station, seconds, viewers, &lines, started_rx)
        .map(|r| LoopBench { haptic_cpu, ..r });
    let _ = server.kill();
    let _ = server.wait();
    std::fs::remove_dir_all(&dir).ok();
    super::emit(json, &result?, print_report)
}

fn measure(
    station: &str,
    seconds: f64,
    viewers: usize,
    lines: &Lines,
    started: std::sync::mpsc::Receiver<()>,
) -> anyhow::Result<LoopBench> {
    started
        .recv_timeout(Duration::from_secs(120))
        .context("the server printed no status line")?;
    let server_t0 = lines.lock().map(|l| l[0].0).unwrap_or(1.0) - 1.0;
    let wall_t0 = Instant::now() - Duration::from_secs_f64(1.0);
    let scene = scalpel_server::scene_file::load_scene("liver")?;
    let script = CutScript::default_for(&scalpel_sim::pipeline::start_surface(&scene))?;
    let stop = Arc::new(AtomicBool::new(false));

    // The device, for both phases.
    let device = spawn_device(station, script, &stop)?;
    // The measuring subscriber.
    let subscriber = spawn_subscriber(station, &stop)?;
    // Phase 1: let the phase lock settle, then S seconds with no viewers.
    let phase1 = settle_then_wait(wall_t0, seconds);
    // Phase 2: with the viewers.
    let viewer_stop = Arc::new(AtomicBool::new(false));
    let viewer_threads = spawn_viewers(station, viewers, &viewer_stop)?;
    let phase2 = settle_then_wait(wall_t0, seconds);
    // One more status line covering the end of phase 2.
    std::thread::sleep(Duration::from_millis(1100));
    viewer_stop.store(true, Ordering::Relaxed);
    let rendered = join_viewers(viewer_threads)?;
    stop.store(true, Ordering::Relaxed);
    let device_latencies = device
        .join()
        .map_err(|_| anyhow::anyhow!("the device panicked"))??;
    let frame_latencies = subscriber
        .join()
        .map_err(|_| anyhow::anyhow!("the subscriber panicked"))??;
    let lines = lines.lock().map_err(|_| anyhow::anyhow!("poisoned"))?;
    let recorded = Recorded {
        device_latencies,
        frame_latencies,
        // The device's and the subscriber's clocks started a little after wall_t0.
        device_offset: 1.0,
        lines: &lines,
        server_t0,
    };
    let phases = vec![
        recorded.phase(phase1, 0, 0),
        recorded.phase(phase2, viewers, rendered),
    ];
    Ok(LoopBench::judge(station, seconds, phases))
}

/// A thread recording samples until it is stopped.
type Recorder<T> = JoinHandle<anyhow::Result<Vec<T>>>;

/// Sleeps a second for things to settle, then `seconds` measured: the measured span, in
/// seconds since `wall_t0`.
fn settle_then_wait(wall_t0: Instant, seconds: f64) -> (f64, f64) {
    std::thread::sleep(Duration::from_secs(1));
    let from = wall_t0.elapsed().as_secs_f64();
    std::thread::sleep(Duration::from_secs_f64(seconds));
    (from, wall_t0.elapsed().as_secs_f64())
}

/// The mock device playing `script` in a loop until `stop`: pose → force latencies as
/// (s since it started, latency s), once phase-locked.
pub(crate) fn spawn_device(
    station: &str,
    script: CutScript,
    stop: &Arc<AtomicBool>,
) -> anyhow::Result<Recorder<(f64, f64)>> {
    let station = station.to_string();
    let stop = stop.clone();
    Ok(std::thread::Builder::new()
        .name("bench-device".into())
        .spawn(move || -> anyhow::Result<Vec<(f64, f64)>> {
            let mut device = MockDevice::open(&station)?;
            let started = Instant::now();
            let mut latencies = Vec::new();
            device.run(
                &script,
                &MockOptions {
                    looping: true,
                    ..MockOptions::default()
                },
                &stop,
                |t| {
                    if let Some(l) = t.latency_s
                        && t.seq > scalpel_client::mock_device::PHASE_LOCK_AFTER
                    {
                        latencies.push((started.elapsed().as_secs_f64(), l));
                    }
                },
            )?;
            Ok(latencies)
        })?)
}

/// The measuring frame subscriber until `stop`: per frame (s since it started, pose →
/// received s, pose → stamped s).
fn spawn_subscriber(
    station: &str,
    stop: &Arc<AtomicBool>,
) -> anyhow::Result<Recorder<(f64, f64, f64)>> {
    let station = station.to_string();
    let stop = stop.clone();
    Ok(std::thread::Builder::new()
        .name("bench-frames".into())
        .spawn(move || -> anyhow::Result<Vec<(f64, f64, f64)>> {
            // A renderer's frame thread that wants frames promptly: real-time, below
            // the server's threads.
            scalpel_client::mock_device::make_fifo(50);
            let mut reader = FrameReader::open(&station)?;
            let started = Instant::now();
            let mut latencies = Vec::new();
            while !stop.load(Ordering::Relaxed) {
                if let Some(f) = reader.wait(Duration::from_millis(50))?
                    && f.header.pose_received_ns > 0
                    && f.received_ns > f.header.pose_received_ns
                {
                    let l = (f.received_ns - f.header.pose_received_ns) as f64 * 1e-9;
                    // Signed: the split must not filter the frames the total counts.
                    let stamped =
                        (f.header.server_time_ns as f64 - f.header.pose_received_ns as f64) * 1e-9;
                    latencies.push((started.elapsed().as_secs_f64(), l, stamped));
                }
            }
            Ok(latencies)
        })?)
}

/// `viewers` viewers that receive, decode and render every frame until `stop`; each
/// returns the frames it drew.
pub(crate) fn spawn_viewers(
    station: &str,
    viewers: usize,
    stop: &Arc<AtomicBool>,
) -> anyhow::Result<Vec<JoinHandle<anyhow::Result<u64>>>> {
    let mut viewer_threads = Vec::new();
    for v in 0..viewers {
        let station = station.to_string();
        let stop = stop.clone();
        viewer_threads.push(
            std::thread::Builder::new()
                .name(format!("bench-viewer-{v}"))
                .spawn(move || -> anyhow::Result<u64> {
                    let mut reader = FrameReader::open(&station)?;
                    let options = RenderOptions {
                        width: 480,
                        height: 360,
                        supersample: 1,
                        ..RenderOptions::default()
                    };
                    let mut drawn = 0;
                    while !stop.load(Ordering::Relaxed) {
                        if let Some(frame) = reader.wait(Duration::from_millis(50))? {
                            crate::view_cmd::draw(
                                &frame,
                                &crate::view_cmd::Orbit::default(),
                                &options,
                            )?;
                            drawn += 1;
                        }
                    }
                    Ok(drawn)
                })?,
        );
    }
    Ok(viewer_threads)
}

/// Waits for the viewers (stopped): the frames they drew in all.
pub(crate) fn join_viewers(viewers: Vec<JoinHandle<anyhow::Result<u64>>>) -> anyhow::Result<u64> {
    let mut rendered = 0;
    for v in viewers {
        rendered += v
            .join()
            .map_err(|_| anyhow::anyhow!("a viewer panicked"))??;
    }
    Ok(rendered)
}

/// What the device, the subscriber and the server recorded over both phases.
struct Recorded<'a> {
    device_latencies: Vec<(f64, f64)>,
    frame_latencies: Vec<(f64, f64, f64)>,
    device_offset: f64,
    lines: &'a [(f64, serde_json::Value)],
    server_t0: f64,
}

impl Recorded<'_> {
    /// The figures of the phase spanning `from..to` (s since wall_t0).
    fn phase(&self, (from, to): (f64, f64), viewers: usize, rendered: u64) -> Phase {
        let device_offset = self.device_offset;
        let within = |t: f64| t >= from - device_offset && t < to - device_offset;
        let force: Vec<f64> = self
            .device_latencies
            .iter()
            .filter(|(t, _)| within(*t))
            .map(|(_, l)| *l)
            .collect();
        let frames: Vec<&(f64, f64, f64)> = self
            .frame_latencies
            .iter()
            .filter(|(t, _, _)| within(*t))
            .collect();
        let frame: Vec<f64> = frames.iter().map(|(_, l, _)| *l).collect();
        let stamped: Vec<f64> = frames.iter().map(|(_, _, s)| *s).collect();
        let rest: Vec<f64> = frames.iter().map(|(_, l, s)| l - s).collect();
        // Status windows wholly inside the phase (a window ends at its line's uptime).
        let server_t0 = self.server_t0;
        let windows: Vec<&serde_json::Value> = self
            .lines
            .iter()
            .filter(|(t, _)| *t - server_t0 >= from + 1.0 && *t - server_t0 <= to + 1e-3)
            .map(|(_, v)| &v["haptic"])
            .collect();
        Phase {
            viewers,
            haptic: haptic_figures(&windows),
            pose_to_force_ms: quantiles(&force),
            pose_to_frame_ms: quantiles(&frame),
            pose_to_frame_stamped_ms: quantiles(&stamped),
            frame_stamped_to_received_ms: quantiles(&rest),
            frames_rendered_by_viewers: rendered,
        }
    }
}

/// The haptic figures of a phase from its status windows.
fn haptic_figures(windows: &[&serde_json::Value]) -> HapticFigures {
    let get = |w: &serde_json::Value, k: &str| w[k].as_f64().unwrap_or(f64::NAN);
    let mut p50s: Vec<f64> = windows.iter().map(|w| get(w, "jitter_p50_ms")).collect();
    p50s.sort_by(f64::total_cmp);
    let sum = |k: &str| -> u64 { windows.iter().map(|w| w[k].as_u64().unwrap_or(0)).sum() };
    HapticFigures {
        windows: windows.len(),
        ticks: sum("ticks"),
        ticks_late_over_0_1_ms: sum("ticks_late_over_0_1_ms"),
        jitter_p50_ms: p50s.get(p50s.len() / 2).copied().unwrap_or(f64::NAN),
        jitter_p99_ms: windows
            .iter()
            .map(|w| get(w, "jitter_p99_ms"))
            .fold(0.0, f64::max),
        jitter_p999_ms: windows
            .iter()
            .map(|w| get(w, "jitter_p999_ms"))
            .fold(0.0, f64::max),
        jitter_max_ms: windows
            .iter()
            .map(|w| get(w, "jitter_max_ms"))
            .fold(0.0, f64::max),
        deadline_misses: windows
            .iter()
            .map(|w| w["deadline_misses"].as_u64().unwrap_or(0))
            .sum(),
        rate_hz_min: windows
            .iter()
            .map(|w| get(w, "rate_hz"))
            .fold(f64::INFINITY, f64::min),
    }
}

impl LoopBench {
    /// The report of both phases, against the targets.
    fn judge(station: &str, seconds: f64, phases: Vec<Phase>) -> Self {
        // p99.9 ≤ 0.1 ms over the whole phase: at most one tick in a thousand 0.1 ms late.
        let jitter_p999_met = phases.iter().all(|p| {
            p.haptic.ticks > 0
                && p.haptic.ticks_late_over_0_1_ms * 1000 <= p.haptic.ticks
                && JITTER_P999_TARGET_MS >= 0.1
        });
        let pose_to_frame_p99_met = phases.iter().all(|p| {
            p.pose_to_frame_ms.n > 0 && p.pose_to_frame_ms.p99 <= POSE_TO_FRAME_P99_TARGET_MS
        });
        let viewers_add_no_misses =
            phases[1].haptic.deadline_misses <= phases[0].haptic.deadline_misses;
        LoopBench {
            station: station.to_string(),
            seconds_per_phase: seconds,
            haptic_cpu: None,
            phases,
            jitter_p999_target_ms: JITTER_P999_TARGET_MS,
            pose_to_frame_p99_target_ms: POSE_TO_FRAME_P99_TARGET_MS,
            jitter_p999_met,
            pose_to_frame_p99_met,
            viewers_add_no_misses,
        }
    }
}

fn print_report(r: &LoopBench) {
    println!(
        "station {}: {} s per phase, release server, SCHED_FIFO haptic thread{}, mock device phase-locked",
        r.station,
        r.seconds_per_phase,
        r.haptic_cpu
            .map_or(String::new(), |c| format!(" on CPU {c} (the rest off it)"))
    );
    for p in &r.phases {
        let h = &p.haptic;
        println!(
            "{} viewer(s): haptic jitter p50 {:.3} p99 {:.3} p99.9 {:.3} max {:.3} ms (worst one-second window), {} of {} ticks 0.1 ms late or more, {} deadline misses ({} windows, ≥ {:.1} Hz)",
            p.viewers,
            h.jitter_p50_ms,
            h.jitter_p99_ms,
            h.jitter_p999_ms,
            h.jitter_max_ms,
            h.ticks_late_over_0_1_ms,
            h.ticks,
            h.deadline_misses,
            h.windows,
            h.rate_hz_min
        );
        println!(
            "    pose → force at the device: p50 {:.3} p99 {:.3} max {:.3} ms (n {});  pose → frame received: p50 {:.3} p99 {:.3} max {:.3} ms (n {}){}",
            p.pose_to_force_ms.p50,
            p.pose_to_force_ms.p99,
            p.pose_to_force_ms.max,
            p.pose_to_force_ms.n,
            p.pose_to_frame_ms.p50,
            p.pose_to_frame_ms.p99,
            p.pose_to_frame_ms.max,
            p.pose_to_frame_ms.n,
            if p.viewers > 0 {
                format!("; viewers rendered {} frames", p.frames_rendered_by_viewers)
            } else {
                String::new()
            }
        );
        println!(
            "    of which pose → frame stamped by the simulation p50 {:.3} p99 {:.3} ms, stamped → received p50 {:.3} p99 {:.3} ms",
            p.pose_to_frame_stamped_ms.p50,
            p.pose_to_frame_stamped_ms.p99,
            p.frame_stamped_to_received_ms.p50,
            p.frame_stamped_to_received_ms.p99,
        );
    }
    println!(
        "targets: jitter p99.9 ≤ {:.3} ms {}; pose → frame p99 ≤ {:.3} ms {}; viewers add no deadline misses {}",
        r.jitter_p999_target_ms,
        if r.jitter_p999_met { "met" } else { "NOT met" },
        r.pose_to_frame_p99_target_ms,
        if r.pose_to_frame_p99_met {
            "met"
        } else {
            "NOT met"
        },
        if r.viewers_add_no_misses { "yes" } else { "NO" }
    );
}
