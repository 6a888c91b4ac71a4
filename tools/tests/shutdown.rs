//! How a station stops and what it refuses to start (issue 45), with real processes:
//!
//! - SIGTERM (what `kill`, containers and supervisors send) and SIGINT both bring the force
//!   down at the rate limit to zero on a real mock device, print the summary and close the
//!   journal (it replays identical); SIGTERM used to kill the process on the spot (exit 143,
//!   2.18 N held then dropped, the journal "not closed");
//! - a scene over the station's memory budget is refused before it is built, with what to
//!   change (`target_points = 3900000` took 17.8 GB of a 24 GB host), by the server, by
//!   `--check` and by `scalpel replay`;
//! - a stop during a long build (SIGTERM, the end of `--duration`) ends it, and a station
//!   that ran no tick exits non-zero.

mod common;

use std::path::Path;
use std::process::Command;
use std::time::Duration;

use common::station::{self, Running, json, scalpel, start_server, unique_station};

/// The output stage's rate limit (N per 1 ms tick, the configuration's default).
const RATE_LIMIT_N: f64 = 0.5;

/// The tests of this file start servers with simulations; on two cores, one at a time.
static ONE_AT_A_TIME: std::sync::Mutex<()> = std::sync::Mutex::new(());

fn one_at_a_time() -> std::sync::MutexGuard<'static, ()> {
    ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner())
}

/// Waits for `child` to exit, for at most `timeout` (then kills it and fails: it ignored
/// what should have stopped it).
fn exits_within(child: &mut std::process::Child, timeout: Duration) -> std::process::ExitStatus {
    let end = std::time::Instant::now() + timeout;
    loop {
        if let Some(status) = child.try_wait().unwrap() {
            return status;
        }
        if std::time::Instant::now() > end {
            let _ = child.kill();
            panic!("still running {timeout:?} after it was told to stop");
        }
        std::thread::sleep(Duration::from_millis(50));
    }
}

fn signal(pid: u32, name: &str) {
    let sent = Command::new("kill")
        .args([&format!("-{name}"), &pid.to_string()])
        .status()
        .unwrap();
    assert!(sent.success(), "kill -{name}");
}

/// The forces a mock device recorded, one per server tick: (tick, |force| N, flags).
fn forces_by_tick(csv: &Path) -> Vec<(u64, f64, u32)> {
    let text = std::fs::read_to_string(csv).unwrap();
    let mut rows: Vec<(u64, f64, u32)> = text
        .lines()
        .skip(1)
        .filter_map(|l| {
            let c: Vec<&str> = l.split(',').collect();
            let f: Vec<f64> = c[5..8].iter().map(|x| x.parse().unwrap()).collect();
            Some((
                c[10].parse().ok()?,
                (f[0] * f[0] + f[1] * f[1] + f[2] * f[2]).sqrt(),
                c[9].parse().ok()?,
            ))
        })
        .filter(|r| r.0 > 0)
        .collect();
    rows.dedup_by_key(|r| r.0);
    rows
}

