//! `scalpel-server [CONFIG] [--duration S] [--json]`: runs a station. With no CONFIG it runs
//! the embedded default: the built-in liver, an in-process scripted device performing the
//! demo cut, a status line once a second.

use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

use anyhow::Context;
use clap::Parser;
use scalpel_server::config::{DeviceKind, ServerConfig};
use scalpel_server::device::{DeviceFactory, HapticDevice, ScriptedDevice};
use scalpel_server::output::OutputLimits;
use scalpel_server::scene_budget::SceneBudget;
use scalpel_server::shm_device::{DeviceGate, ShmDevice, ShmDeviceCounters};
use scalpel_server::station::{self, StationParams, StationReport, StatusLine};
use scalpel_server::{host_check, journal, say, scene_file};
use scalpel_sim::pipeline::CutScript;

#[derive(Parser)]
#[command(
    version,
    about = "scalpel station server: simulation and 1 kHz haptic loop"
)]
struct Args {
    /// Server configuration (TOML, docs/SERVER.md); none runs the embedded default.
    config: Option<PathBuf>,
    /// Stop after this many seconds (default: run until Ctrl-C).
    #[arg(long)]
    duration: Option<f64>,
    /// Status lines and the summary as JSON, one object per line.
    #[arg(long)]
    json: bool,
    /// Write every input the simulation uses to FILE (replay it with `scalpel replay`).
    #[arg(long, value_name = "FILE")]
    journal: Option<PathBuf>,
    /// Check this host and configuration for the station (real-time limits, the scene, the
    /// station name, shared memory, the network endpoint) and exit: 0 if it can run, 1 if
    /// something would stop it.
    #[arg(long, conflicts_with_all = ["duration", "journal"])]
    check: bool,
    /// With --check: leave out timing the scene's simulation (2 s), for a check before
    /// every start (the lab's systemd unit) where only what would stop the station counts.
    #[arg(long, requires = "check")]
    no_timing: bool,
}

/// The longest `--duration` (s): a year.
const MAX_DURATION_S: f64 = 3.2e7;

fn main() {
    if let Err(e) = run() {
        scalpel_server::console::error(format_args!("{e:#}"));
        std::process::exit(1);
    }
}

fn run() -> anyhow::Result<()> {
    let args = Args::parse();
    let config = match &args.config {
        Some(path) => ServerConfig::load(path)?,
        None => ServerConfig::default(),
    };
    if let Some(d) = args.duration
        && !(d > 0.0 && d <= MAX_DURATION_S)
    {
        anyhow::bail!(
            "--duration must be above 0 and at most {MAX_DURATION_S:e} s (a year), got {}",
            scalpel_sim::scene::file::readable_number(d)
        );
    }
    scalpel_proto::shm::quiet_logging();
    if args.check {
        return check_host(&config, !args.no_timing, args.json);
    }
    let stop = stop_on_signals_and_duration(args.duration)?;
    let (scene, sim, cutting_note) =
        build_scene_unless_stopped(&config.scene, SceneBudget::station(&config.limits), &stop)?;
    let shm = Arc::new(ShmDeviceCounters::default());
    let device_gate = Arc::new(DeviceGate::default());
    let device = device_factory(&config, &scene, &shm, &device_gate)?;
    let params = station_params(&config, &scene, device_gate)?;
    if !args.json {
        say_start(&config, &scene, &params, cutting_note.as_deref());
    }
    let journal = open_journal(args.journal.as_deref(), &config)?;
    let json = args.json;
    let mut notes = DeviceNotes::default();
    let summary = station::run(&scene, sim, device, &params, journal, stop, |report| {
        print_report(report, json);
        if let StationReport::Status(line) = report {
            notes.say_new(&shm, line.uptime_s, json);
        }
    })?;
    print_summary(&summary, params.monitor_device.then_some(&*shm), json)?;
    if summary.sim.ticks == 0 {
        anyhow::bail!(
            "the station stopped before its first simulation tick: it did no work (a stop or the end of --duration during its start)"
        );
    }
    Ok(())
}

