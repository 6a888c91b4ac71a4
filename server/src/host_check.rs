//! `scalpel-server CONFIG --check`: what this host and this configuration give a station,
//! before it runs — for a lab setting up a machine (deploy/README.md).
//!
//! The server itself starts with less (normal scheduling, unlocked memory) and says so in
//! warnings; the check finds those causes up front and names the fix. What would stop the
//! station from starting at all (a scene that does not load, a station name in use, a
//! missing certificate, a port taken) is a failure.

use std::path::Path;

use serde::Serialize;

use scalpel_sim::pipeline::CutScript;

use crate::config::{DeviceKind, ServerConfig};
use crate::realtime;
use crate::scene_budget::SceneBudget;

/// How a check came out.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Status {
    /// As the station wants it.
    Ok,
    /// The station runs, with less (the detail says what and how to fix it).
    Warn,
    /// The station would not start.
    Fail,
}

/// One line of the report.
#[derive(Debug, Clone, Serialize)]
pub struct Check {
    /// What was checked (a stable key).
    pub name: &'static str,
    /// The outcome.
    pub status: Status,
    /// What was found, and what to do about it.
    pub detail: String,
}

fn check(name: &'static str, status: Status, detail: impl Into<String>) -> Check {
    Check {
        name,
        status,
        detail: detail.into(),
    }
}

/// Runs every check for `config` (its scene already loaded, or the error it gave); `timing`
/// times the scene's simulation on this host (up to [`TIMING_WALL_S`]).
pub fn run(
    config: &ServerConfig,
    scene: Result<&scalpel_sim::scene::BuiltScene, &str>,
    timing: bool,
) -> Vec<Check> {
    let observers = scene.as_ref().is_ok_and(|s| s.spec.features.observers);
    let haptics = scene.as_ref().map_or(true, |s| s.spec.features.haptics);
    // The server refuses to start only when its device is on shared memory; render frames
    // and the monitor's clean-up are dropped with a warning.
    let needs_shm = config.device.kind == DeviceKind::SharedMemory;
    // Laid or read once, for the device's check and the timing.
    let script = station_script(config, scene.ok());
    vec![
        scene_check(scene),
        device_check(config, script.as_ref()),
        if timing {
            simulation_check(config, scene.ok(), script.and_then(Result::ok))
        } else {
            check("simulation", Status::Ok, "not timed (--no-timing)")
        },
        station_check(&config.station, needs_shm),
        fifo_check(
            config.realtime.fifo_priority,
            config.realtime.sim_fifo_priority,
            haptics,
        ),
        memlock_check(config.realtime.lock_memory),
        rt_throttling_check(),
        cpu_check(config.realtime.haptic_cpu, haptics),
        shm_check(needs_shm),
        network_check(config, observers),
    ]
}

/// The scene's footprint against the station's budget (a check line), and the scene built
/// when it is within it — not otherwise: building it would take the host.
pub fn estimate_and_build(
    name: &str,
    budget: &SceneBudget,
) -> (Check, Result<scalpel_sim::scene::BuiltScene, String>) {
    let surface = match crate::scene_file::prepare_station_scene(name) {
        Ok((surface, _)) => surface,
        Err(e) => {
            return (
                check(
                    "estimate",
                    Status::Warn,
                    "not estimated: the scene did not load",
                ),
                Err(format!("{e:#}")),
            );
        }
    };
    let f = surface.footprint();
    if let Err(e) = budget.check(&surface.spec.name, &f) {
        return (
            check("estimate", Status::Fail, e),
            Err(
                "not built: over the station's budget (the estimate below says by how much)".into(),
            ),
        );
    }
    let tick = match (f.tick, f.slowdown()) {
        (Some(t), Some(slowdown)) => format!(
            "about {:.2} ms ({} sub-steps; {slowdown:.1}× real time)",
            t.wall_s * 1e3,
            t.substeps
        ),
        _ => "not estimated (stiff mode: timed below)".into(),
    };
    let figures = format!(
        "about {:.0} MB ({} points, {} triangles), a whole-body tick {tick}; within the budget: {}",
        f.memory_mb(),
        f.points,
        f.triangles,
        budget.describe()
    );
    let scene = scalpel_sim::scene::build_model(surface, &mut scalpel_sim::progress::Silent)
        .map_err(|e| e.to_string());
    (check("estimate", Status::Ok, figures), scene)
}

