//! The lab deployment in `deploy/`, as a host would use it: the stations' configurations
//! laid out as `/etc/scalpel`, a lab CA made with `scalpel certs`, and the real server's
//! `--check` on each; the check failing for a station that already runs; the systemd unit
//! verified by systemd itself.

mod common;

use std::collections::HashSet;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Duration;

use common::station::{self, json, scratch, start_server, unique_station};

fn deploy_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../deploy")
}

/// `scalpel-server CONFIG --check --no-timing --json` run in `dir` (as the lab's unit runs
/// it before each start): exit success and the report.
fn check(dir: &Path, config: &Path) -> (bool, serde_json::Value) {
    let out = Command::new(station::server_binary())
        .current_dir(dir)
        .arg(config)
        .args(["--check", "--no-timing", "--json"])
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    let report = json(stdout.trim());
    assert!(
        report.get("checks").is_some(),
        "no report: {stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert_eq!(out.status.success(), report["passed"] == true, "{report}");
    assert_eq!(
        status_of(&report, "simulation"),
        ("ok", "not timed (--no-timing)")
    );
    (out.status.success(), report)
}

fn status_of<'a>(report: &'a serde_json::Value, name: &str) -> (&'a str, &'a str) {
    let c = report["checks"]
        .as_array()
        .unwrap()
        .iter()
        .find(|c| c["name"] == name)
        .unwrap_or_else(|| panic!("no {name} check in {report}"));
    (c["status"].as_str().unwrap(), c["detail"].as_str().unwrap())
}

#[test]
fn the_lab_stations_pass_the_host_check_with_their_own_names_ports_and_cpus() {
    let etc = scratch("deploy-lab");
    common::copy_tree(&deploy_dir().join("lab"), &etc);
    station::make_lab_ca(&etc.join("lab-certs"));

    let mut stations = Vec::new();
    for entry in std::fs::read_dir(etc.join("stations")).unwrap() {
        stations.push(entry.unwrap().path());
    }
    stations.sort();
    assert_eq!(stations.len(), 3, "{stations:?}");
    let (mut names, mut ports, mut cpus) = (HashSet::new(), HashSet::new(), HashSet::new());
    for path in &stations {
        let config = scalpel_server::config::ServerConfig::load(path).unwrap();
        assert!(names.insert(config.station.clone()), "{path:?}: name taken");
        assert!(
            ports.insert(config.network.listen.clone()),
            "{path:?}: port taken"
        );
        assert!(
            cpus.insert(config.realtime.haptic_cpu),
            "{path:?}: CPU taken"
        );
        assert!(
            config.realtime.haptic_cpu >= 1,
            "CPU 0 is left to the system"
        );

        // Checked as laid out, but under a name and on a port nothing else on this
        // machine can hold (a developer's station-a, another job's 4433).
        let text = std::fs::read_to_string(path).unwrap();
        let text = text
            .replace(&config.station, &unique_station("lab"))
            .replace(&config.network.listen, "127.0.0.1:0");
        let relative = path.strip_prefix(&etc).unwrap();
        std::fs::write(path, text).unwrap();
        let (passed, report) = check(&etc, relative);
        assert!(passed, "{path:?}: {report:#}");
        let (scene, detail) = status_of(&report, "scene");
        assert_eq!(scene, "ok");
        assert!(detail.contains("observers"), "{detail}");
        let (network, detail) = status_of(&report, "network");
        assert_eq!(network, "ok", "{detail}");
        assert!(detail.contains("QUIC on 127.0.0.1:0"), "{detail}");
    }
    std::fs::remove_dir_all(&etc).unwrap();
}

#[test]
fn the_check_fails_for_a_station_that_already_runs_and_for_a_port_in_use() {
    let dir = scratch("deploy-busy");
    let name = unique_station("busy");
    let mut server = start_server(&name, &dir, 60.0);
    // Started (the scene built and the loop running) before the check looks.
    server.wait_for(Duration::from_secs(60), |l| json(l).get("haptic").is_some());
    let config = dir.join(format!("{name}.toml"));
    let (passed, report) = check(&dir, &config);
    assert!(!passed, "{report:#}");
    let (status, detail) = status_of(&report, "station");
    assert_eq!(status, "fail");
    assert!(detail.contains("already has a running server"), "{detail}");
    // Stopped as an operator stops it: its shared memory goes with it.
    let (status, _) = server.interrupt();
    assert!(status.success());
    let (passed, report) = check(&dir, &config);
    assert!(passed, "free again once it stopped: {report:#}");

    // A port someone holds: the check names it (with certificates that are fine).
    station::make_lab_ca(&dir.join("certs"));
    station::write_observed_scene(&dir);
    let held = std::net::UdpSocket::bind("127.0.0.1:0").unwrap();
    let other = dir.join("other.toml");
    std::fs::write(
        &other,
        format!(
            "station = \"{}\"\nscene = \"observed.toml\"\n[network]\nlisten = \"{}\"\ncerts = \"certs\"\n",
            unique_station("port"),
            held.local_addr().unwrap()
        ),
    )
    .unwrap();
    let (passed, report) = check(&dir, Path::new("other.toml"));
    assert!(!passed, "{report:#}");
    let (status, detail) = status_of(&report, "network");
    assert_eq!(status, "fail");
    assert!(
        detail.contains(&held.local_addr().unwrap().to_string()),
        "{detail}"
    );
    drop(held);
    let (passed, report) = check(&dir, Path::new("other.toml"));
    assert!(passed, "{report:#}");
    std::fs::remove_dir_all(&dir).unwrap();
}

/// Needs `systemd-analyze`; `.ci/run` runs it.
#[test]
#[ignore = "needs systemd-analyze; .ci/run runs this"]
fn systemd_the_station_unit_verifies() {
    let unit =
        std::fs::read_to_string(deploy_dir().join("systemd/scalpel-station@.service")).unwrap();
    // The unit names the installed binary; verify it against the one just built.
    assert!(unit.contains("/usr/local/bin/scalpel-server"));
    let server = station::server_binary();
    let local = unit.replace("/usr/local/bin/scalpel-server", server.to_str().unwrap());
    let dir = scratch("deploy-unit");
    let path = dir.join("scalpel-station@station-a.service");
    std::fs::write(&path, local).unwrap();
    let out = Command::new("systemd-analyze")
        .arg("verify")
        .arg(&path)
        .output()
        .expect("systemd-analyze runs");
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    // Unknown keys and bad values are only warnings to systemd: none allowed for this unit
    // (other units of the host it loads may have their own).
    let ours: Vec<&str> = stderr
        .lines()
        .filter(|l| l.contains("scalpel-station@"))
        .collect();
    assert!(ours.is_empty(), "{stderr}");
    // And a unit naming a missing binary does fail (the check above can fail).
    std::fs::write(&path, unit.replace("/usr/local/bin/", "/nonexistent/")).unwrap();
    let out = Command::new("systemd-analyze")
        .arg("verify")
        .arg(&path)
        .output()
        .unwrap();
    assert!(!out.status.success());
    std::fs::remove_dir_all(&dir).unwrap();
}
