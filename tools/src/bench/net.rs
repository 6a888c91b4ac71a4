//! `scalpel bench net [--seconds S] [--observers N] [--scene NAME] [--json]`: remote
//! observers over real QUIC with TLS on loopback. Starts the release server (beside this
//! binary) with the QUIC endpoint on a lab made for the run, the in-process scripted device
//! cutting the scene in a loop (topology changes, so keyframes: the costly case) and render
//! frames at 60 Hz. Two phases of S seconds: no observers, then N observers subscribed at
//! 30 Hz. Reports the observers' frame latency (the server's CLOCK_MONOTONIC when the
//! simulation wrote the frame → decoded by the observer), the bytes per second each
//! observer receives (UDP payloads, from quinn's connection statistics), frames per second,
//! and the haptic loop's deadline misses in each phase (from the server's status lines).

use std::io::{BufRead, BufReader};
use std::net::SocketAddr;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::Receiver;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use anyhow::{Context, bail};
use scalpel_client::remote::{Credentials, Observer, Update};
use serde::Serialize;

use crate::mock_cmd::quantiles_ms;

/// Targets of issue 6.
const LATENCY_P99_TARGET_MS: f64 = 5.0;
/// See [`LATENCY_P99_TARGET_MS`].
const BYTES_PER_S_TARGET: f64 = 1e6;

#[derive(Debug, Serialize)]
struct Latency {
    n: usize,
    p50: f64,
    p99: f64,
    max: f64,
}

#[derive(Debug, Serialize)]
struct NetBench {
    scene: String,
    seconds_per_phase: f64,
    observers: usize,
    /// Frame latency over every observer's frames of the second phase (ms).
    frame_latency_ms: Latency,
    /// Bytes received per observer per second: the mean and the largest over observers.
    bytes_per_s_mean: f64,
    bytes_per_s_max: f64,
    /// Frames decoded per observer per second (mean).
    frames_per_s_mean: f64,
    /// Keyframes among them (a topology change or once a second).
    keyframe_share: f64,
    /// Haptic deadline misses in the phase without observers and in the phase with them.
    deadline_misses_without: u64,
    deadline_misses_with: u64,
    /// Haptic ticks in each phase (for the misses' share).
    haptic_ticks_without: u64,
    haptic_ticks_with: u64,
    latency_p99_target_ms: f64,
    bytes_per_s_target: f64,
    latency_p99_met: bool,
    bytes_per_s_met: bool,
    observers_add_no_misses: bool,
}

/// One observer's record of the measured phase.
#[derive(Debug, Default)]
struct Record {
    latencies_s: Vec<f64>,
    frames: u64,
    keyframes: u64,
    bytes: u64,
}

/// Status lines of the server as (arrival, s since the bench started; haptic window).
type Lines = Arc<Mutex<Vec<(f64, serde_json::Value)>>>;

/// Runs the benchmark.
pub fn run(seconds: f64, observers: usize, scene: &str, json: bool) -> anyhow::Result<()> {
    if !(seconds.is_finite() && (2.0..=3600.0).contains(&seconds)) {
        bail!("--seconds must be between 2 and 3600, got {seconds}");
    }
    if !(1..=64).contains(&observers) {
        bail!("--observers must be between 1 and 64, got {observers}");
    }
    let station = format!("bench-net-{}", std::process::id());
    let dir = std::env::temp_dir().join(&station);
    std::fs::create_dir_all(&dir)?;
    let result = (|| {
        crate::certs_cmd::init(&dir, &[])?;
        crate::certs_cmd::issue(&dir, "observer", "bench")?;
        let scene_file = dir.join("scene.toml");
        std::fs::write(
            &scene_file,
            format!("extends = \"{scene}\"\n[features]\nobservers = true\n"),
        )?;
        // The haptic thread on the last CPU, alone: the server's network threads and the
        // observers (this process) on the others.
        let haptic_cpu = scalpel_server::realtime::allowed_cpus()
            .last()
            .map_or(-1, |&c| c as i64);
        let config = dir.join("server.toml");
        std::fs::write(
            &config,
            format!(
                "station = \"{station}\"\nscene = \"{}\"\n[device]\nkind = \"scripted\"\nloop_script = true\n[rates]\nstatus_interval_s = 1.0\nframe_hz = 60.0\n[realtime]\nhaptic_cpu = {haptic_cpu}\n[network]\nlisten = \"127.0.0.1:0\"\ncerts = \"{}\"\nframe_hz = 30.0\nmax_connections = {}\nmax_per_address = {}\n",
                scene_file.display(),
                dir.display(),
                observers + 4,
                observers + 4,
            ),
        )?;
        measure(&config, scene, &dir, seconds, observers)
    })();
    std::fs::remove_dir_all(&dir).ok();
    super::emit(json, &result?, print_report)
}

