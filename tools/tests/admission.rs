//! Issue 45: a QUIC handshake started and never finished used to take a connection's place
//! until the idle timeout, so a trickle of Initial packets from a few addresses kept every
//! observer out (15 of 15 refused). A flood of unfinished handshakes — Initials never
//! followed up, and handshakes that answer the Retry and then stall — from three addresses,
//! while a real observer (mutual TLS against the lab's CA) connects 20 times against the
//! real server process: 20 of 20 admitted, and the station says what it refused.

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
