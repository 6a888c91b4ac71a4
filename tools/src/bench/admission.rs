//! `scalpel bench admission [--attempts N] [--addresses A] [--rate R] [--json]`: a station's
//! QUIC endpoint under a flood of handshakes that never finish, while a legitimate observer
//! connects `N` times (issue 45).
//!
//! The flood comes from `A` loopback addresses (127.0.0.2, .3, ...), `R` new connection
//! attempts a second from each, of two kinds taken in turn: **Initials** — a real client's
//! first packet (a ClientHello), never followed up (no Retry answered); and **stalls** — a
//! client that answers the server's Retry (its address really is its own) and then never
//! finishes the TLS handshake. Both are made by quinn-proto's client state machine; nothing
//! here reads what else the server sends. The figures: how many of the observer's attempts
//! got in, how long each took, and what the server said in its log.
//!
//! With `--target HOST:PORT --certs DIR --name NAME` it floods a station that is already
//! running (another build, for a before/after) instead of starting one.

use std::collections::HashMap;
use std::io::{BufRead, BufReader};
use std::net::{IpAddr, SocketAddr, UdpSocket};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use anyhow::{Context, bail};
use quinn_proto::{ClientConfig, Connection, ConnectionHandle, DatagramEvent, Endpoint};
use scalpel_client::remote::{Credentials, Observer};
use serde::Serialize;

/// A station to flood that is already running.
pub struct Target {
    /// Its QUIC endpoint.
    pub addr: SocketAddr,
    /// The lab's certificate folder (`ca.pem`, and the observer's certificate).
    pub certs: PathBuf,
    /// The observer certificate's name.
    pub name: String,
}

/// What the flood sent and what came back to it.
#[derive(Debug, Default, Serialize)]
struct FloodCounts {
    /// Initials sent and never followed up.
    initials: u64,
    /// Handshakes that answered the server's Retry and then stalled.
    stalls: u64,
    /// Retry packets the flood received.
    retries_received: u64,
}

#[derive(Debug, Serialize)]
struct AdmissionBench {
    /// Whose endpoint: a station this run started, or `--target`'s.
    station: String,
    attempts: usize,
    /// The observer's attempts that got in (its Welcome came).
    admitted: usize,
    /// The first reasons the others were given.
    refusals: Vec<String>,
    /// Time from starting an attempt to the Welcome, over those that got in (ms).
    connect_ms_p50: f64,
    connect_ms_max: f64,
    flood_addresses: usize,
    /// New connection attempts per second from each flooding address.
    flood_rate_per_address: f64,
    flood: FloodCounts,
    /// The station's log lines about refused connections (a station this run started).
    server_refusal_lines: Vec<String>,
}

/// Runs the benchmark.
pub fn run(
    attempts: usize,
    addresses: usize,
    rate: f64,
    target: Option<Target>,
    json: bool,
) -> anyhow::Result<()> {
    if !(1..=1000).contains(&attempts) {
        bail!("--attempts must be between 1 and 1000, got {attempts}");
    }
    if !(1..=200).contains(&addresses) {
        bail!("--addresses must be between 1 and 200 (127.0.0.2 onwards), got {addresses}");
    }
    if !(rate.is_finite() && (1.0..=2000.0).contains(&rate)) {
        bail!("--rate must be between 1 and 2000 attempts a second per address, got {rate}");
    }
    let report = match target {
        Some(t) => {
            check_certs(&t.certs)?;
            measure(&t, attempts, addresses, rate, None)?
        }
        None => with_own_station(attempts, addresses, rate)?,
    };
    super::emit(json, &report, print_report)
}