fn measure(
    config: &std::path::Path,
    scene: &str,
    dir: &std::path::Path,
    seconds: f64,
    observers: usize,
) -> anyhow::Result<NetBench> {
    let total = 2.0 * seconds + 30.0;
    let started = Instant::now();
    let (mut server, stdout) = super::loop_bench::spawn_server(config, total)?;
    let lines: Lines = Arc::default();
    let endpoint = spawn_status_reader(stdout, &lines, started);
    let records: Vec<Arc<Mutex<Record>>> = (0..observers).map(|_| Arc::default()).collect();
    let result = (|| {
        let addr = endpoint
            .recv_timeout(Duration::from_secs(120))
            .context("the server did not report its network endpoint")?;
        // Let the cut start, then phase 1 without observers.
        std::thread::sleep(Duration::from_secs(3));
        let phase1 = (started.elapsed().as_secs_f64(), seconds);
        std::thread::sleep(Duration::from_secs_f64(seconds));
        // Phase 2: the observers connect, settle for a second, and are measured. They
        // stand for machines elsewhere in the lab: they keep off the server's haptic CPU
        // (the last one; the server keeps its own network threads off it too).
        keep_off_the_haptic_cpu();
        let phase2 = observe(addr, dir, &records, started, seconds)?;
        // One more status line covering the end of phase 2.
        wait_for_one_more_line(&lines, started, total);
        anyhow::Ok((phase1, phase2))
    })();
    let _ = server.kill();
    let _ = server.wait();
    let (phase1, phase2) = result?;
    let lines = lines.lock().map_err(|_| anyhow::anyhow!("poisoned"))?;
    let recorded = Recorded {
        lines: &lines,
        records: records
            .iter()
            .map(|r| std::mem::take(&mut *r.lock().unwrap_or_else(|e| e.into_inner())))
            .collect(),
    };
    Ok(NetBench::judge(
        scene,
        seconds,
        observers,
        &recorded,
        [phase1, phase2],
    ))
}

/// Reads the server's stdout until it closes: sends the QUIC endpoint's address once it is
/// reported, and keeps the status lines' haptic windows in `lines`.
fn spawn_status_reader(
    stdout: std::process::ChildStdout,
    lines: &Lines,
    started: Instant,
) -> Receiver<SocketAddr> {
    let (addr_tx, addr_rx) = std::sync::mpsc::channel();
    let lines = lines.clone();
    std::thread::spawn(move || {
        for line in BufReader::new(stdout).lines().map_while(Result::ok) {
            let v: serde_json::Value = serde_json::from_str(&line).unwrap_or_default();
            if let Some(addr) = v["event"]
                .as_str()
                .and_then(|e| e.split("network endpoint on ").nth(1))
                .and_then(|s| s.split([',', ';']).next())
                .and_then(|s| s.trim().parse::<SocketAddr>().ok())
            {
                let _ = addr_tx.send(addr);
            }
            if v.get("haptic").is_some()
                && let Ok(mut l) = lines.lock()
            {
                l.push((started.elapsed().as_secs_f64(), v["haptic"].clone()));
            }
        }
    });
    addr_rx
}