/// A stop flag set by SIGINT, SIGTERM, SIGHUP or the end of `duration` (s), from now on —
/// while the scene builds too.
fn stop_on_signals_and_duration(duration: Option<f64>) -> anyhow::Result<Arc<AtomicBool>> {
    let stop = Arc::new(AtomicBool::new(false));
    let on_signal = stop.clone();
    ctrlc::set_handler(move || on_signal.store(true, Ordering::Relaxed))
        .context("cannot install the signal handler")?;
    if let Some(d) = duration {
        let d = std::time::Duration::try_from_secs_f64(d)
            .map_err(|e| anyhow::anyhow!("--duration {d}: {e}"))?;
        let timer = stop.clone();
        std::thread::spawn(move || {
            std::thread::sleep(d);
            timer.store(true, Ordering::Relaxed);
        });
    }
    Ok(stop)
}

/// How the haptic thread makes its device: the scripted one playing the configured script
/// (or the scene's demo cut), or the shared-memory one.
fn device_factory(
    config: &ServerConfig,
    scene: &scalpel_sim::scene::BuiltScene,
    shm: &Arc<ShmDeviceCounters>,
    gate: &Arc<DeviceGate>,
) -> anyhow::Result<DeviceFactory> {
    Ok(match (&config.device.kind, config.device.script.as_str()) {
        (DeviceKind::Scripted, script) => {
            let script = if script.is_empty() {
                CutScript::default_for(&scalpel_sim::pipeline::start_surface(scene))
                    .context("the scene has no place for the demo cut")?
            } else {
                scene_file::load_script(std::path::Path::new(script))?
            };
            let looping = config.device.loop_script;
            Box::new(move || {
                Ok(Box::new(ScriptedDevice::new(script, looping)) as Box<dyn HapticDevice>)
            })
        }
        (DeviceKind::SharedMemory, _) => {
            let (station, counters, gate) = (config.station.clone(), shm.clone(), gate.clone());
            Box::new(move || {
                Ok(Box::new(ShmDevice::open(&station, counters, gate)?) as Box<dyn HapticDevice>)
            })
        }
    })
}

/// The station's parameters from its configuration and scene.
fn station_params(
    config: &ServerConfig,
    scene: &scalpel_sim::scene::BuiltScene,
    device_gate: Arc<DeviceGate>,
) -> anyhow::Result<StationParams> {
    let o = &config.output;
    let lesson = lesson_plan(config, scene)?;
    Ok(StationParams {
        haptic_hz: config.rates.haptic_hz,
        fifo_priority: config.realtime.fifo_priority,
        sim_fifo_priority: config.realtime.sim_fifo_priority,
        lock_memory: config.realtime.lock_memory,
        haptic_cpu: usize::try_from(config.realtime.haptic_cpu).ok(),
        sim_threads: config.realtime.sim_threads as usize,
        sim_nice: config.realtime.sim_nice,
        limits: OutputLimits {
            // Both are range-checked; the bound holds for built-in scenes too.
            max_force_n: if o.max_force_n > 0.0 {
                o.max_force_n
            } else {
                scene.spec.force.max_force_n
            }
            .min(scalpel_sim::scene::file::MAX_DEVICE_FORCE_N),
            rate_limit_n_per_ms: o.rate_limit_n_per_ms,
            device_timeout_s: o.device_timeout_ms * 1e-3,
            sim_timeout_s: o.sim_timeout_ms * 1e-3,
            fade_out_s: o.fade_out_ms * 1e-3,
            fade_in_s: o.fade_in_ms * 1e-3,
            passivity: o.passivity,
            passivity_memory_s: if o.passivity_memory_ms > 0.0 {
                o.passivity_memory_ms * 1e-3
            } else {
                f64::INFINITY
            },
            period_s: 1.0 / config.rates.haptic_hz,
            max_stiffness_n_per_m: o.max_stiffness_n_per_m,
        },
        status_interval_s: config.rates.status_interval_s,
        station: config.station.clone(),
        frame_hz: if scene.spec.features.frames {
            config.rates.frame_hz
        } else {
            0.0
        },
        monitor_device: config.device.kind == DeviceKind::SharedMemory,
        device_gate,
        haptics: scene.spec.features.haptics,
        network: network_params(config, scene, lesson.as_ref())?,
        lesson,
    })
}