/// Whether nothing failed.
pub fn passed(checks: &[Check]) -> bool {
    checks.iter().all(|c| c.status != Status::Fail)
}

fn scene_check(scene: Result<&scalpel_sim::scene::BuiltScene, &str>) -> Check {
    match scene {
        Ok(s) => {
            let f = &s.spec.features;
            let on: Vec<&str> = [
                ("cutting", f.cutting),
                ("haptics", f.haptics),
                ("frames", f.frames),
                ("observers", f.observers),
            ]
            .iter()
            .filter(|(_, on)| *on)
            .map(|(n, _)| *n)
            .collect();
            check(
                "scene",
                Status::Ok,
                format!(
                    "{}: {} triangles, {} points; features: {}",
                    s.spec.name,
                    s.model.surface.triangles.len(),
                    s.model.points.len(),
                    if on.is_empty() {
                        "none".to_string()
                    } else {
                        on.join(", ")
                    }
                ),
            )
        }
        Err(e) => check("scene", Status::Fail, e),
    }
}

/// The blade script the station plays: the device's script file, or the demo cut laid on
/// the scene (with a shared-memory device, as the timing's stand-in); `None` when it
/// needs the scene and the scene did not load.
fn station_script(
    config: &ServerConfig,
    scene: Option<&scalpel_sim::scene::BuiltScene>,
) -> Option<Result<CutScript, String>> {
    match (&config.device.kind, config.device.script.as_str()) {
        (DeviceKind::Scripted, file) if !file.is_empty() => Some(
            crate::scene_file::load_script(Path::new(file))
                .map_err(|e| format!("device.script: {e:#}")),
        ),
        _ => scene.map(|s| {
            CutScript::default_for(&scalpel_sim::pipeline::start_surface(s)).map_err(|e| {
                format!("the scene has no place for the demo cut ({e}): give device.script")
            })
        }),
    }
}

fn device_check(config: &ServerConfig, script: Option<&Result<CutScript, String>>) -> Check {
    match config.device.kind {
        DeviceKind::SharedMemory => check(
            "device",
            Status::Ok,
            format!(
                "a device process on station {}'s shared-memory services (docs/PROTOCOL.md); the force fades to zero until it connects",
                config.station
            ),
        ),
        // The server refuses to start without the script it plays.
        DeviceKind::Scripted => match script {
            Some(Ok(_)) if config.device.script.is_empty() => check(
                "device",
                Status::Ok,
                "in-process scripted device, the scene's demo cut",
            ),
            Some(Ok(_)) => check(
                "device",
                Status::Ok,
                format!(
                    "in-process scripted device playing {}",
                    config.device.script
                ),
            ),
            Some(Err(e)) => check("device", Status::Fail, e.clone()),
            None => check(
                "device",
                Status::Warn,
                "in-process scripted device, the scene's demo cut (not laid: the scene did not load)",
            ),
        },
    }
}

/// Wall time the simulation check may take, building the simulation included.
const TIMING_WALL_S: f64 = 2.0;

/// One timed tick of the simulation check.
struct TimedTick {
    wall_ms: f64,
    substeps: u32,
    /// The tissue moved (a cutting scene integrates nothing until the tool touches it:
    /// those ticks would only dilute the figures).
    moving: bool,
}