/// Pins this thread (and so the observers' runtime) to every allowed CPU but the last, the
/// server's haptic CPU, when there are others.
fn keep_off_the_haptic_cpu() {
    let cpus = scalpel_server::realtime::allowed_cpus();
    if let Some((_, others)) = cpus.split_last()
        && !others.is_empty()
    {
        let _ = scalpel_server::realtime::pin_thread(others);
    }
}

/// Phase 2 on a runtime of its own: one observer per record connects and subscribes at
/// 30 Hz, a second to settle, then `seconds` measured; the measured span (from, length).
fn observe(
    addr: SocketAddr,
    dir: &std::path::Path,
    records: &[Arc<Mutex<Record>>],
    started: Instant,
    seconds: f64,
) -> anyhow::Result<(f64, f64)> {
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()?;
    runtime.block_on(async {
        let credentials = Credentials::from_dir(dir, "bench");
        let mut tasks = Vec::new();
        let measuring = Arc::new(AtomicBool::new(false));
        for (k, record) in records.iter().enumerate() {
            let mut o = Observer::connect(addr, "localhost", &credentials, &format!("bench-{k}"))
                .await
                .with_context(|| format!("observer {k} cannot connect"))?;
            o.0.subscribe(30.0).await?;
            tasks.push(spawn_observer(o, record, &measuring));
        }
        tokio::time::sleep(Duration::from_secs(1)).await;
        measuring.store(true, Ordering::Relaxed);
        let from = started.elapsed().as_secs_f64();
        tokio::time::sleep(Duration::from_secs_f64(seconds)).await;
        for t in &tasks {
            t.abort();
        }
        anyhow::Ok((from, seconds))
    })
}

/// An observer's task until aborted: once `measuring`, counts its frames, keyframes, frame
/// latencies and bytes received into `record`.
fn spawn_observer(
    mut o: Observer,
    record: &Arc<Mutex<Record>>,
    measuring: &Arc<AtomicBool>,
) -> tokio::task::JoinHandle<()> {
    let (record, measuring) = (record.clone(), measuring.clone());
    tokio::spawn(async move {
        let mut counting_from = None;
        while let Some(update) = o.0.next().await {
            let on = measuring.load(Ordering::Relaxed);
            if on && counting_from.is_none() {
                counting_from = Some(o.0.bytes_received());
            }
            if let (true, Update::Frame(f)) = (on, update) {
                let now = scalpel_client::frame_reader::monotonic_ns();
                let mut r = record.lock().unwrap_or_else(|e| e.into_inner());
                r.frames += 1;
                r.keyframes += u64::from(f.keyframe);
                if f.server_time_ns > 0 && now > f.server_time_ns {
                    r.latencies_s.push((now - f.server_time_ns) as f64 * 1e-9);
                }
                r.bytes = o.0.bytes_received() - counting_from.unwrap_or(0);
            }
        }
    })
}

/// Waits for a status line that arrives a second or more from now, or until `total` s
/// after `started`.
fn wait_for_one_more_line(lines: &Lines, started: Instant, total: f64) {
    let last_line = || lines.lock().map_or(0.0, |l| l.last().map_or(0.0, |x| x.0));
    let want = started.elapsed().as_secs_f64() + 1.0;
    while last_line() < want && started.elapsed().as_secs_f64() < total {
        std::thread::sleep(Duration::from_millis(100));
    }
}

/// What the server's status lines and the observers recorded over both phases.
struct Recorded<'a> {
    lines: &'a [(f64, serde_json::Value)],
    records: Vec<Record>,
}

impl Recorded<'_> {
    /// Haptic deadline misses and ticks of the phase spanning `from` for `len` s: the
    /// one-second status windows wholly inside it (a line arrives as its window ends; 50 ms
    /// of slack for the printing).
    fn haptic(&self, (from, len): (f64, f64)) -> (u64, u64) {
        let windows: Vec<&serde_json::Value> = self
            .lines
            .iter()
            .filter(|(t, _)| *t - 1.0 >= from - 0.05 && *t <= from + len + 0.05)
            .map(|(_, w)| w)
            .collect();
        let sum = |k: &str| {
            windows
                .iter()
                .map(|w| w[k].as_u64().unwrap_or(0))
                .sum::<u64>()
        };
        (sum("deadline_misses"), sum("ticks"))
    }
}