/// One station with a mock device cutting in a loop, stopped by `name` once the device
/// feels the cut.
fn stop_a_cutting_station_with(name: &str) {
    let dir = station::scratch(&format!("signal-{name}"));
    let station_name = unique_station(&format!("sig{name}"));
    let journal = dir.join("session.journal");
    let config = dir.join("server.toml");
    std::fs::write(
        &config,
        format!(
            "station = \"{station_name}\"\n[device]\nkind = \"shared_memory\"\n[rates]\nstatus_interval_s = 0.25\n"
        ),
    )
    .unwrap();
    let mut command = Command::new(station::server_binary());
    command
        .arg(&config)
        .args(["--json", "--duration", "120", "--journal"])
        .arg(&journal);
    let mut server = Running::start(command);
    server.wait_for(Duration::from_secs(60), |l| l.contains("\"haptic\""));
    let forces = dir.join("forces.csv");
    let mut mock = scalpel();
    mock.args(["mock-device", "--station", &station_name, "--loop", "--out"])
        .arg(&forces);
    let mock = Running::start(mock);
    server.wait_for(Duration::from_secs(30), |l| {
        json(l)["haptic"]["force_n"]
            .as_f64()
            .is_some_and(|f| f > 1.0)
    });
    signal(server.child.id(), name);
    let (status, out) = server.finish();
    assert!(
        status.success(),
        "SIG{name}: {status:?}\n{}",
        out.join("\n")
    );
    let summary = json(out.last().unwrap());
    assert!(
        summary["haptic_ticks"].as_u64().unwrap() > 0
            && summary["sim"]["ticks"].as_u64().unwrap() > 0,
        "SIG{name}: no summary: {}",
        out.join("\n")
    );
    // The device: the force came down at the rate limit, and the last one it got is zero.
    std::thread::sleep(Duration::from_millis(300));
    signal(mock.child.id(), "INT");
    let (mock_status, mock_out) = mock.finish();
    assert!(mock_status.success(), "{mock_out:?}");
    let rows = forces_by_tick(&forces);
    let last = *rows.last().unwrap();
    assert_eq!(last.1, 0.0, "SIG{name}: the last force: {last:?}");
    let peak = rows
        .iter()
        .rposition(|r| r.1 > 0.5)
        .expect("the device felt the cut");
    for w in rows[peak..].windows(2) {
        let ((t0, f0, _), (t1, f1, _)) = (w[0], w[1]);
        assert!(
            f0 - f1 <= RATE_LIMIT_N * (t1 - t0) as f64 + 1e-9,
            "SIG{name}: the force dropped from {f0} to {f1} N between ticks {t0} and {t1}"
        );
    }
    // The journal is closed and replays bit for bit; timed, it names its slowest ticks.
    let replay = scalpel().arg("replay").arg(&journal).output().unwrap();
    let text = String::from_utf8_lossy(&replay.stdout);
    assert!(
        replay.status.success() && text.contains("\nidentical to the live run"),
        "SIG{name}: {text}{}",
        String::from_utf8_lossy(&replay.stderr)
    );
    let timed = scalpel()
        .args(["replay", "--json", "--slowest", "3"])
        .arg(&journal)
        .output()
        .unwrap();
    let r: serde_json::Value = serde_json::from_slice(&timed.stdout).unwrap();
    assert_eq!(r["identical"], true, "SIG{name}: {r}");
    let ticks = r["slowest"]["ticks"].as_array().unwrap();
    assert_eq!(ticks.len(), 3, "SIG{name}: {r}");
    assert!(
        ticks
            .windows(2)
            .all(|w| w[0]["ms"].as_f64() >= w[1]["ms"].as_f64())
            && ticks.iter().all(|t| t["ms"].as_f64().unwrap() > 0.0
                && t["stages_ms"].as_object().is_some_and(|s| !s.is_empty())),
        "SIG{name}: {r}"
    );
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn sigterm_and_sigint_ramp_the_force_down_sum_up_and_close_the_journal() {
    let _serial = one_at_a_time();
    stop_a_cutting_station_with("TERM");
    stop_a_cutting_station_with("INT");
}

/// A scene file `extends = "liver"` with `points` target points, and a server configuration
/// for it with `limits`.
fn scene_and_config(dir: &Path, label: &str, points: usize, limits: &str) -> std::path::PathBuf {
    let scene = dir.join(format!("{label}.toml"));
    std::fs::write(
        &scene,
        format!("extends = \"liver\"\n[sampling]\ntarget_points = {points}\n"),
    )
    .unwrap();
    let config = dir.join(format!("{label}-server.toml"));
    std::fs::write(
        &config,
        format!(
            "station = \"{}\"\nscene = \"{}\"\n[limits]\n{limits}\n",
            unique_station(label),
            scene.display()
        ),
    )
    .unwrap();
    config
}

#[test]
fn a_scene_over_the_memory_budget_is_refused_before_it_is_built() {
    let dir = station::scratch("budget");
    // The scene, against a budget of 4 GB (the default is half of the host's memory).
    let config = scene_and_config(&dir, "huge", 3_900_000, "memory_mb = 4096");
    let out = Command::new(station::server_binary())
        .arg(&config)
        .args(["--duration", "20"])
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{stderr}");
    assert!(
        stderr.contains("would take about")
            && stderr.contains("limit of 4096 MB (limits.memory_mb)")
            && stderr.contains("target_points"),
        "{stderr}"
    );
    // --check says the same and fails.
    let out = Command::new(station::server_binary())
        .arg(&config)
        .args(["--check", "--json"])
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(1));
    let report: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let estimate = report["checks"]
        .as_array()
        .unwrap()
        .iter()
        .find(|c| c["name"] == "estimate")
        .unwrap()
        .clone();
    assert_eq!(estimate["status"], "fail", "{estimate}");
    // So does a replay of a journal that names it.
    let journal = dir.join("huge.journal");
    std::fs::write(
        &journal,
        scalpel_server::journal::header(
            dir.join("huge.toml").to_str().unwrap(),
            0,
            "[limits]\nmemory_mb = 4096.0\n",
            "",
        ),
    )
    .unwrap();
    let out = scalpel().arg("replay").arg(&journal).output().unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{stderr}");
    assert!(stderr.contains("would take about"), "{stderr}");
    // A tick far from real time is refused too (300k points on the liver: ~250× real time
    // estimated).
    let config = scene_and_config(&dir, "slow", 300_000, "");
    let out = Command::new(station::server_binary())
        .arg(&config)
        .args(["--duration", "20"])
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{stderr}");
    assert!(stderr.contains("limits.max_slowdown"), "{stderr}");
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn a_stop_during_a_long_build_ends_it_and_no_tick_is_no_success() {
    let _serial = one_at_a_time();
    let dir = station::scratch("longbuild");
    // 300k points, admitted (a slowdown of up to 1000): seconds of building and preparing.
    let config = scene_and_config(&dir, "long", 300_000, "max_slowdown = 1000");
    let out = Command::new(station::server_binary())
        .arg(&config)
        .args(["--duration", "0.5"])
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{stderr}");
    assert!(
        stderr.contains("stopped while the scene was still building"),
        "{stderr}"
    );
    // SIGTERM in the middle of the build.
    let mut server = Command::new(station::server_binary())
        .arg(&config)
        .stderr(std::process::Stdio::piped())
        .stdout(std::process::Stdio::null())
        .spawn()
        .unwrap();
    std::thread::sleep(Duration::from_millis(500));
    signal(server.id(), "TERM");
    // (The whole build takes over 10 s; a server that ignored the signal would then run
    // until killed.)
    let status = exits_within(&mut server, Duration::from_secs(60));
    let mut stderr = String::new();
    std::io::Read::read_to_string(&mut server.stderr.take().unwrap(), &mut stderr).unwrap();
    assert_eq!(status.code(), Some(1), "{stderr}");
    assert!(
        stderr.contains("stopped while the scene was still building"),
        "{stderr}"
    );
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn a_station_that_ticked_exits_zero() {
    // The default limits admit what runs today.
    let _serial = one_at_a_time();
    let dir = station::scratch("admitted");
    let name = unique_station("admitted");
    let mut server = start_server(&name, &dir, 3.0);
    server.wait_for(Duration::from_secs(60), |l| l.contains("\"haptic\""));
    let (status, out) = server.finish();
    assert!(status.success(), "{out:?}");
    std::fs::remove_dir_all(&dir).ok();
}
