//! `scalpel bench stations [--seconds S] [--viewers N] [--threads T] [--scenes A,B,…]
//! [--mesh-units U] [--json]`: each station as a lab runs it (issue 42). For each scene the
//! release server (`scalpel-server`, beside this binary) runs on a station of its own with
//! a shared-memory device, the mock device loops the scene's default cut over shared memory
//! and N viewers receive, decode and render every frame; after S seconds the server's
//! summary gives the simulation's late ticks and tick-time quantiles and the haptic loop's
//! misses, and its status lines the haptic jitter.

use std::io::{BufRead, BufReader};
use std::path::Path;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

use anyhow::{Context, bail};
use scalpel_sim::geometry::import::MeshFormat;
use scalpel_sim::pipeline::CutScript;
use scalpel_sim::scene::Features;
use serde::Serialize;

use super::loop_bench::{join_viewers, spawn_device, spawn_server, spawn_viewers};

/// Seconds a station runs before it is measured (its build, the device's phase lock).
const SETTLE_S: f64 = 3.0;

/// Issue 42's targets.
const JITTER_P999_TARGET_MS: f64 = 0.100;

/// One station's figures.
#[derive(Debug, Serialize)]
struct StationRow {
    scene: String,
    points: usize,
    sim_threads: usize,
    seconds: f64,
    sim_ticks: u64,
    sim_late_ticks: u64,
    /// Of those, the ones over a tick of the simulation thread's CPU time.
    sim_late_ticks_cpu: u64,
    /// Simulated time behind the wall clock at the end (%).
    sim_behind_pct: f64,
    /// The simulation tick's wall time over the whole run (ms; bins of 0.02 ms; `None`
    /// beyond 5.1 ms).
    sim_tick_p50_ms: Option<f64>,
    sim_tick_p99_ms: Option<f64>,
    sim_tick_p999_ms: Option<f64>,
    sim_tick_max_ms: f64,
    most_substeps: u64,
    /// Ticks that shared their work with the simulation's worker.
    shared_ticks: u64,
    haptic_ticks: u64,
    haptic_misses: u64,
    /// Largest p99.9 of the haptic wake-up jitter over the measured status windows.
    haptic_jitter_p999_ms: f64,
    frames_rendered_by_viewers: u64,
    zero_late_ticks: bool,
    jitter_met: bool,
}

#[derive(Debug, Serialize)]
struct StationsBench {
    viewers: usize,
    rows: Vec<StationRow>,
    jitter_p999_target_ms: f64,
}

/// What to run.
pub struct StationsArgs<'a> {
    pub seconds: f64,
    pub viewers: usize,
    pub threads: usize,
    pub scenes: &'a [String],
    pub mesh_units: &'a str,
    pub json: bool,
}

/// Runs the benchmark.
pub fn run(args: &StationsArgs<'_>) -> anyhow::Result<()> {
    if !(args.seconds.is_finite() && (2.0..=3600.0).contains(&args.seconds)) {
        bail!("--seconds must be between 2 and 3600, got {}", args.seconds);
    }
    if args.viewers > 7 {
        bail!("--viewers: at most 7 (the frame service takes 8 subscribers)");
    }
    if args.scenes.is_empty() {
        bail!("--scenes: no scene given");
    }
    scalpel_proto::shm::quiet_logging();
    let mut rows = Vec::new();
    for (k, scene) in args.scenes.iter().enumerate() {
        let station = format!("bench-stations-{}-{k}", std::process::id());
        let dir = std::env::temp_dir().join(&station);
        std::fs::create_dir_all(&dir)?;
        let row = scene_file_for(scene, args.mesh_units, &dir)
            .and_then(|scene_ref| run_station(&station, scene, &scene_ref, &dir, args));
        std::fs::remove_dir_all(&dir).ok();
        let mut row = row.with_context(|| format!("station on {scene}"))?;
        // A mesh file by its name.
        if let Some(stem) = Path::new(scene).file_stem().filter(|_| scene.contains('/')) {
            row.scene = stem.to_string_lossy().to_string();
        }
        rows.push(row);
    }
    let report = StationsBench {
        viewers: args.viewers,
        rows,
        jitter_p999_target_ms: JITTER_P999_TARGET_MS,
    };
    super::emit(args.json, &report, print_report)
}