/// The scene's simulation ticks timed on this host against the station's 1 ms tick: the
/// device's script (with a shared-memory device, the scene's demo cut as a stand-in; no
/// tool where neither can be laid) played from its start, as the simulation thread would,
/// for at most [`TIMING_WALL_S`] — on a thread of its own, left behind when time is up (a
/// stiff scene's single tick can take minutes; the check ends, and the process with it).
/// A scene somewhat too heavy for the host still runs — the haptic loop bridges late ticks
/// with the local force model and the tissue lags the tool — so that warns; one whose median
/// tick is over `limits.max_slowdown` times the 1 ms it simulates (or whose first tick does
/// not end at all) cannot run in real time and fails.
fn simulation_check(
    config: &ServerConfig,
    scene: Option<&scalpel_sim::scene::BuiltScene>,
    script: Option<CutScript>,
) -> Check {
    use scalpel_sim::pipeline::{NoClock, SIMULATION_TICK_S};
    use std::sync::atomic::{AtomicBool, Ordering};
    use std::time::{Duration, Instant};
    let Some(scene) = scene else {
        return check(
            "simulation",
            Status::Warn,
            "not timed: the scene did not load",
        );
    };
    let played = match (&script, config.device.script.as_str()) {
        (None, _) => "no tool",
        (Some(_), "") => "the scene's demo cut",
        (Some(_), _) => "the device's script",
    };
    let ticks = script.as_ref().map_or(1000, |s| {
        ((s.duration_s() / SIMULATION_TICK_S).ceil() as usize).max(1)
    });
    let started = Instant::now();
    let deadline = started + Duration::from_secs_f64(TIMING_WALL_S);
    let (sent, timed) = std::sync::mpsc::channel();
    let stop = std::sync::Arc::new(AtomicBool::new(false));
    {
        let (scene, stop) = (scene.clone(), stop.clone());
        std::thread::spawn(move || {
            let mut sim = crate::station::prepare_simulation(&scene);
            for k in 0..ticks {
                if stop.load(Ordering::Relaxed) {
                    return;
                }
                sim.handle_tool_pose(
                    script
                        .as_ref()
                        .map(|s| s.pose_at(k as f64 * SIMULATION_TICK_S)),
                );
                let tick = Instant::now();
                let report = sim.tick(SIMULATION_TICK_S, &mut NoClock);
                let timed = TimedTick {
                    wall_ms: tick.elapsed().as_secs_f64() * 1e3,
                    substeps: report.solver.substeps,
                    moving: report.active_points > 0,
                };
                if sent.send(timed).is_err() {
                    return;
                }
            }
        });
    }
    let mut wall_ms = Vec::with_capacity(ticks);
    let (mut played_ticks, mut most_substeps) = (0, 0);
    while let Ok(t) = timed.recv_timeout(deadline.saturating_duration_since(Instant::now())) {
        played_ticks += 1;
        most_substeps = most_substeps.max(t.substeps);
        if t.moving {
            wall_ms.push(t.wall_ms);
        }
    }
    stop.store(true, Ordering::Relaxed);
    let timed_out = played_ticks < ticks;
    let most = config.limits.max_slowdown;
    if played_ticks == 0 {
        return check(
            "simulation",
            Status::Fail,
            format!(
                "the first tick of {played} did not end within {TIMING_WALL_S} s: far too slow for the 1 ms tick — fewer points ([sampling]) or a softer material"
            ),
        );
    }
    let timed = wall_ms.len();
    if timed == 0 && timed_out {
        return check(
            "simulation",
            Status::Fail,
            format!(
                "{played_ticks} ticks of {played} with the tissue at rest, then the first with it moving did not end within {TIMING_WALL_S} s: far too slow for the 1 ms tick — fewer points ([sampling]) or a softer material"
            ),
        );
    }
    if timed == 0 {
        return check(
            "simulation",
            Status::Ok,
            format!("{played_ticks} ticks of {played}: the tissue never moved, nothing to time"),
        );
    }
    wall_ms.sort_by(f64::total_cmp);
    let at = |q: f64| wall_ms[((timed - 1) as f64 * q).round() as usize];
    let over = wall_ms.iter().filter(|&&ms| ms > 1.0).count();
    let figures = format!(
        "{timed} ticks with the tissue moving in {played_ticks}{} of {played}: p50 {:.3}, p99 {:.3}, max {:.2} ms of the 1 ms tick, at most {most_substeps} sub-step(s)",
        if timed_out {
            format!(" (of {ticks}: {TIMING_WALL_S} s of wall time)")
        } else {
            String::new()
        },
        at(0.5),
        at(0.99),
        at(1.0),
    );
    if at(0.99) <= 1.0 {
        check("simulation", Status::Ok, figures)
    } else if at(0.5) > most {
        check(
            "simulation",
            Status::Fail,
            format!(
                "{figures}: the median tick is over limits.max_slowdown = {most} times the 1 ms it simulates, the station cannot run it in real time — fewer points ([sampling]) or a softer material"
            ),
        )
    } else {
        check(
            "simulation",
            Status::Warn,
            format!(
                "{figures}; {over} over 1 ms: the tissue will lag the tool (the haptic loop bridges late ticks with the local force model) — fewer points ([sampling]) or a softer material"
            ),
        )
    }
}