/// Starts a station with a lab of its own and floods it.
fn with_own_station(
    attempts: usize,
    addresses: usize,
    rate: f64,
) -> anyhow::Result<AdmissionBench> {
    let station = format!("bench-admission-{}", std::process::id());
    let dir = std::env::temp_dir().join(&station);
    std::fs::create_dir_all(&dir)?;
    let result = (|| {
        crate::certs_cmd::init(&dir, &[])?;
        crate::certs_cmd::issue(&dir, "observer", "bench")?;
        let scene = dir.join("scene.toml");
        std::fs::write(
            &scene,
            "extends = \"liver\"\n[features]\nobservers = true\n",
        )?;
        let config = dir.join("server.toml");
        std::fs::write(
            &config,
            format!(
                "station = \"{station}\"\nscene = \"{}\"\n[rates]\nstatus_interval_s = 1.0\n[network]\nlisten = \"127.0.0.1:0\"\ncerts = \"{}\"\n",
                scene.display(),
                dir.display()
            ),
        )?;
        let (mut server, stdout) = super::loop_bench::spawn_server(&config, 600.0)?;
        let lines = Arc::new(Mutex::new(Vec::new()));
        let (addr_tx, addr_rx) = std::sync::mpsc::channel();
        {
            let lines = lines.clone();
            std::thread::spawn(move || {
                for line in BufReader::new(stdout).lines().map_while(Result::ok) {
                    let v: serde_json::Value = serde_json::from_str(&line).unwrap_or_default();
                    let Some(event) = v["event"].as_str() else {
                        continue;
                    };
                    if let Some(addr) = event
                        .split("network endpoint on ")
                        .nth(1)
                        .and_then(|s| s.split([',', ';']).next())
                        .and_then(|s| s.trim().parse::<SocketAddr>().ok())
                    {
                        let _ = addr_tx.send(addr);
                    }
                    if event.starts_with("network:")
                        && let Ok(mut l) = lines.lock()
                    {
                        l.push(event.to_string());
                    }
                }
            });
        }
        let measured = addr_rx
            .recv_timeout(Duration::from_secs(120))
            .context("the server did not report its network endpoint")
            .and_then(|addr| {
                let target = Target {
                    addr,
                    certs: dir.clone(),
                    name: "bench".into(),
                };
                measure(&target, attempts, addresses, rate, Some(&lines))
            });
        let _ = server.kill();
        let _ = server.wait();
        let mut report = measured?;
        report.station = station.clone();
        Ok(report)
    })();
    std::fs::remove_dir_all(&dir).ok();
    result
}

fn measure(
    target: &Target,
    attempts: usize,
    addresses: usize,
    rate: f64,
    server_lines: Option<&Arc<Mutex<Vec<String>>>>,
) -> anyhow::Result<AdmissionBench> {
    let config = scalpel_client::remote::client_config(None, &target.certs.join("ca.pem"))
        .context("the flood's client configuration")?;
    let stop = Arc::new(AtomicBool::new(false));
    let counts = Arc::new(Counters::default());
    let mut flooders = Vec::new();
    for k in 0..addresses {
        let ip = IpAddr::from([127, 0, 0, 2 + k as u8]);
        let socket = UdpSocket::bind((ip, 0))
            .with_context(|| format!("cannot bind {ip} (the flood's source address)"))?;
        let (config, stop, counts, addr) =
            (config.clone(), stop.clone(), counts.clone(), target.addr);
        flooders.push(std::thread::spawn(move || {
            flood(socket, addr, config, rate, &stop, &counts)
        }));
    }
    // The flood is under way before the observer tries.
    std::thread::sleep(Duration::from_secs(2));
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()?;
    let credentials = Credentials::from_dir(&target.certs, &target.name);
    let mut connect_ms = Vec::new();
    let mut refusals = Vec::new();
    for k in 0..attempts {
        let started = Instant::now();
        let result = runtime.block_on(Observer::connect(
            target.addr,
            "localhost",
            &credentials,
            &format!("bench-admission-{k}"),
        ));
        match result {
            Ok(observer) => {
                connect_ms.push(started.elapsed().as_secs_f64() * 1e3);
                drop(observer);
            }
            Err(e) if refusals.len() < 5 => refusals.push(e.to_string()),
            Err(_) => {}
        }
        std::thread::sleep(Duration::from_millis(100));
    }
    stop.store(true, Ordering::Relaxed);
    for f in flooders {
        f.join()
            .map_err(|_| anyhow::anyhow!("a flooding thread panicked"))??;
    }
    let admitted = connect_ms.len();
    let (p50, max) = if connect_ms.is_empty() {
        (f64::NAN, f64::NAN)
    } else {
        let max = connect_ms.iter().copied().fold(0.0, f64::max);
        (super::median(&mut connect_ms), max)
    };
    // The station's summaries come once a second: let the last one arrive.
    std::thread::sleep(Duration::from_millis(1500));
    Ok(AdmissionBench {
        station: target.addr.to_string(),
        attempts,
        admitted,
        refusals,
        connect_ms_p50: p50,
        connect_ms_max: max,
        flood_addresses: addresses,
        flood_rate_per_address: rate,
        flood: FloodCounts {
            initials: counts.initials.load(Ordering::Relaxed),
            stalls: counts.stalls.load(Ordering::Relaxed),
            retries_received: counts.retries.load(Ordering::Relaxed),
        },
        server_refusal_lines: server_lines
            .map(|l| l.lock().map(|l| l.clone()).unwrap_or_default())
            .unwrap_or_default(),
    })
}

#[derive(Default)]
struct Counters {
    initials: AtomicU64,
    stalls: AtomicU64,
    retries: AtomicU64,
}