/// The station's lesson laid on its scene (checked with the configuration; laid here on
/// the scene as built).
fn lesson_plan(
    config: &ServerConfig,
    scene: &scalpel_sim::scene::BuiltScene,
) -> anyhow::Result<Option<scalpel_sim::lesson::Plan>> {
    if config.lesson.is_empty() {
        return Ok(None);
    }
    let spec = scene_file::load_lesson(&config.lesson)?;
    Ok(Some(scalpel_sim::lesson::Plan::new(
        spec,
        &scene.model.surface,
        &config.lesson,
    )?))
}

/// The station's first lines: what runs, and what the scene's loading noted.
fn say_start(
    config: &ServerConfig,
    scene: &scalpel_sim::scene::BuiltScene,
    params: &StationParams,
    cutting_note: Option<&str>,
) {
    say!(
        "station {}: scene {} ({} points), {}, frames {} Hz",
        config.station,
        scene.spec.name,
        scene.model.points.len(),
        match (params.haptics, params.monitor_device) {
            (false, _) => "no haptics".to_string(),
            (true, true) => format!("shared-memory device, haptic {} Hz", params.haptic_hz),
            (true, false) => format!("scripted device, haptic {} Hz", params.haptic_hz),
        },
        params.frame_hz
    );
    if let Some(note) = cutting_note {
        say!("  scene: {note}");
    }
    // Repairs of the surface, and a scan remeshed on loading, said once.
    for w in &scene.mesh_warnings {
        say!("  mesh: {w}");
    }
    // A mesh's default sampling thinned (or still over) for a real-time tick, likewise.
    if let Some(plan) = scene
        .sampling_plan
        .as_ref()
        .filter(|p| p.resampled() || !p.fits())
    {
        say!("  sampling: {plan}");
    }
}

/// The journal file with its header, if asked for.
fn open_journal(
    path: Option<&std::path::Path>,
    config: &ServerConfig,
) -> anyhow::Result<Option<std::io::BufWriter<std::fs::File>>> {
    let Some(path) = path else {
        return Ok(None);
    };
    let mut file = std::io::BufWriter::new(
        std::fs::File::create(path)
            .with_context(|| format!("cannot create journal {}", path.display()))?,
    );
    // A scene file is named by its absolute path, so the journal replays from anywhere.
    let scene_name = match scalpel_sim::scene::builtin(&config.scene) {
        Some(_) => config.scene.clone(),
        None => std::fs::canonicalize(&config.scene)?.display().to_string(),
    };
    let lesson = match config.lesson.as_str() {
        "" => String::new(),
        name => scene_file::lesson_text(name)?,
    };
    let started = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_secs());
    std::io::Write::write_all(
        &mut file,
        journal::header(&scene_name, started, &config.to_toml(), &lesson).as_bytes(),
    )?;
    Ok(Some(file))
}

/// Malformed poses a shared-memory device sent since the last status line, and poses from
/// processes that had not connected as the device: said with it (the force meanwhile fades
/// as if the device were silent).
#[derive(Default)]
struct DeviceNotes {
    rejected_said: u64,
    unconnected_said: u64,
}

impl DeviceNotes {
    fn say_new(&mut self, shm: &ShmDeviceCounters, uptime_s: f64, json: bool) {
        let say = |event: String| {
            print_report(
                &StationReport::Event(station::StationEvent { uptime_s, event }),
                json,
            );
        };
        let rejected = shm.rejected.load(Ordering::Relaxed);
        if rejected > self.rejected_said {
            say(format!(
                "device: {} poses rejected as malformed (a tip not finite or beyond {} m, an orientation far from a unit quaternion, or another layout version; docs/PROTOCOL.md)",
                rejected - self.rejected_said,
                scalpel_server::shm_device::WORKSPACE_RADIUS_M
            ));
            self.rejected_said = rejected;
        }
        let unconnected = shm.unconnected.load(Ordering::Relaxed);
        if unconnected > self.unconnected_said {
            say(format!(
                "device: {} poses dropped from a process that had not connected as the station's device (docs/PROTOCOL.md, \"Connecting a device\")",
                unconnected - self.unconnected_said
            ));
            self.unconnected_said = unconnected;
        }
    }
}