fn station_check(station: &str, needs_shm: bool) -> Check {
    match scalpel_proto::shm::station_nodes(station) {
        Ok(nodes) => {
            if let Some(node) = crate::station::live_server(&nodes) {
                return check(
                    "station",
                    Status::Fail,
                    crate::station::station_taken(station, node),
                );
            }
            let dead = nodes.iter().filter(|n| !n.alive).count();
            check(
                "station",
                Status::Ok,
                if dead > 0 {
                    format!(
                        "{station} is free; {dead} dead node(s) of an earlier run will be cleaned up at start"
                    )
                } else {
                    format!("{station} is free")
                },
            )
        }
        Err(e) => check(
            "station",
            // Without iceoryx2's files the device's services cannot open either.
            if needs_shm {
                Status::Fail
            } else {
                Status::Warn
            },
            format!(
                "cannot list the shared-memory nodes ({e}): iceoryx2 keeps its state in /tmp/iceoryx2 and /dev/shm, owned by whoever made them first — every station, device and viewer process of a host must run as one user"
            ),
        ),
    }
}

/// Tries SCHED_FIFO at `priority` on a thread of its own, which then ends (the caller's
/// scheduling is untouched).
fn probe_fifo(priority: i32) -> Result<(), String> {
    std::thread::spawn(move || realtime::make_thread_fifo(priority))
        .join()
        .unwrap_or_else(|_| Err("the probe thread panicked".into()))
}

fn fifo_check(priority: i32, sim_priority: i32, haptics: bool) -> Check {
    if !haptics {
        return check(
            "sched_fifo",
            Status::Ok,
            "no haptic thread (the scene has no haptics)",
        );
    }
    if priority == 0 {
        return check(
            "sched_fifo",
            Status::Warn,
            "realtime.fifo_priority = 0: the haptic thread runs with normal scheduling",
        );
    }
    let limit = || match realtime::soft_limit(libc::RLIMIT_RTPRIO) {
        Ok(Some(soft)) => format!("RLIMIT_RTPRIO is {soft}"),
        Ok(None) => "RLIMIT_RTPRIO is unlimited".to_string(),
        Err(e) => format!("RLIMIT_RTPRIO: {e}"),
    };
    if let Err(e) = probe_fifo(priority) {
        return check(
            "sched_fifo",
            Status::Warn,
            format!(
                "{e} ({}): the haptic thread would run with normal scheduling; allow it with LimitRTPRIO={priority} in the service (deploy/systemd) or `rtprio {priority}` in /etc/security/limits.d (deploy/host)",
                limit()
            ),
        );
    }
    if sim_priority > 0
        && let Err(e) = probe_fifo(sim_priority)
    {
        // The server drops it silently (the simulation then runs with normal scheduling).
        return check(
            "sched_fifo",
            Status::Warn,
            format!(
                "the haptic thread gets SCHED_FIFO {priority}, but realtime.sim_fifo_priority: {e} ({}): the simulation thread would run with normal scheduling",
                limit()
            ),
        );
    }
    check(
        "sched_fifo",
        Status::Ok,
        if sim_priority > 0 {
            format!("the haptic thread gets SCHED_FIFO {priority}, the simulation {sim_priority}")
        } else {
            format!("the haptic thread gets SCHED_FIFO {priority}")
        },
    )
}

