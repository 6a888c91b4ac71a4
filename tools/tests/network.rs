//! Remote clients over real QUIC with TLS, against the real server process: a lab CA and
//! certificates made with `scalpel certs`, observers receiving metrics, events and frames,
//! a client without a certificate refused, an observer certificate that cannot instruct,
//! and a malformed message that closes only its own connection.

mod common;

use std::net::SocketAddr;
use std::path::Path;
use std::time::Duration;

use common::station::{self, Running, json, scalpel, unique_station};
use scalpel_client::remote::{
    ClientError, Credentials, Instructor, Observer, Session, Update, client_config,
};
use scalpel_proto::codec::{CLIENT_LIMIT, write_frame};
use scalpel_proto::wire::{Action, ClientMessage, Outcome, PROTOCOL_VERSION};

/// A lab: CA, server certificate, two observers and an instructor.
fn make_certs(dir: &Path) {
    let run = |args: &[&str]| {
        let out = scalpel().args(args).output().unwrap();
        assert!(
            out.status.success(),
            "scalpel {args:?}: {}",
            String::from_utf8_lossy(&out.stderr)
        );
    };
    station::make_lab_ca(dir);
    let d = dir.to_str().unwrap();
    for (role, name) in [
        ("observer", "obs1"),
        ("observer", "obs2"),
        ("instructor", "ann"),
    ] {
        run(&["certs", "issue", "--dir", d, "--role", role, "--name", name]);
    }
}

/// Starts a server with the QUIC endpoint on a free port (and the in-process scripted
/// device); returns it and the address.
fn start(dir: &Path, station: &str) -> (Running, SocketAddr) {
    start_with(dir, station, "", &[])
}

/// [`start`] with more configuration (TOML sections) and arguments.
fn start_with(dir: &Path, station: &str, more: &str, args: &[&str]) -> (Running, SocketAddr) {
    let scene = station::write_observed_scene(dir);
    let config = dir.join("server.toml");
    std::fs::write(
        &config,
        format!(
            "station = \"{station}\"\nscene = \"{}\"\n[rates]\nstatus_interval_s = 0.25\n[network]\nlisten = \"127.0.0.1:0\"\ncerts = \"{}\"\n{more}",
            scene.display(),
            dir.display()
        ),
    )
    .unwrap();
    let mut command = std::process::Command::new(station::server_binary());
    command
        .arg(&config)
        .args(["--json", "--duration", "120"])
        .args(args);
    let mut server = Running::start(command);
    let runs = server.wait_for(Duration::from_secs(60), |l| {
        json(l)["event"]
            .as_str()
            .is_some_and(|e| e.starts_with("runs:"))
    });
    let event = json(&runs)["event"].as_str().unwrap().to_string();
    let addr = event
        .split("network endpoint on ")
        .nth(1)
        .and_then(|s| s.split([',', ';']).next())
        .unwrap_or_else(|| panic!("no endpoint in {event}"))
        .trim()
        .parse()
        .unwrap();
    (server, addr)
}

#[test]
fn a_client_with_no_station_at_its_address_gives_up_and_says_why() {
    let dir = station::scratch("network-nobody");
    make_certs(&dir);
    // A port that takes datagrams and never answers (a host whose station is down, or a
    // firewall that drops them): QUIC's idle timeout alone kept the CLI waiting 30 s and
    // then said only "timed out".
    let silent = std::net::UdpSocket::bind("127.0.0.1:0").unwrap();
    let addr = silent.local_addr().unwrap().to_string();
    for args in [["instruct", "ann", "list"], ["observe", "obs1", "--plain"]] {
        let asked = std::time::Instant::now();
        let out = scalpel()
            .args([args[0], &addr, "--certs"])
            .arg(&dir)
            .args(["--name", args[1], args[2]])
            .output()
            .unwrap();
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success(), "{args:?}");
        assert!(
            stderr.contains(&format!("no answer from {addr} within 10 s"))
                && stderr.contains("network.listen"),
            "{args:?}: {stderr}"
        );
        // Well before the 30 s of the idle timeout (the bound is 10 s; the rest is room for
        // a busy machine).
        assert!(asked.elapsed() < Duration::from_secs(25), "{args:?}");
    }
}