/// The run's totals (with the shared-memory device's counters, if it had one).
fn print_summary(
    summary: &station::RunSummary,
    shm: Option<&ShmDeviceCounters>,
    json: bool,
) -> anyhow::Result<()> {
    use std::sync::atomic::Ordering::Relaxed;
    if json {
        let mut out = serde_json::to_value(summary)?;
        if let Some(shm) = shm {
            out["device"] = serde_json::json!({
                "poses_used": shm.poses.load(Relaxed),
                "poses_rejected": shm.rejected.load(Relaxed),
                "poses_unconnected": shm.unconnected.load(Relaxed),
                "forces_not_sent": shm.send_failures.load(Relaxed),
            });
        }
        say!("{out}");
        return Ok(());
    }
    say!(
        "stopped: {} haptic ticks, {} deadline misses, {} poses dropped; {} simulation ticks ({} late, {} of them over a tick of CPU time; p50 / p99 / p99.9 {} ms; longest {:.2} ms, {:.2} ms of CPU; at most {} sub-step(s); {} re-cut(s) waited for), cut {:.1} mm; state hash {:016x}; SCHED_FIFO {}, memory locked {}",
        summary.haptic_ticks,
        summary.deadline_misses,
        summary.poses_dropped,
        summary.sim.ticks,
        summary.sim.late_ticks,
        summary.sim.late_ticks_cpu,
        [0.5, 0.99, 0.999]
            .map(|q| summary
                .sim
                .tick_times
                .quantile_ms(q)
                .map_or("> 5.1".to_string(), |ms| format!("{ms:.2}")))
            .join(" / "),
        summary.sim.max_tick_ms,
        summary.sim.max_tick_cpu_ms,
        summary.sim.most_substeps,
        summary.sim.recuts_waited,
        summary.sim.cut_length_mm,
        summary.state_hash,
        summary.fifo_priority,
        summary.memory_locked
    );
    let slowest = &summary.sim.slowest_tick;
    say!(
        "slowest simulation tick: {} ({:.2} ms, {:.2} ms of CPU; stages in ms: {})",
        slowest.tick,
        slowest.wall_ms,
        slowest.cpu_ms,
        station::stages_text(&slowest.stages_ms)
    );
    if let Some(shm) = shm {
        say!(
            "device: {} poses used, {} rejected as malformed, {} forces not sent",
            shm.poses.load(Relaxed),
            shm.rejected.load(Relaxed),
            shm.send_failures.load(Relaxed)
        );
    }
    Ok(())
}

/// The station's scene and its prepared simulation.
type Built = (
    scalpel_sim::scene::BuiltScene,
    scalpel_sim::pipeline::Simulation,
    Option<String>,
);

/// Builds the station's scene within `budget`, and its simulation, on a thread of its own,
/// so that a stop (a signal, the end of `--duration`) ends a long build: the process then
/// exits without having ticked, and says so.
fn build_scene_unless_stopped(
    name: &str,
    budget: SceneBudget,
    stop: &AtomicBool,
) -> anyhow::Result<Built> {
    let (built_tx, built) = std::sync::mpsc::channel();
    let name = name.to_string();
    std::thread::Builder::new()
        .name("scene-build".into())
        .spawn(move || {
            let result =
                scene_file::load_station_scene_within(&name, &budget).map(|(scene, note)| {
                    let sim = station::prepare_simulation(&scene);
                    (scene, sim, note)
                });
            let _ = built_tx.send(result);
        })
        .context("cannot start the scene's build")?;
    let started = std::time::Instant::now();
    loop {
        match built.recv_timeout(std::time::Duration::from_millis(20)) {
            Ok(result) => return result,
            Err(std::sync::mpsc::RecvTimeoutError::Timeout) => {
                if stop.load(Ordering::Relaxed) {
                    anyhow::bail!(
                        "stopped while the scene was still building ({:.1} s in): no tick ran",
                        started.elapsed().as_secs_f64()
                    );
                }
            }
            Err(std::sync::mpsc::RecvTimeoutError::Disconnected) => {
                anyhow::bail!("the scene's build panicked")
            }
        }
    }
}