/// What the server's `scene` key takes for `scene`: a built-in name or a scene file as
/// given, a mesh file through a scene file written into `dir`.
fn scene_file_for(scene: &str, units: &str, dir: &Path) -> anyhow::Result<String> {
    if MeshFormat::from_file_name(scene).is_err() {
        return Ok(scene.to_string());
    }
    let mesh = std::fs::canonicalize(scene).with_context(|| {
        format!("{scene}: no such mesh file (is ../shared beside the project?)")
    })?;
    let name = Path::new(scene)
        .file_stem()
        .map_or("mesh".into(), |s| s.to_string_lossy().to_string());
    // A cutting station's features, as the built-in organs have them.
    let features: String = Features::CUTTING_STATION
        .enabled()
        .iter()
        .map(|f| format!("{f} = true\n"))
        .collect();
    let file = dir.join("scene.toml");
    std::fs::write(
        &file,
        format!(
            "name = {}\n[mesh]\nfile = {}\nunits = \"{units}\"\n[features]\n{features}",
            toml_string(&name),
            toml_string(&mesh.to_string_lossy())
        ),
    )?;
    Ok(file.to_string_lossy().to_string())
}

/// `text` as a TOML basic string (a JSON string is one).
fn toml_string(text: &str) -> String {
    serde_json::Value::String(text.to_string()).to_string()
}

/// One station for `args.seconds` after it settled.
fn run_station(
    station: &str,
    scene: &str,
    scene_ref: &str,
    dir: &Path,
    args: &StationsArgs<'_>,
) -> anyhow::Result<StationRow> {
    let built = scalpel_server::scene_file::load_scene(scene_ref)?;
    let script = CutScript::default_for(&scalpel_sim::pipeline::start_surface(&built))?;
    let config = dir.join("server.toml");
    std::fs::write(
        &config,
        format!(
            "station = \"{station}\"\nscene = {}\n[device]\nkind = \"shared_memory\"\n[rates]\nstatus_interval_s = 1.0\nframe_hz = 60.0\n[realtime]\nsim_threads = {}\n",
            toml_string(scene_ref),
            args.threads
        ),
    )?;
    // Stopped by a signal once measured (its `--duration` counts its build too); the
    // duration is only a backstop.
    let (mut server, stdout) = spawn_server(&config, args.seconds + SETTLE_S + 600.0)?;
    let (lines_tx, lines_rx) = std::sync::mpsc::channel::<serde_json::Value>();
    let reader = std::thread::spawn(move || {
        for line in BufReader::new(stdout).lines().map_while(Result::ok) {
            if let Ok(v) = serde_json::from_str::<serde_json::Value>(&line) {
                let _ = lines_tx.send(v);
            }
        }
    });
    // The first status line: the station runs.
    let first = lines_rx
        .iter()
        .find(|v| v.get("haptic").is_some())
        .context("the server ended before its first status line")?;
    let start_uptime = first["uptime_s"].as_f64().unwrap_or(0.0);
    let stop = Arc::new(AtomicBool::new(false));
    let device = spawn_device(station, script, &stop)?;
    let viewer_stop = Arc::new(AtomicBool::new(false));
    let viewers = spawn_viewers(station, args.viewers, &viewer_stop)?;
    let mut windows = Vec::new();
    let mut summary = None;
    let mut stopping = false;
    for v in lines_rx.iter() {
        if v.get("state_hash").is_some() {
            summary = Some(v);
            break;
        }
        let t = v["uptime_s"].as_f64().unwrap_or(0.0);
        if v.get("haptic").is_some() && t >= start_uptime + SETTLE_S && !stopping {
            windows.push(v["haptic"].clone());
        }
        if t >= start_uptime + SETTLE_S + args.seconds && !stopping {
            // SIGTERM: the server stops and prints its summary.
            stopping = true;
            std::process::Command::new("kill")
                .args(["-TERM", &server.id().to_string()])
                .status()
                .context("kill -TERM the server")?;
        }
    }
    viewer_stop.store(true, Ordering::Relaxed);
    stop.store(true, Ordering::Relaxed);
    let rendered = join_viewers(viewers)?;
    let _ = device.join();
    wait_or_kill(&mut server, Duration::from_secs(10));
    let _ = reader.join();
    let summary = summary.context("the server printed no summary")?;
    Ok(row_of(
        scene,
        built.model.points.len(),
        args,
        &summary,
        &windows,
        rendered,
    ))
}