#[test]
fn observers_get_metrics_events_and_frames_and_nothing_else_gets_in() {
    let dir = station::scratch("network");
    make_certs(&dir);
    let name = unique_station("net");
    let (mut server, addr) = start(&dir, &name);

    // The terminal observer, as a user runs it.
    let out = scalpel()
        .args(["observe", &addr.to_string(), "--certs"])
        .arg(&dir)
        .args(["--name", "obs1", "--frames", "--seconds", "5", "--json"])
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{stdout}{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let lines: Vec<serde_json::Value> = stdout.lines().map(json).collect();
    assert_eq!(lines[0]["welcome"]["role"], "Observer", "{stdout}");
    assert_eq!(lines[0]["welcome"]["identity"], "obs1");
    let metrics = lines.iter().filter(|l| l.get("metrics").is_some()).count();
    assert!(metrics >= 20, "{metrics} metrics in 5 s (10 Hz)");
    // The demo cut ruptures the liver about 2 s in: the event gives the force the tissue
    // gave way at (issue 45: it always said 0.0 N, the force after the drop).
    let rupture = lines
        .iter()
        .find_map(|l| {
            let e = l.get("event").filter(|e| e["kind"] == "Rupture")?;
            e["detail"].as_str().map(str::to_string)
        })
        .unwrap_or_else(|| panic!("no rupture in 5 s: {stdout}"));
    let newtons: f64 = rupture
        .strip_prefix("rupture: cutting, at ")
        .and_then(|r| r.split(' ').next())
        .and_then(|n| n.parse().ok())
        .unwrap_or_else(|| panic!("{rupture}"));
    assert!(newtons > 0.5, "{rupture}");
    let frames: Vec<&serde_json::Value> = lines.iter().filter_map(|l| l.get("frame")).collect();
    assert!(frames.len() >= 30, "{} frames in 3 s", frames.len());
    assert!(frames.iter().all(|f| f["vertices"].as_u64().unwrap() > 200));

    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .unwrap();
    runtime.block_on(async {
        // No client certificate: refused.
        let ca = dir.join("ca.pem");
        let config = client_config(None, &ca).unwrap();
        let refused = Session::connect(addr, "localhost", config, "anonymous").await;
        assert!(refused.is_err(), "a client without a certificate got in");

        // A Hello whose client name is over 256 bytes is refused as such (issue 45: it was
        // "the first message must be a Hello"). The SDK shortens names: a raw client.
        let mut raw = quinn::Endpoint::client("127.0.0.1:0".parse().unwrap()).unwrap();
        raw.set_default_client_config(
            client_config(Some(&Credentials::from_dir(&dir, "obs1")), &ca).unwrap(),
        );
        let conn = raw.connect(addr, "localhost").unwrap().await.unwrap();
        let (mut send, _recv) = conn.open_bi().await.unwrap();
        let hello = ClientMessage::Hello {
            protocol_version: PROTOCOL_VERSION,
            client: "n".repeat(300),
        };
        write_frame::<_, CLIENT_LIMIT>(&mut send, &hello).await.unwrap();
        let closed = conn.closed().await.to_string();
        assert!(
            closed.contains("the client name is 300 bytes, at most 256"),
            "{closed}"
        );

        // An observer cannot instruct.
        let mut observer = Observer::connect(
            addr,
            "localhost",
            &Credentials::from_dir(&dir, "obs2"),
            "obs2",
        )
        .await
        .unwrap();
        let (outcome, _) = observer.0.command(Action::List).await.unwrap();
        assert!(
            matches!(&outcome, Outcome::Rejected { reason } if reason.contains("observer")),
            "{outcome:?}"
        );
        // Nor can it flood the log and the journal with its refusals (below).
        for _ in 0..100 {
            let (outcome, _) = observer.0.command(Action::List).await.unwrap();
            assert!(matches!(&outcome, Outcome::Rejected { .. }), "{outcome:?}");
        }

        // An instructor's replayed command is refused; a flood is cut off by the rate limit.
        let mut ann = Instructor::connect(
            addr,
            "localhost",
            &Credentials::from_dir(&dir, "ann"),
            "ann",
        )
        .await
        .unwrap();
        let (outcome, faults) = ann.list().await.unwrap();
        assert_eq!((outcome, faults.len()), (Outcome::Listed, 0));
        ann.0.set_next_seq(1);
        let (outcome, _) = ann.list().await.unwrap();
        assert!(
            matches!(&outcome, Outcome::Rejected { reason } if reason.contains("replayed")),
            "{outcome:?}"
        );
        ann.0.set_next_seq(2);
        let mut limited = 0;
        for _ in 0..30 {
            if let (Outcome::Rejected { reason }, _) = ann.list().await.unwrap() {
                assert!(reason.contains("rate limit"), "{reason}");
                limited += 1;
            }
        }
        // A burst of 20 (two used above), refilled at 10 a second while the flood lasts.
        assert!((1..=20).contains(&limited), "{limited} of 30 refused");

        // Issue 45: one command with seq u64::MAX used to lock its identity out until the
        // station restarted. Sequence numbers are the connection's now.
        tokio::time::sleep(Duration::from_secs(3)).await; // the rate limit's bucket refills
        let mut top = Instructor::connect(
            addr,
            "localhost",
            &Credentials::from_dir(&dir, "ann"),
            "ann-top",
        )
        .await
        .unwrap();
        top.0.set_next_seq(u64::MAX);
        assert_eq!(top.list().await.unwrap().0, Outcome::Listed);
        top.0.set_next_seq(5);
        let (outcome, _) = top.list().await.unwrap();
        assert!(
            matches!(&outcome, Outcome::Rejected { reason } if reason.contains("outside the window")),
            "{outcome:?}"
        );
        // The same identity's other connection, and a new one, go on.
        assert_eq!(ann.list().await.unwrap().0, Outcome::Listed);
        let mut again = Instructor::connect(
            addr,
            "localhost",
            &Credentials::from_dir(&dir, "ann"),
            "ann-again",
        )
        .await
        .unwrap();
        assert_eq!(again.list().await.unwrap().0, Outcome::Listed);
        drop((top, again));

        // Eight observers at once all get metrics.
        let mut many = Vec::new();
        for k in 0..8 {
            let name = if k % 2 == 0 { "obs1" } else { "obs2" };
            many.push(
                Observer::connect(addr, "localhost", &Credentials::from_dir(&dir, name), name)
                    .await
                    .unwrap(),
            );
        }
        for o in &mut many {
            let got = tokio::time::timeout(Duration::from_secs(2), async {
                loop {
                    if let Some(Update::Metrics(m)) = o.0.next().await {
                        return m;
                    }
                }
            })
            .await
            .expect("metrics within 2 s");
            assert!(got.sim_tick > 0);
        }

        // A malformed message closes that connection only.
        let mut bad = Observer::connect(
            addr,
            "localhost",
            &Credentials::from_dir(&dir, "obs1"),
            "bad",
        )
        .await
        .unwrap();
        bad.0
            .send_raw(&[3, 0, 0, 0, 0xff, 0xff, 0xff])
            .await
            .unwrap();
        let why = tokio::time::timeout(Duration::from_secs(3), bad.0.closed())
            .await
            .expect("the server closes a connection that sent garbage");
        assert!(why.contains("control stream"), "{why}");
        // An oversized one too.
        let mut big = Observer::connect(
            addr,
            "localhost",
            &Credentials::from_dir(&dir, "obs1"),
            "big",
        )
        .await
        .unwrap();
        big.0.send_raw(&(10u32 << 20).to_le_bytes()).await.unwrap();
        let why = tokio::time::timeout(Duration::from_secs(3), big.0.closed())
            .await
            .expect("the server closes a connection that announced 10 MB");
        assert!(why.contains("limit"), "{why}");
        // A frame rate near zero (a period of centuries panicked the frame loop, and the
        // session never gave its place in the per-address limit back): refused, and more
        // such connections than the limit of 16 from one address leave it open.
        for _ in 0..20 {
            let mut slow = Observer::connect(
                addr,
                "localhost",
                &Credentials::from_dir(&dir, "obs1"),
                "slow",
            )
            .await
            .expect("a place in the limit is free again");
            slow.0.subscribe(1e-30).await.unwrap();
            let why = tokio::time::timeout(Duration::from_secs(3), slow.0.closed())
                .await
                .expect("the server closes a connection that asked for 1e-30 Hz");
            assert!(
                why.contains("frame_hz") && why.contains("at least 0.1"),
                "{why}"
            );
        }
        // The others are still served.
        for o in &mut many {
            let got = tokio::time::timeout(Duration::from_secs(2), o.0.next())
                .await
                .expect("still served");
            assert!(got.is_some());
        }
        // Past the limit of 16 from one address (ten are open here), a client is told why
        // (QUIC's refusal carries no reason; it said "the server refused to accept a new
        // connection").
        let mut more = Vec::new();
        let refusal = loop {
            match Observer::connect(addr, "localhost", &Credentials::from_dir(&dir, "obs1"), "more")
                .await
            {
                Ok(o) => more.push(o),
                Err(e) => break e,
            }
            assert!(more.len() <= 16, "no limit");
        };
        assert!(
            matches!(&refusal, ClientError::Refused(why) if why.contains("network.max_per_address")),
            "{refusal}"
        );
        drop(more);
        let _ = ClientError::Setup(String::new());
    });
    // And the station never stopped ticking.
    server.assert_ticking();
    // The client without a certificate left a line in the station's log (issue 45: a
    // refused TLS handshake left none).
    let tls_refused = |l: &str| {
        json(l)["event"]
            .as_str()
            .is_some_and(|e| e.starts_with("network: refused 127.0.0.1: TLS handshake failed"))
    };
    if !server.seen.iter().any(|l| tls_refused(l)) {
        server.wait_for(Duration::from_secs(5), tls_refused);
    }
    // obs2's 101 refused commands: the first ones written out one by one, the rest of the
    // flood counted and said in summaries (once a second; some may be out already).
    let obs2 = |line: &str| {
        json(line)["event"]
            .as_str()
            .filter(|e| e.starts_with("observer obs2: ") || e.starts_with("client obs2: "))
            .map(str::to_string)
    };
    let tally = |seen: &[String]| {
        let events: Vec<String> = seen.iter().filter_map(|l| obs2(l)).collect();
        let one_by_one = events.iter().filter(|e| e.contains(": command ")).count();
        let counted: usize = events
            .iter()
            .filter(|e| e.contains("more commands refused"))
            .filter_map(|e| {
                e.split(": ")
                    .nth(1)?
                    .split(' ')
                    .next()?
                    .parse::<usize>()
                    .ok()
            })
            .sum();
        (one_by_one, counted)
    };
    let waited = std::time::Instant::now();
    while tally(&server.seen).0 + tally(&server.seen).1 < 101 {
        assert!(
            waited.elapsed() < Duration::from_secs(5),
            "obs2's refusals: {:?}",
            tally(&server.seen)
        );
        server.wait_for(Duration::from_secs(5), |l| obs2(l).is_some());
    }
    let (one_by_one, counted) = tally(&server.seen);
    // The burst of 20, and 2 a second while the flood lasted; the rest counted.
    assert!(one_by_one >= 20 && counted > 0, "{one_by_one} + {counted}");
    assert_eq!(one_by_one + counted, 101);
    server.kill_9();
    std::fs::remove_dir_all(&dir).ok();
}

/// A third-party QUIC stack (Python aioquic, which `.ci/run` installs in its venv) completes
/// the handshake with a lab certificate and decodes a Welcome, a Metrics and a keyframe
/// with nothing but docs/PROTOCOL.md (tools/tests/python/quic_observer.py).
#[test]
#[ignore = "needs aioquic; .ci/run installs it and runs this"]
fn python_aioquic_observes_a_station() {
    let dir = station::scratch("aioquic");
    make_certs(&dir);
    let name = unique_station("aq");
    let (mut server, addr) = start(&dir, &name);
    let found = station::run_python(
        "quic_observer.py",
        &[
            addr.ip().to_string(),
            addr.port().to_string(),
            dir.display().to_string(),
            "obs1".into(),
            "20".into(),
        ],
    );
    assert_eq!(found["welcome"]["station"], name.as_str(), "{found}");
    assert_eq!(found["welcome"]["role"], "Observer");
    assert!(
        found["metrics"]["sim_tick"].as_u64().unwrap() > 0,
        "{found}"
    );
    let frame = &found["frame"];
    let vertices = frame["vertices"].as_u64().unwrap();
    assert!(
        vertices > 200 && frame["max_index"].as_u64().unwrap() < vertices,
        "{found}"
    );
    for (axis, half) in [(0, 125.0), (1, 75.0), (2, 25.0)] {
        let lo = frame["bbox_mm"][0][axis].as_f64().unwrap();
        let hi = frame["bbox_mm"][1][axis].as_f64().unwrap();
        assert!(
            (lo + half).abs() < 5.0 && (hi - half).abs() < 5.0,
            "{found}"
        );
    }
    server.kill_9();
    std::fs::remove_dir_all(&dir).ok();
}

/// What the test saw of one fault window, on the station clock (ms).
#[derive(Debug, Clone, Copy)]
struct Window {
    start: u64,
    end: u64,
}

/// A row of the mock device's recording.
#[derive(Debug, Clone, Copy)]
struct ForceRow {
    seq: u64,
    force: [f64; 3],
    force_n: f64,
    faded: bool,
    /// The station tick of the force.
    tick: u64,
    pose_seq: u64,
}

fn read_forces(csv: &Path) -> Vec<ForceRow> {
    let text = std::fs::read_to_string(csv).unwrap();
    text.lines()
        .skip(1)
        .map(|l| {
            let c: Vec<f64> = l
                .split(',')
                .map(|x| x.parse().unwrap_or(f64::NAN))
                .collect();
            ForceRow {
                seq: c[1] as u64,
                force: [c[5], c[6], c[7]],
                force_n: (c[5] * c[5] + c[6] * c[6] + c[7] * c[7]).sqrt(),
                faded: (c[9] as u32) & 1 == 1,
                tick: c[10] as u64,
                pose_seq: c[11] as u64,
            }
        })
        .filter(|r| r.tick > 0)
        .collect()
}

/// What one observer received, stamped with the station tick it arrived at.
#[derive(Debug, Default)]
struct Seen {
    /// (arrival tick, metrics).
    metrics: Vec<(u64, scalpel_proto::wire::Metrics)>,
    /// (arrival tick, tick the simulation wrote it, tool tip y in mm).
    frames: Vec<(u64, u64, Option<f64>)>,
    events: Vec<scalpel_proto::wire::Event>,
}

/// The whole set-up of the issue, with real processes: a server with the QUIC endpoint and a
/// shared-memory device, the mock device cutting, two viewers, eight observers and an
/// instructor (the `scalpel instruct` CLI). The instructor schedules every fault of the
/// vocabulary at its own station tick; each has the effect docs/PROTOCOL.md ("Faults")
/// documents, as seen by the mock device, the observers and a renderer, and the output
/// stage's limits hold throughout.
#[test]
fn every_fault_has_its_documented_effect_and_the_limits_hold() {
    use scalpel_proto::wire::EventKind;
    let dir = station::scratch("faults");
    make_certs(&dir);
    let name = unique_station("flt");
    let journal = dir.join("faults.journal");
    let (mut server, addr) = start_with(
        &dir,
        &name,
        "[device]\nkind = \"shared_memory\"\n",
        &["--journal", journal.to_str().unwrap()],
    );
    let clock = server.wait_for(Duration::from_secs(10), |l| {
        json(l)["event"]
            .as_str()
            .is_some_and(|e| e.starts_with("clock:"))
    });
    let origin_ns: u64 = json(&clock)["event"]
        .as_str()
        .unwrap()
        .split("CLOCK_MONOTONIC ")
        .nth(1)
        .and_then(|s| s.split(' ').next())
        .unwrap()
        .parse()
        .unwrap();
    let station_now =
        move || scalpel_client::frame_reader::monotonic_ns().saturating_sub(origin_ns) / 1_000_000;

    // The device: the liver's demo stroke at 3 mm/s (20 s of steady cutting, room for the
    // ten windows), recorded.
    let liver = scalpel_sim::scene::build_scene(
        &scalpel_sim::scene::builtin("liver").unwrap(),
        None,
        &mut scalpel_sim::progress::Silent,
    )
    .unwrap();
    let stroke =
        scalpel_sim::pipeline::CutScript::stroke_for(&liver.model.surface, 0.06, 0.01, 0.003)
            .unwrap();
    let script = dir.join("stroke.csv");
    std::fs::write(&script, common::conformance::script_csv(&stroke)).unwrap();
    let forces_csv = dir.join("forces.csv");
    let mut mock = scalpel();
    mock.args([
        "mock-device",
        "--station",
        &name,
        "--duration",
        "26",
        "--script",
    ])
    .arg(&script)
    .arg("--out")
    .arg(&forces_csv);
    let mock = Running::start(mock);
    server.wait_for(Duration::from_secs(20), |l| {
        json(l)["event"]
            .as_str()
            .is_some_and(|e| e.starts_with("device connected"))
    });
    // Two viewers, headless, attached all along.
    let viewers: Vec<Running> = (0..2)
        .map(|k| {
            let mut v = scalpel();
            v.args([
                "view",
                "--station",
                &name,
                "--after",
                "700",
                "--timeout",
                "60",
            ])
            .arg("--snapshot")
            .arg(dir.join(format!("viewer{k}.png")));
            Running::start(v)
        })
        .collect();
    // A renderer of the test's own, to see exactly when frames stop and start.
    let stop = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
    let renderer = {
        let (name, stop) = (name.clone(), stop.clone());
        std::thread::spawn(move || {
            let mut reader = scalpel_client::frame_reader::FrameReader::open(&name).unwrap();
            let mut arrivals = Vec::new();
            while !stop.load(std::sync::atomic::Ordering::Relaxed) {
                if let Ok(Some(_)) = reader.wait(Duration::from_millis(50)) {
                    arrivals.push(station_now());
                }
            }
            arrivals
        })
    };

    // Eight observers, frames at 30 Hz, on a thread of their own.
    let seen: Vec<std::sync::Arc<std::sync::Mutex<Seen>>> = (0..8)
        .map(|_| std::sync::Arc::new(std::sync::Mutex::new(Seen::default())))
        .collect();
    let observing = {
        let (seen, stop, dir) = (seen.clone(), stop.clone(), dir.clone());
        std::thread::spawn(move || {
            let runtime = tokio::runtime::Builder::new_current_thread()
                .enable_all()
                .build()
                .unwrap();
            runtime.block_on(async move {
                for (k, log) in seen.into_iter().enumerate() {
                    let who = if k % 2 == 0 { "obs1" } else { "obs2" };
                    let mut o = Observer::connect(
                        addr,
                        "localhost",
                        &Credentials::from_dir(&dir, who),
                        who,
                    )
                    .await
                    .unwrap();
                    o.0.subscribe(30.0).await.unwrap();
                    tokio::spawn(async move {
                        while let Some(u) = o.0.next().await {
                            let at = station_now();
                            let mut s = log.lock().unwrap();
                            match u {
                                Update::Metrics(m) => s.metrics.push((at, m)),
                                Update::Frame(f) => s.frames.push((
                                    at,
                                    f.server_time_ns.saturating_sub(origin_ns) / 1_000_000,
                                    f.tool.map(|t| f64::from(t.tip_m[1]) * 1e3),
                                )),
                                Update::Event(e) => s.events.push(e),
                            }
                        }
                    });
                }
                while !stop.load(std::sync::atomic::Ordering::Relaxed) {
                    tokio::time::sleep(Duration::from_millis(20)).await;
                }
            });
        })
    };
    // Wait for steady cutting (the demo cut ruptures about a second after entry).
    let steady = || {
        let s = seen[0].lock().unwrap();
        s.metrics.len() > 10
            && s.metrics[s.metrics.len() - 10..]
                .iter()
                .all(|(_, m)| m.force_n > 1.0 && m.cut_length_mm > 2.0)
    };
    let waited = std::time::Instant::now();
    while !steady() {
        assert!(waited.elapsed() < Duration::from_secs(20), "no steady cut");
        std::thread::sleep(Duration::from_millis(50));
    }

    // The instructor schedules the vocabulary, one window each, with the CLI (ten runs,
    // each with a TLS handshake; a debug build's too: five seconds is room enough on a
    // busy machine).
    let t = station_now() + 5000;
    let plan: [(&[&str], u64, u64); 10] = [
        (
            &["tissue-stiffness", "--factor", "3", "--ramp-ms", "100"],
            0,
            700,
        ),
        (&["force-spike", "--newtons", "100"], 1000, 400),
        (&["force-saturation", "--max-n", "1"], 1700, 400),
        (&["device-latency", "--ms", "50"], 2400, 500),
        (&["pose-noise", "--sigma-mm", "2"], 3200, 500),
        (&["device-dropout"], 4000, 400),
        (&["sim-stall"], 4700, 400),
        (&["sim-slowdown", "--factor", "4"], 5400, 800),
        (&["renderer-freeze"], 6500, 400),
        (&["observer-stream-loss"], 7200, 400),
    ];
    let mut windows = Vec::new();
    for (args, offset, ms) in plan {
        let out = scalpel()
            .args(["instruct", &addr.to_string(), "--certs"])
            .arg(&dir)
            .args(["--name", "ann", "fault"])
            .args(args)
            .args(["--at", &(t + offset).to_string()])
            .args(["--duration-ms", &ms.to_string()])
            .output()
            .unwrap();
        let text = String::from_utf8_lossy(&out.stdout);
        assert!(
            out.status.success() && text.starts_with("scheduled: fault"),
            "{args:?}: {text}{}",
            String::from_utf8_lossy(&out.stderr)
        );
        windows.push(Window {
            start: t + offset,
            end: t + offset + ms,
        });
    }
    assert!(
        station_now() < t,
        "scheduling took too long to test the first window"
    );
    let listed = scalpel()
        .args(["instruct", &addr.to_string(), "--certs"])
        .arg(&dir)
        .args(["--name", "ann", "--json", "list"])
        .output()
        .unwrap();
    let listed = json(String::from_utf8_lossy(&listed.stdout).trim());
    assert_eq!(
        listed["faults"].as_array().map(Vec::len),
        Some(10),
        "{listed}"
    );
    assert!(
        listed["faults"]
            .as_array()
            .unwrap()
            .iter()
            .all(|f| f["by"] == "ann")
    );
    // Until the last window has been over for a while.
    while station_now() < t + 8300 {
        std::thread::sleep(Duration::from_millis(50));
    }
    stop.store(true, std::sync::atomic::Ordering::Relaxed);
    let frames_rendered = renderer.join().unwrap();
    observing.join().unwrap();
    // The device stops as a user stops it (Ctrl-C): it writes its recording and exits.
    let (status, _) = mock.interrupt();
    assert!(status.success(), "the mock device failed");
    for v in viewers {
        let (status, lines) = v.finish();
        assert!(status.success(), "a viewer failed: {lines:?}");
    }
    for k in 0..2 {
        assert!(dir.join(format!("viewer{k}.png")).is_file());
    }
    let forces = read_forces(&forces_csv);
    let w = |k: usize| windows[k];
    let rows = |from: u64, to: u64| forces.iter().filter(move |r| (from..to).contains(&r.tick));
    let mean = |from: u64, to: u64| {
        let v: Vec<f64> = rows(from, to).map(|r| r.force_n).collect();
        v.iter().sum::<f64>() / v.len().max(1) as f64
    };

    // The output stage's limits hold over the whole run, every fault included (to the
    // recording's five decimals).
    const CSV: f64 = 1e-4;
    // Each force sample once (a row repeats the last sample until a new one comes; the
    // device zeroes a sample that is 10 ms old by itself, which is its own safety, not the
    // server's output).
    let mut samples = forces.clone();
    samples.dedup_by_key(|r| r.tick);
    for pair in samples.windows(2) {
        let (a, b) = (pair[0], pair[1]);
        assert!(b.force_n <= 3.3 + CSV, "{b:?}");
        // The change of the force vector, direction included.
        let step = (0..3)
            .map(|i| (b.force[i] - a.force[i]).powi(2))
            .sum::<f64>()
            .sqrt();
        let ticks = b.tick.saturating_sub(a.tick).max(1) as f64;
        assert!(step <= 0.5 * ticks + CSV, "{a:?} -> {b:?}");
    }
    let baseline = mean(t - 500, t);
    assert!(
        baseline > 1.0,
        "cutting force before the faults: {baseline} N"
    );

    // Tissue stiffness ×3: the blade rubs on stiffer walls, the force rises.
    let stiff = mean(w(0).start + 150, w(0).end);
    assert!(
        stiff > baseline * 1.15,
        "stiffness ×3: {stiff} N against {baseline} N"
    );
    // Force spike of 100 N: the device gets F_max, no more (checked above), rate-limited.
    let peak = rows(w(1).start, w(1).end)
        .map(|r| r.force_n)
        .fold(0.0, f64::max);
    assert!(peak > 3.2, "the spike should reach F_max: {peak} N");
    // Saturation at 1 N: after the rate-limited descent, at most 1 N.
    let sat = rows(w(2).start + 20, w(2).end)
        .map(|r| r.force_n)
        .fold(0.0, f64::max);
    assert!(sat <= 1.0 + CSV, "saturated at 1 N: {sat} N");
    // Latency of 50 ms: the force answers a pose 50 samples old.
    let lag = |from: u64, to: u64| {
        let mut v: Vec<u64> = rows(from, to)
            .map(|r| r.seq.saturating_sub(r.pose_seq))
            .collect();
        v.sort_unstable();
        v[v.len() / 2]
    };
    assert!(
        (45..=56).contains(&lag(w(3).start + 80, w(3).end)),
        "{}",
        lag(w(3).start + 80, w(3).end)
    );
    assert!(lag(t - 500, t) <= 3, "{}", lag(t - 500, t));
    eprintln!(
        "device: baseline {baseline:.3} N, stiffness ×3 {stiff:.3} N, spike peak {peak:.3} N, saturated {sat:.3} N, lag {} samples",
        lag(w(3).start + 80, w(3).end)
    );
    // Dropout: the force fades to zero within the watchdog's 5 ms and its 5 ms fade.
    assert!(rows(w(5).start + 15, w(5).end).all(|r| r.faded && r.force_n == 0.0));
    // Stall: no new force model; the watchdog fades the force after its 100 ms.
    assert!(rows(w(6).start + 120, w(6).end).all(|r| r.faded && r.force_n == 0.0));
    // And it all came back after the last window.
    assert!(
        mean(t + 7800, t + 8100) > 0.5,
        "force after the faults: {}",
        mean(t + 7800, t + 8100)
    );

    for (k, log) in seen.iter().enumerate() {
        let s = log.lock().unwrap();
        // What arrived when (delivery), and what was made when (the metrics' station
        // tick, the frames' write time): under load a message made before a window can
        // arrive inside it.
        let metrics_in = |from: u64, to: u64| {
            s.metrics
                .iter()
                .filter(move |(at, _)| (from..to).contains(at))
        };
        let frames_in = |from: u64, to: u64| {
            s.frames
                .iter()
                .filter(move |(at, _, _)| (from..to).contains(at))
        };
        let metrics_made = |from: u64, to: u64| {
            s.metrics
                .iter()
                .filter(move |(_, m)| (from..to).contains(&m.station_tick))
        };
        let frames_made = |from: u64, to: u64| {
            s.frames
                .iter()
                .filter(move |(_, made, _)| (from..to).contains(made))
        };
        // Every fault announced, applied and ended.
        let applied = s
            .events
            .iter()
            .filter(|e| e.kind == EventKind::FaultApplied)
            .count();
        let ended = s
            .events
            .iter()
            .filter(|e| e.kind == EventKind::FaultCleared)
            .count();
        assert_eq!((applied, ended), (10, 10), "observer {k}: {:?}", s.events);
        // Pose noise of 2 mm: the blade in the frames shakes across the stroke (it follows
        // the noisy pose at most 2 mm a tick, so its spread is about 1.2 mm, not 2).
        let spread = |from: u64, to: u64| {
            let y: Vec<f64> = frames_made(from, to).filter_map(|(_, _, y)| *y).collect();
            let m = y.iter().sum::<f64>() / y.len().max(1) as f64;
            (y.iter().map(|v| (v - m).powi(2)).sum::<f64>() / y.len().max(1) as f64).sqrt()
        };
        assert!(
            spread(w(4).start + 50, w(4).end) > 0.5,
            "observer {k}: noise {}",
            spread(w(4).start + 50, w(4).end)
        );
        assert!(
            spread(t - 500, t) < 0.2,
            "observer {k}: {}",
            spread(t - 500, t)
        );
        // Stall: the simulation tick stands still.
        let ticks: Vec<u64> = metrics_made(w(6).start + 15, w(6).end)
            .map(|(_, m)| m.sim_tick)
            .collect();
        assert!(
            ticks.len() >= 2 && ticks.last().unwrap() - ticks[0] <= 1,
            "observer {k}: {ticks:?}"
        );
        // Slowdown ×4: a quarter of the ticks.
        let during: Vec<(u64, u64)> = metrics_made(w(7).start + 50, w(7).end)
            .map(|(_, m)| (m.station_tick, m.sim_tick))
            .collect();
        let (first, last) = (during[0], during[during.len() - 1]);
        let rate = (last.1 - first.1) as f64 / (last.0 - first.0) as f64;
        assert!(
            (0.18..0.33).contains(&rate),
            "observer {k}: {rate} simulated ms per ms"
        );
        // Renderer freeze: no frames reach the observers either (they come from the same
        // shared memory).
        assert_eq!(
            frames_made(w(8).start + 20, w(8).end).count(),
            0,
            "observer {k}"
        );
        // Stream loss: none of the metrics and frames made while it lasts arrive (the
        // station notices within its 10 ms round), but for the latest of each, which goes
        // out when the stream resumes (metrics are sent every 100 ms, frames as they are
        // read, up to 33 ms apart); both are back after it.
        let leaked: Vec<(u64, u64)> = metrics_made(w(9).start + 15, w(9).end - 120)
            .map(|(at, m)| (*at, m.station_tick))
            .collect();
        assert!(
            leaked.is_empty(),
            "observer {k}: metrics (arrived, made) {leaked:?} in {:?}",
            w(9)
        );
        assert_eq!(
            frames_made(w(9).start + 15, w(9).end - 40).count(),
            0,
            "observer {k}"
        );
        assert!(
            metrics_in(w(9).end + 100, w(9).end + 800).count() >= 4,
            "observer {k}"
        );
        assert!(
            frames_in(w(9).end + 100, w(9).end + 800).count() >= 5,
            "observer {k}"
        );
    }
    // Renderer freeze, as a renderer sees it: no frame within the window, frames around it.
    let rendered = |from: u64, to: u64| {
        frames_rendered
            .iter()
            .filter(|&&at| (from..to).contains(&at))
            .count()
    };
    assert_eq!(rendered(w(8).start + 20, w(8).end), 0);
    assert!(rendered(w(8).start - 300, w(8).start) >= 10);
    assert!(rendered(w(8).end + 50, w(8).end + 350) >= 10);

    // The server never stopped ticking.
    server.assert_ticking();
    // Stopped as an operator stops it, its journal replays bit for bit, with every
    // command and who sent it.
    let (status, _) = server.interrupt();
    assert!(status.success());
    let out = scalpel()
        .arg("replay")
        .arg(&journal)
        .arg("--json")
        .output()
        .unwrap();
    let replay = json(String::from_utf8_lossy(&out.stdout).trim());
    assert_eq!(replay["identical"], true, "{replay}");
    let commands = replay["commands"].as_array().unwrap();
    assert_eq!(commands.len(), 11, "ten faults and a list: {replay}");
    assert!(commands.iter().all(|c| c["by"] == "ann"));
    assert!(
        replay["stiffness_changes"].as_u64().unwrap() >= 2,
        "{replay}"
    );
    std::fs::remove_dir_all(&dir).ok();
}