fn print_report(report: &StationReport, json: bool) {
    if json {
        if let Ok(s) = serde_json::to_string(report) {
            say!("{s}");
        }
        return;
    }
    match report {
        StationReport::Status(line) => print_status(line),
        StationReport::Event(e) => say!("{:7.1} s  {}", e.uptime_s, e.event),
    }
}

fn print_status(line: &StatusLine) {
    let haptic = match &line.haptic {
        Some(h) => format!(
            "haptic {:6.1} Hz  jitter p50 {:.3} p99 {:.3} max {:.3} ms  misses {}  force {:.2} N{}{}{}",
            h.rate_hz,
            h.jitter_p50_ms,
            h.jitter_p99_ms,
            h.jitter_max_ms,
            h.deadline_misses,
            h.force_n,
            if h.watchdog_faded { " (faded)" } else { "" },
            if h.passivity_ticks > 0 {
                format!("  passivity damped {} ticks", h.passivity_ticks)
            } else {
                String::new()
            },
            match line.device_connected {
                Some(false) => "  no device",
                _ => "",
            }
        ),
        None => "no haptics".to_string(),
    };
    say!(
        "{:7.1} s  {haptic}  | sim {} ticks, {} points × {} sub-step(s), cut {:.1} mm, {} frames",
        line.uptime_s,
        line.sim.ticks,
        line.sim.active_points,
        line.sim.substeps,
        line.sim.cut_length_mm,
        line.sim.frames_sent
    );
}

/// `--check`: the host check's report; exits 1 when something would stop the station.
fn check_host(config: &ServerConfig, timing: bool, json: bool) -> anyhow::Result<()> {
    let budget = SceneBudget::station(&config.limits);
    let (estimate, scene) = host_check::estimate_and_build(&config.scene, &budget);
    let mut checks = host_check::run(config, scene.as_ref().map_err(String::as_str), timing);
    // After the scene's line.
    checks.insert(1, estimate);
    let passed = host_check::passed(&checks);
    if json {
        say!(
            "{}",
            serde_json::json!({ "station": config.station, "checks": checks, "passed": passed })
        );
    } else {
        say!("station {}:", config.station);
        for c in &checks {
            let status = match c.status {
                host_check::Status::Ok => "ok",
                host_check::Status::Warn => "warn",
                host_check::Status::Fail => "FAIL",
            };
            say!("  {status:<5}{:<15}{}", c.name, c.detail);
        }
        say!(
            "{}",
            if passed {
                "the station can run here (warnings say what it would run without)"
            } else {
                "the station would not start: see FAIL above"
            }
        );
    }
    if !passed {
        std::process::exit(1);
    }
    Ok(())
}

/// The QUIC endpoint's parameters: only with `network.listen` set and a scene that has the
/// `observers` feature.
fn network_params(
    config: &ServerConfig,
    scene: &scalpel_sim::scene::BuiltScene,
    lesson: Option<&scalpel_sim::lesson::Plan>,
) -> anyhow::Result<Option<scalpel_server::net::NetworkParams>> {
    let n = &config.network;
    if n.listen.is_empty() {
        return Ok(None);
    }
    if !scene.spec.features.observers {
        scalpel_server::console::error(format_args!(
            "network.listen is set but scene {} has no `observers` feature: no endpoint",
            scene.spec.name
        ));
        return Ok(None);
    }
    let certs = PathBuf::from(&n.certs);
    scalpel_server::net::check_certs(&certs)?;
    Ok(Some(scalpel_server::net::NetworkParams {
        listen: n.listen.parse().context("network.listen")?,
        certs,
        frame_hz: n.frame_hz,
        max_connections: n.max_connections as usize,
        max_per_address: n.max_per_address as usize,
        max_handshakes: n.max_handshakes as usize,
        max_handshakes_per_address: n.max_handshakes_per_address as usize,
        station: config.station.clone(),
        scene: scene.spec.name.clone(),
        // The station sets them (away from the haptic thread's CPU).
        cpus: Vec::new(),
        lesson: lesson.map(|p| scalpel_server::lesson_feed::plan_message(p, &config.trainee)),
    }))
}