impl NetBench {
    /// The report of both phases (without observers, with them), against the targets.
    fn judge(
        scene: &str,
        seconds: f64,
        observers: usize,
        recorded: &Recorded<'_>,
        [phase1, phase2]: [(f64, f64); 2],
    ) -> Self {
        let (misses_without, ticks_without) = recorded.haptic(phase1);
        let (misses_with, ticks_with) = recorded.haptic(phase2);
        let records = &recorded.records;
        let latencies: Vec<f64> = records.iter().flat_map(|r| r.latencies_s.clone()).collect();
        let (p50, p99, max) = quantiles_ms(&latencies).unwrap_or((f64::NAN, f64::NAN, f64::NAN));
        let per_s = |x: u64| x as f64 / phase2.1;
        let bytes: Vec<f64> = records.iter().map(|r| per_s(r.bytes)).collect();
        let frames: u64 = records.iter().map(|r| r.frames).sum();
        let keyframes: u64 = records.iter().map(|r| r.keyframes).sum();
        let bytes_per_s_mean = bytes.iter().sum::<f64>() / bytes.len() as f64;
        let bytes_per_s_max = bytes.iter().copied().fold(0.0, f64::max);
        NetBench {
            scene: scene.to_string(),
            seconds_per_phase: seconds,
            observers,
            frame_latency_ms: Latency {
                n: latencies.len(),
                p50,
                p99,
                max,
            },
            bytes_per_s_mean,
            bytes_per_s_max,
            frames_per_s_mean: per_s(frames) / observers as f64,
            keyframe_share: keyframes as f64 / frames.max(1) as f64,
            deadline_misses_without: misses_without,
            deadline_misses_with: misses_with,
            haptic_ticks_without: ticks_without,
            haptic_ticks_with: ticks_with,
            latency_p99_target_ms: LATENCY_P99_TARGET_MS,
            bytes_per_s_target: BYTES_PER_S_TARGET,
            latency_p99_met: !latencies.is_empty() && p99 <= LATENCY_P99_TARGET_MS,
            bytes_per_s_met: bytes_per_s_max <= BYTES_PER_S_TARGET,
            // Only when both phases had status windows to count in.
            observers_add_no_misses: ticks_without > 0
                && ticks_with > 0
                && misses_with <= misses_without,
        }
    }
}

fn print_report(r: &NetBench) {
    println!(
        "scene {}: {} observers at 30 Hz over QUIC on loopback, {} s per phase (release server, scripted device cutting in a loop)",
        r.scene, r.observers, r.seconds_per_phase
    );
    println!(
        "frame latency (written by the simulation → decoded by an observer): p50 {:.3} p99 {:.3} max {:.3} ms (n {})",
        r.frame_latency_ms.p50,
        r.frame_latency_ms.p99,
        r.frame_latency_ms.max,
        r.frame_latency_ms.n
    );
    println!(
        "per observer: {:.0} B/s mean, {:.0} B/s largest; {:.1} frames/s ({:.0} % keyframes)",
        r.bytes_per_s_mean,
        r.bytes_per_s_max,
        r.frames_per_s_mean,
        100.0 * r.keyframe_share
    );
    println!(
        "haptic deadline misses: {} in {} ticks without observers, {} in {} ticks with them",
        r.deadline_misses_without,
        r.haptic_ticks_without,
        r.deadline_misses_with,
        r.haptic_ticks_with
    );
    let met = |b: bool| if b { "met" } else { "NOT met" };
    println!(
        "targets: latency p99 ≤ {} ms {}; ≤ {:.0} B/s per observer {}; observers add no deadline misses {}",
        r.latency_p99_target_ms,
        met(r.latency_p99_met),
        r.bytes_per_s_target,
        met(r.bytes_per_s_met),
        if r.observers_add_no_misses {
            "yes"
        } else {
            "NO"
        }
    );
}