/// Linux capability bit of CAP_IPC_LOCK (linux/capability.h).
const CAP_IPC_LOCK: u32 = 14;

/// Whether this process has capability `bit` in its effective set (/proc/self/status).
fn has_capability(bit: u32) -> bool {
    std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|s| {
            s.lines()
                .find_map(|l| l.strip_prefix("CapEff:"))
                .and_then(|v| u64::from_str_radix(v.trim(), 16).ok())
        })
        .is_some_and(|caps| caps & (1 << bit) != 0)
}

fn memlock_check(wanted: bool) -> Check {
    if !wanted {
        return check(
            "memory_lock",
            Status::Warn,
            "realtime.lock_memory = false: the haptic loop may wait on page faults",
        );
    }
    let limit = realtime::soft_limit(libc::RLIMIT_MEMLOCK);
    let shown = match &limit {
        Ok(None) => "unlimited".to_string(),
        Ok(Some(soft)) => format!("{} KiB", soft / 1024),
        Err(e) => format!("unknown ({e})"),
    };
    match (realtime::try_lock_memory(), limit) {
        (Ok(()), Ok(None)) => check(
            "memory_lock",
            Status::Ok,
            "mlockall permitted, RLIMIT_MEMLOCK unlimited",
        ),
        // CAP_IPC_LOCK (root has it) locks whatever the limit says.
        (Ok(()), _) if has_capability(CAP_IPC_LOCK) => check(
            "memory_lock",
            Status::Ok,
            format!("mlockall permitted (CAP_IPC_LOCK: RLIMIT_MEMLOCK {shown} does not apply)"),
        ),
        (Ok(()), _) => check(
            "memory_lock",
            Status::Warn,
            format!(
                "mlockall permitted now, but RLIMIT_MEMLOCK is {shown}: the running station (its scene, render frames, device) may need more; set LimitMEMLOCK=infinity (deploy/systemd) or `memlock unlimited` (deploy/host)"
            ),
        ),
        (Err(e), _) => check(
            "memory_lock",
            Status::Warn,
            format!(
                "mlockall: {e} (RLIMIT_MEMLOCK {shown}): the haptic loop may wait on page faults; set LimitMEMLOCK=infinity (deploy/systemd) or `memlock unlimited` (deploy/host)"
            ),
        ),
    }
}

fn rt_throttling_check() -> Check {
    let path = "/proc/sys/kernel/sched_rt_runtime_us";
    let read = |p: &str| std::fs::read_to_string(p).map(|s| s.trim().parse::<i64>());
    // The runtime is out of this period (1 s unless changed).
    let period_us = match read("/proc/sys/kernel/sched_rt_period_us") {
        Ok(Ok(p)) if p > 0 => p,
        _ => 1_000_000,
    };
    let share = |us: i64| {
        format!(
            "real-time threads get at most {:.0} % of each {} ms ({path} = {us})",
            us as f64 / period_us as f64 * 100.0,
            period_us / 1000
        )
    };
    match read(path) {
        Ok(Ok(-1)) => check(
            "rt_throttling",
            Status::Warn,
            format!(
                "{path} is -1: a real-time thread that runs away can take a CPU for good; the default 950000 (of 1 s) keeps 5 % for the rest"
            ),
        ),
        // Under half the period the haptic thread's ~1 % is safe, but a real-time
        // simulation thread is not (and 0 stops real-time threads altogether).
        Ok(Ok(us)) if us < period_us / 2 => check(
            "rt_throttling",
            Status::Warn,
            format!(
                "{}: too little for a real-time simulation thread; the default is 950000 of 1000000",
                share(us)
            ),
        ),
        Ok(Ok(us)) => check("rt_throttling", Status::Ok, share(us)),
        _ => check("rt_throttling", Status::Warn, format!("cannot read {path}")),
    }
}

