//! Issue 45: a QUIC handshake started and never finished used to take a connection's place
//! until the idle timeout, so a trickle of Initial packets from a few addresses kept every
//! observer out (15 of 15 refused). A flood of unfinished handshakes — Initials never
//! followed up, and handshakes that answer the Retry and then stall — from three addresses,
//! while a real observer (mutual TLS against the lab's CA) connects 20 times against the
//! real server process: 20 of 20 admitted, and the station says what it refused — a
//! certificate refused for its role too.

mod common;

use std::process::Command;

#[test]
fn a_flood_of_unfinished_handshakes_does_not_keep_an_observer_out() {
    let out = Command::new(env!("CARGO_BIN_EXE_scalpel"))
        .args(["bench", "admission", "--attempts", "20", "--addresses", "3"])
        .args(["--rate", "50", "--json"])
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let r: serde_json::Value = serde_json::from_str(&stdout).unwrap();
    assert_eq!(r["admitted"], 20, "{r:#}");
    // The flood was real: Initials and stalls sent, and each address answered with a Retry
    // (the server validates addresses before anything else).
    let flood = &r["flood"];
    assert!(flood["initials"].as_u64().unwrap() > 50, "{r:#}");
    assert!(flood["stalls"].as_u64().unwrap() > 50, "{r:#}");
    assert!(flood["retries_received"].as_u64().unwrap() > 50, "{r:#}");
    // The stalls that answered their Retry were held to their share of handshakes, and the
    // station's log says so (said in full, then summed up).
    let lines: Vec<&str> = r["server_refusal_lines"]
        .as_array()
        .unwrap()
        .iter()
        .filter_map(|l| l.as_str())
        .collect();
    assert!(
        lines
            .iter()
            .any(|l| l.contains("handshakes in flight from this address already")),
        "{lines:#?}"
    );
    assert!(
        lines
            .iter()
            .any(|l| l.contains("more connection attempts refused")),
        "{lines:#?}"
    );
}

/// A certificate the lab's CA signed but that names no role gets through TLS and is then
/// refused; the station's log says so, as it says a client without a certificate (issue 45:
/// neither left a line).
#[test]
fn refused_certificates_leave_a_line_in_the_stations_log() {
    use common::station::{self, Running, json, unique_station};
    use rcgen::{
        CertificateParams, DistinguishedName, DnType, ExtendedKeyUsagePurpose, Issuer, KeyPair,
    };
    use scalpel_client::remote::{Credentials, Observer};
    use std::time::Duration;

    let dir = station::scratch("roleless");
    station::make_lab_ca(&dir);
    // "visitor": no role the station knows.
    let ca_key = KeyPair::from_pem(&std::fs::read_to_string(dir.join("ca.key")).unwrap()).unwrap();
    let issuer = Issuer::from_ca_cert_pem(
        &std::fs::read_to_string(dir.join("ca.pem")).unwrap(),
        ca_key,
    )
    .unwrap();
    let mut params = CertificateParams::new(Vec::<String>::new()).unwrap();
    let mut dn = DistinguishedName::new();
    dn.push(DnType::OrganizationalUnitName, "visitor");
    dn.push(DnType::CommonName, "vic");
    params.distinguished_name = dn;
    params.extended_key_usages = vec![ExtendedKeyUsagePurpose::ClientAuth];
    let key = KeyPair::generate().unwrap();
    let cert = params.signed_by(&key, &issuer).unwrap();
    std::fs::write(dir.join("vic.pem"), cert.pem()).unwrap();
    std::fs::write(dir.join("vic.key"), key.serialize_pem()).unwrap();

    let scene = station::write_observed_scene(&dir);
    let config = dir.join("server.toml");
    std::fs::write(
        &config,
        format!(
            "station = \"{}\"\nscene = \"{}\"\n[rates]\nstatus_interval_s = 0.25\n[network]\nlisten = \"127.0.0.1:0\"\ncerts = \"{}\"\n",
            unique_station("roleless"),
            scene.display(),
            dir.display()
        ),
    )
    .unwrap();
    let mut command = Command::new(station::server_binary());
    command.arg(&config).args(["--json", "--duration", "60"]);
    let mut server = Running::start(command);
    let runs = server.wait_for(Duration::from_secs(60), |l| {
        json(l)["event"]
            .as_str()
            .is_some_and(|e| e.starts_with("runs:"))
    });
    let addr: std::net::SocketAddr = json(&runs)["event"]
        .as_str()
        .unwrap()
        .split("network endpoint on ")
        .nth(1)
        .and_then(|s| s.split([',', ';']).next())
        .unwrap()
        .trim()
        .parse()
        .unwrap();
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .unwrap();
    let refused = runtime.block_on(Observer::connect(
        addr,
        "localhost",
        &Credentials::from_dir(&dir, "vic"),
        "vic",
    ));
    assert!(refused.is_err(), "a certificate with no role got in");
    server.wait_for(Duration::from_secs(5), |l| {
        json(l)["event"].as_str().is_some_and(|e| {
            e.starts_with("network: refused 127.0.0.1: certificate refused")
                && e.contains("names no role")
        })
    });
    server.kill_9();
    std::fs::remove_dir_all(&dir).ok();
}