/// Waits up to `timeout` for `child` to end (it stops at its duration), then kills it.
fn wait_or_kill(child: &mut std::process::Child, timeout: Duration) {
    let until = std::time::Instant::now() + timeout;
    while std::time::Instant::now() < until {
        if matches!(child.try_wait(), Ok(Some(_))) {
            return;
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    let _ = child.kill();
    let _ = child.wait();
}

/// The row of a station from its summary and its measured status windows.
fn row_of(
    scene: &str,
    points: usize,
    args: &StationsArgs<'_>,
    summary: &serde_json::Value,
    windows: &[serde_json::Value],
    rendered: u64,
) -> StationRow {
    let sim = &summary["sim"];
    let u = |v: &serde_json::Value| v.as_u64().unwrap_or(0);
    let f = |v: &serde_json::Value| v.as_f64().unwrap_or(f64::NAN);
    let (sim_ticks, haptic_ticks) = (u(&sim["ticks"]), u(&summary["haptic_ticks"]));
    let late = u(&sim["late_ticks"]);
    let misses = u(&summary["deadline_misses"]);
    let jitter = windows
        .iter()
        .map(|w| f(&w["jitter_p999_ms"]))
        .fold(0.0, f64::max);
    StationRow {
        scene: scene.to_string(),
        points,
        sim_threads: args.threads,
        seconds: args.seconds,
        sim_ticks,
        sim_late_ticks: late,
        sim_late_ticks_cpu: u(&sim["late_ticks_cpu"]),
        sim_behind_pct: if haptic_ticks > 0 {
            100.0 * (1.0 - sim_ticks as f64 / haptic_ticks as f64)
        } else {
            f64::NAN
        },
        sim_tick_p50_ms: sim["tick_times"]["p50_ms"].as_f64(),
        sim_tick_p99_ms: sim["tick_times"]["p99_ms"].as_f64(),
        sim_tick_p999_ms: sim["tick_times"]["p999_ms"].as_f64(),
        sim_tick_max_ms: f(&sim["max_tick_ms"]),
        most_substeps: u(&sim["most_substeps"]),
        shared_ticks: u(&sim["shared_ticks"]),
        haptic_ticks,
        haptic_misses: misses,
        haptic_jitter_p999_ms: jitter,
        frames_rendered_by_viewers: rendered,
        zero_late_ticks: late == 0,
        jitter_met: jitter <= JITTER_P999_TARGET_MS,
    }
}

fn print_report(r: &StationsBench) {
    let ms = |v: Option<f64>| v.map_or("> 5.1".to_string(), |v| format!("{v:.2}"));
    println!(
        "stations, {} viewer(s) each (simulation tick p50 / p99 / p99.9 in ms, bins of 0.02 ms):",
        r.viewers
    );
    for s in &r.rows {
        println!(
            "  {:<12} {:>5} points, {} thread(s), {:.0} s: sim {} ticks, {} late ({} over a tick of CPU), {:.1} % behind, tick {} / {} / {} (max {:.2}), ≤ {} sub-steps; haptic {} ticks, {} misses, jitter p99.9 {:.3} ms; viewers drew {} frames{}",
            s.scene,
            s.points,
            s.sim_threads,
            s.seconds,
            s.sim_ticks,
            s.sim_late_ticks,
            s.sim_late_ticks_cpu,
            s.sim_behind_pct,
            ms(s.sim_tick_p50_ms),
            ms(s.sim_tick_p99_ms),
            ms(s.sim_tick_p999_ms),
            s.sim_tick_max_ms,
            s.most_substeps,
            s.haptic_ticks,
            s.haptic_misses,
            s.haptic_jitter_p999_ms,
            s.frames_rendered_by_viewers,
            if s.zero_late_ticks && s.jitter_met {
                ""
            } else {
                "  ✘ (targets: 0 late ticks, jitter p99.9 ≤ 0.1 ms)"
            }
        );
    }
}