fn cpu_check(haptic_cpu: i32, haptics: bool) -> Check {
    let cpus = realtime::allowed_cpus();
    if haptic_cpu >= 0 && haptics {
        let c = haptic_cpu as usize;
        return match realtime::cpus_besides(c, &cpus) {
            Ok(_) => check(
                "cpus",
                Status::Ok,
                format!(
                    "the haptic thread pinned to CPU {c} of {cpus:?}, the network threads kept off it"
                ),
            ),
            Err(e) => check(
                "cpus",
                Status::Warn,
                format!("{e}: the haptic thread would share its CPU"),
            ),
        };
    }
    if cpus.len() >= 2 {
        check(
            "cpus",
            Status::Ok,
            format!(
                "{} CPUs {cpus:?}; the haptic thread is not pinned",
                cpus.len()
            ),
        )
    } else {
        check(
            "cpus",
            Status::Warn,
            format!(
                "one CPU {cpus:?}: the haptic and simulation threads share it (a station wants two)"
            ),
        )
    }
}

fn shm_check(needs_shm: bool) -> Check {
    let free_mib = match realtime::free_bytes(c"/dev/shm") {
        Ok(b) => b as f64 / (1024.0 * 1024.0),
        Err(e) => {
            return check(
                "shared_memory",
                if needs_shm {
                    Status::Fail
                } else {
                    Status::Warn
                },
                format!("/dev/shm: {e}: iceoryx2 needs it for the device and render services"),
            );
        }
    };
    // A station's services take a few MiB (frames grow with the cut surface).
    if free_mib < 64.0 {
        check(
            "shared_memory",
            Status::Warn,
            format!("/dev/shm has {free_mib:.0} MiB free: render frames may not find room"),
        )
    } else {
        check(
            "shared_memory",
            Status::Ok,
            format!("/dev/shm has {free_mib:.0} MiB free"),
        )
    }
}

