//! A station owns its shared memory (issue 45), against the real server process and the
//! real mock device. This test process plays the squatter: another local process of the
//! same user that makes a station's services first, or publishes poses without connecting.
//!
//! Before: a squatter that made the pose publisher first was taken for the device ("device
//! connected") and locked the mock device out (`ExceedsMaxSupportedPublishers`); one that
//! made the frame publisher first fed renderers its own frames while the server ran
//! without any.

mod common;

use std::process::Command;
use std::time::Duration;

use common::station::{self, Running, json, scalpel, start_server, unique_station};
use scalpel_proto::shm::{self, DevicePose, LAYOUT_VERSION};

static ONE_AT_A_TIME: std::sync::Mutex<()> = std::sync::Mutex::new(());

fn one_at_a_time() -> std::sync::MutexGuard<'static, ()> {
    ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner())
}

/// Runs a server on `station` for a few seconds and returns its exit status and stderr.
fn server_run(station: &str, dir: &std::path::Path) -> (std::process::ExitStatus, String) {
    let config = dir.join("server.toml");
    std::fs::write(
        &config,
        format!("station = \"{station}\"\n[device]\nkind = \"shared_memory\"\n"),
    )
    .unwrap();
    let out = Command::new(station::server_binary())
        .arg(&config)
        .args(["--duration", "3"])
        .output()
        .unwrap();
    (
        out.status,
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

#[test]
fn a_station_whose_services_another_process_made_refuses_to_start_and_names_it() {
    let _serial = one_at_a_time();
    shm::quiet_logging();
    let dir = station::scratch("squat-before");
    for service in ["device/pose", "render/frames"] {
        let name = unique_station("squat");
        let node = shm::node("squatter", &name).unwrap();
        let service_name = shm::service_name(&name, service).unwrap();
        // Made first, with the contract's settings, and held.
        let held: Box<dyn std::any::Any> = match service {
            "device/pose" => Box::new(shm::pose_builder(&node, &service_name).create().unwrap()),
            _ => Box::new(shm::frame_builder(&node, &service_name).create().unwrap()),
        };
        let (status, stderr) = server_run(&name, &dir);
        assert_eq!(status.code(), Some(1), "{service}: {stderr}");
        assert!(
            stderr.contains("shared memory is taken")
                && stderr.contains(&format!("scalpel/{name}/{service}"))
                && stderr.contains(&format!("squatter.{name} (pid {})", std::process::id())),
            "{service}: {stderr}"
        );
        // Once the squatter is gone, the station starts.
        drop(held);
        drop(node);
        let (status, stderr) = server_run(&name, &dir);
        assert!(
            status.success(),
            "{service}, after the squatter left: {stderr}"
        );
    }
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn only_a_device_that_connected_is_taken_and_one_at_a_time() {
    let _serial = one_at_a_time();
    shm::quiet_logging();
    let dir = station::scratch("squat-after");
    let name = unique_station("squat");
    let mut server = start_server(&name, &dir, 60.0);
    server.wait_for(Duration::from_secs(60), |l| l.contains("\"haptic\""));
    // A process that publishes poses without connecting: dropped and said, not taken for
    // the device.
    let node = shm::node("squatter", &name).unwrap();
    let squatter = shm::pose_service(&node, &name)
        .unwrap()
        .publisher_builder()
        .create()
        .unwrap();
    for seq in 1..=200 {
        squatter
            .send_copy(DevicePose {
                layout_version: LAYOUT_VERSION,
                flags: 0,
                seq,
                device_time_ns: scalpel_client::frame_reader::monotonic_ns(),
                tip_m: [0.0, 0.0, 0.0],
                orientation_xyzw: [0.0, 0.0, 0.0, 1.0],
            })
            .unwrap();
        std::thread::sleep(Duration::from_millis(1));
    }
    server.wait_for(Duration::from_secs(5), |l| {
        json(l)["event"]
            .as_str()
            .is_some_and(|e| e.contains("had not connected as the station's device"))
    });
    assert!(
        !server.seen.iter().any(|l| json(l)["event"]
            .as_str()
            .is_some_and(|e| e.starts_with("device connected"))),
        "the squatter was taken for the device"
    );
    // The real mock device connects past it and feels the cut.
    let mut mock = scalpel();
    mock.args([
        "mock-device",
        "--station",
        &name,
        "--loop",
        "--duration",
        "30",
    ]);
    let _mock = Running::start(mock);
    server.wait_for(Duration::from_secs(10), |l| {
        json(l)["event"] == "device connected (scalpel-mock-device)"
    });
    server.wait_for(Duration::from_secs(20), |l| {
        json(l)["haptic"]["force_n"]
            .as_f64()
            .is_some_and(|f| f > 0.5)
    });
    // A second device is refused while the first is connected, and told why.
    let e = shm::connect::hello(&node, &name, "second", Duration::from_secs(2)).unwrap_err();
    assert!(
        e.to_string()
            .contains("the station has a device already (scalpel-mock-device)"),
        "{e}"
    );
    server.wait_for(Duration::from_secs(5), |l| {
        json(l)["event"]
            .as_str()
            .is_some_and(|e| e.starts_with("device second refused"))
    });
    // And nobody else can publish frames: the server holds the frame service's only
    // publisher.
    let frames = shm::frame_service(&node, &name).unwrap();
    assert!(frames.publisher_builder().create().is_err());
    server.kill_9();
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn a_device_needs_a_running_station() {
    let name = unique_station("nostation");
    let out = scalpel()
        .args(["mock-device", "--station", &name, "--duration", "1"])
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{stderr}");
    assert!(
        stderr.contains(&format!("station {name} is not running on this machine")),
        "{stderr}"
    );
}