/// Stalled handshakes are forgotten after this (the server has long given up on them).
const FORGET_AFTER: Duration = Duration::from_secs(10);

/// One flooding address: `rate` new attempts a second until `stop`, Initials and stalls in
/// turn, from one socket and one quinn-proto client endpoint.
fn flood(
    socket: UdpSocket,
    server: SocketAddr,
    config: ClientConfig,
    rate: f64,
    stop: &AtomicBool,
    counts: &Counters,
) -> anyhow::Result<()> {
    socket.set_read_timeout(Some(Duration::from_millis(1)))?;
    let mut endpoint = Endpoint::new(
        Arc::new(quinn_proto::EndpointConfig::default()),
        None,
        false,
        None,
    );
    // The stalls that wait for their Retry, and when each began.
    let mut awaiting_retry: HashMap<ConnectionHandle, (Connection, Instant)> = HashMap::new();
    let mut stalled: Vec<(Connection, Instant)> = Vec::new();
    let period = Duration::from_secs_f64(1.0 / rate);
    let mut next = Instant::now();
    let mut stall_next = false;
    let mut buf = Vec::new();
    let mut datagram = vec![0u8; 65536];
    while !stop.load(Ordering::Relaxed) {
        let now = Instant::now();
        if now >= next {
            next += period;
            let (handle, mut conn) = endpoint
                .connect(now, config.clone(), server, "localhost")
                .context("quinn-proto connect")?;
            send_all(&mut conn, &socket, &mut buf)?;
            if stall_next {
                counts.stalls.fetch_add(1, Ordering::Relaxed);
                awaiting_retry.insert(handle, (conn, now));
            } else {
                counts.initials.fetch_add(1, Ordering::Relaxed);
            }
            stall_next = !stall_next;
        }
        match socket.recv_from(&mut datagram) {
            Ok((n, from)) => {
                let is_retry = n > 0 && datagram[0] & 0xf0 == 0xf0;
                counts
                    .retries
                    .fetch_add(u64::from(is_retry), Ordering::Relaxed);
                let mut response = Vec::new();
                let event = endpoint.handle(
                    Instant::now(),
                    from,
                    None,
                    None,
                    bytes::BytesMut::from(&datagram[..n]),
                    &mut response,
                );
                // A stall answers its Retry (a new Initial, with the token) and nothing
                // after it.
                if let (true, Some(DatagramEvent::ConnectionEvent(handle, event))) =
                    (is_retry, event)
                    && let Some((mut conn, began)) = awaiting_retry.remove(&handle)
                {
                    conn.handle_event(event);
                    while let Some(e) = conn.poll_endpoint_events() {
                        if let Some(back) = endpoint.handle_event(handle, e) {
                            conn.handle_event(back);
                        }
                    }
                    send_all(&mut conn, &socket, &mut buf)?;
                    stalled.push((conn, began));
                }
            }
            Err(e)
                if matches!(
                    e.kind(),
                    std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut
                ) => {}
            Err(e) => return Err(e.into()),
        }
        let now = Instant::now();
        stalled.retain(|(_, began)| now.duration_since(*began) < FORGET_AFTER);
        awaiting_retry.retain(|_, (_, began)| now.duration_since(*began) < FORGET_AFTER);
    }
    Ok(())
}

/// Sends every datagram `conn` has queued.
fn send_all(conn: &mut Connection, socket: &UdpSocket, buf: &mut Vec<u8>) -> anyhow::Result<()> {
    loop {
        buf.clear();
        let Some(t) = conn.poll_transmit(Instant::now(), 1, buf) else {
            return Ok(());
        };
        socket.send_to(&buf[..t.size], t.destination)?;
    }
}

fn print_report(r: &AdmissionBench) {
    println!(
        "admission under a handshake flood ({}): {} of {} observer connections admitted, connect p50 {:.1} ms, max {:.1} ms",
        r.station, r.admitted, r.attempts, r.connect_ms_p50, r.connect_ms_max
    );
    println!(
        "  flood: {} addresses × {} attempts/s: {} Initials never followed up, {} handshakes stalled after the Retry, {} Retry received",
        r.flood_addresses,
        r.flood_rate_per_address,
        r.flood.initials,
        r.flood.stalls,
        r.flood.retries_received
    );
    for why in &r.refusals {
        println!("  refused: {why}");
    }
    for line in &r.server_refusal_lines {
        println!("  station: {line}");
    }
}

/// The lab folder exists and has the CA (for `--target`).
fn check_certs(dir: &Path) -> anyhow::Result<()> {
    let ca = dir.join("ca.pem");
    if !ca.is_file() {
        bail!(
            "{} is missing: --certs must be the lab's certificate folder",
            ca.display()
        );
    }
    Ok(())
}