fn network_check(config: &ServerConfig, observers: bool) -> Check {
    let n = &config.network;
    if n.listen.is_empty() {
        return check(
            "network",
            Status::Ok,
            "no endpoint (network.listen is empty)",
        );
    }
    if !observers {
        return check(
            "network",
            Status::Warn,
            format!(
                "network.listen is {} but the scene has no `observers` feature: no endpoint would run",
                n.listen
            ),
        );
    }
    let addr: std::net::SocketAddr = match n.listen.parse() {
        Ok(a) => a,
        Err(e) => {
            return check(
                "network",
                Status::Fail,
                format!("network.listen {:?}: {e}", n.listen),
            );
        }
    };
    // The files there, and a TLS configuration made from them (a key that does not match
    // its certificate, a file that is not PEM).
    if let Err(e) = crate::net::check_certs(Path::new(&n.certs))
        .and_then(|()| crate::net::tls::server_config(Path::new(&n.certs)).map(drop))
    {
        return check("network", Status::Fail, format!("network.certs: {e:#}"));
    }
    // QUIC runs over UDP: the port must be free now (a bound-and-released probe).
    match std::net::UdpSocket::bind(addr) {
        Ok(_) => check(
            "network",
            Status::Ok,
            format!(
                "QUIC on {addr} (UDP port free), certificates in {}",
                n.certs
            ),
        ),
        Err(e) => check(
            "network",
            Status::Fail,
            format!("network.listen {addr}: {e} (another station or program holds the port?)"),
        ),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_scene_that_does_not_load_fails_the_check_and_the_rest_still_run() {
        let checks = run(
            &ServerConfig::default(),
            Err("no such scene: nowhere"),
            true,
        );
        assert!(!passed(&checks));
        assert_eq!(checks[0].name, "scene");
        assert_eq!(checks[0].status, Status::Fail);
        let names: Vec<&str> = checks.iter().map(|c| c.name).collect();
        assert_eq!(
            names,
            [
                "scene",
                "device",
                "simulation",
                "station",
                "sched_fifo",
                "memory_lock",
                "rt_throttling",
                "cpus",
                "shared_memory",
                "network"
            ]
        );
    }

    #[test]
    fn the_simulation_check_times_the_demo_cut_and_passes_the_liver() {
        // Whether it warns depends on this machine's speed; what it says does not, and the
        // liver's median tick is far below the 10 ms that fails.
        let scene = crate::scene_file::load_scene("liver").unwrap();
        let config = ServerConfig::default();
        let script = station_script(&config, Some(&scene)).and_then(Result::ok);
        assert!(script.is_some(), "the liver has a place for the demo cut");
        let c = simulation_check(&config, Some(&scene), script);
        assert_ne!(c.status, Status::Fail, "{}", c.detail);
        assert!(
            c.detail.contains("ticks with the tissue moving")
                && c.detail.contains("of the scene's demo cut")
                && c.detail.contains("sub-step(s)"),
            "{}",
            c.detail
        );
        let c = simulation_check(&ServerConfig::default(), None, None);
        assert_eq!(c.status, Status::Warn);
    }

    #[test]
    fn missing_or_garbled_certificates_and_a_bad_address_fail_the_network_check() {
        // (A port in use: tools/tests/deploy.rs, with real certificates.)
        let mut config = ServerConfig::default();
        config.network.listen = "127.0.0.1:0".into();
        let dir = std::env::temp_dir().join(format!("scalpel-no-certs-{}", std::process::id()));
        config.network.certs = dir.display().to_string();
        let c = network_check(&config, true);
        assert_eq!(c.status, Status::Fail);
        assert!(c.detail.contains("is missing"), "{}", c.detail);

        config.network.listen = "not an address".into();
        let c = network_check(&config, true);
        assert_eq!(c.status, Status::Fail);
        assert!(c.detail.contains("network.listen"), "{}", c.detail);

        // Files that are there but hold no certificate.
        std::fs::create_dir_all(&dir).unwrap();
        for f in ["ca.pem", "server.pem", "server.key"] {
            std::fs::write(dir.join(f), "not PEM\n").unwrap();
        }
        config.network.listen = "127.0.0.1:0".into();
        let c = network_check(&config, true);
        assert_eq!(c.status, Status::Fail);
        assert!(c.detail.contains("network.certs"), "{}", c.detail);
        std::fs::remove_dir_all(&dir).unwrap();

        // Without the observers feature the endpoint would not run at all.
        assert_eq!(network_check(&config, false).status, Status::Warn);
    }

    #[test]
    fn a_missing_device_script_fails_and_a_priority_of_zero_warns() {
        let mut config = ServerConfig::default();
        config.device.script = "/nonexistent/cut.toml".into();
        // The demo cut is laid on the scene as the server would lay it.
        let liver = crate::scene_file::load_scene("liver").unwrap();
        let default = ServerConfig::default();
        let check_with = |config: &ServerConfig, scene| {
            device_check(config, station_script(config, scene).as_ref())
        };
        assert_eq!(check_with(&default, Some(&liver)).status, Status::Ok);
        assert_eq!(check_with(&default, None).status, Status::Warn);
        // The device's own script is read whether or not the scene loaded.
        let c = check_with(&config, None);
        assert_eq!(c.status, Status::Fail);
        assert!(c.detail.contains("device.script"), "{}", c.detail);
        assert_eq!(fifo_check(0, 0, true).status, Status::Warn);
        assert_eq!(fifo_check(80, 60, false).status, Status::Ok);
    }
}
