//! The QUIC endpoint for remote observers and instructors (quinn on a tokio runtime of its
//! own, on the network thread; nothing here touches the real-time threads). Protocol:
//! `scalpel_proto::wire` and docs/PROTOCOL.md.
//!
//! Security: mutual TLS against the lab's CA, the role from the client certificate, default
//! deny (`tls`). Limits: at most `max_connections` connections and `max_per_address` from
//! one address, 64 KiB per client message, one control stream per connection, no streams
//! opened by clients besides it, an idle connection closed after 3 s. A malformed or
//! oversized message closes only its connection.

pub mod frames;
pub mod session;
pub mod tls;

use std::collections::HashMap;
use std::net::{IpAddr, SocketAddr};
use std::path::Path;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use anyhow::Context;
use scalpel_proto::wire::{Event, Metrics};
use tokio::sync::{broadcast, watch};

use frames::SourceFrame;

/// Events in flight to each observer; a slower one skips (its stream says how many).
const EVENT_QUEUE: usize = 256;

/// How the endpoint runs.
#[derive(Debug, Clone)]
pub struct NetworkParams {
    /// Address to listen on.
    pub listen: SocketAddr,
    /// Folder with `ca.pem`, `server.pem`, `server.key`.
    pub certs: std::path::PathBuf,
    /// Frames per second to observers, at most.
    pub frame_hz: f64,
    /// Connections at once.
    pub max_connections: usize,
    /// Connections at once from one address.
    pub max_per_address: usize,
    /// The station.
    pub station: String,
    /// The scene.
    pub scene: String,
    /// CPUs for the network threads (empty: any); the station keeps them off the haptic
    /// thread's CPU.
    pub cpus: Vec<usize>,
}

/// What the station hands the endpoint; the station keeps the senders.
pub struct NetworkFeeds {
    /// The latest metrics (the main thread updates them at 10 Hz).
    pub metrics: watch::Sender<Metrics>,
    /// Events.
    pub events: broadcast::Sender<Event>,
    /// An observer-stream-loss fault is in effect: no frames, no metrics.
    pub stream_lost: watch::Sender<bool>,
}

/// An instructor's command on its way to the station's fault book (main thread), and
/// where its answer goes.
pub struct CommandRequest {
    /// Who sent it (certificate common name).
    pub by: String,
    /// Their role (from the certificate): the station refuses and journals an observer's.
    pub role: scalpel_proto::wire::Role,
    /// The command.
    pub command: scalpel_proto::wire::Command,
    /// The outcome, and the fault list for `List`.
    pub reply: tokio::sync::oneshot::Sender<(
        scalpel_proto::wire::Outcome,
        Option<Vec<scalpel_proto::wire::ScheduledFault>>,
    )>,
}

/// The running endpoint.
pub struct Network {
    /// Where it listens.
    pub local_addr: SocketAddr,
    /// Feeds for the station to fill.
    pub feeds: NetworkFeeds,
    /// Instructors' commands, for the station to answer.
    pub commands: std::sync::mpsc::Receiver<CommandRequest>,
    stop: watch::Sender<bool>,
    thread: Option<std::thread::JoinHandle<()>>,
}

impl Network {
    /// Stops the endpoint (closing every connection) and waits for its thread.
    pub fn stop(mut self) {
        let _ = self.stop.send(true);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

/// Connections per remote address, shared by the accept loop and the sessions.
#[derive(Default, Clone)]
pub struct AddressCounts(Arc<Mutex<HashMap<IpAddr, usize>>>);

impl AddressCounts {
    /// Counts one more from `ip` unless that makes more than `max`.
    fn admit(&self, ip: IpAddr, max: usize) -> bool {
        let mut m = self.0.lock().unwrap_or_else(|e| e.into_inner());
        let n = m.entry(ip).or_default();
        if *n >= max {
            return false;
        }
        *n += 1;
        true
    }

    fn release(&self, ip: IpAddr) {
        // (Called by `Admitted::drop`.)
        let mut m = self.0.lock().unwrap_or_else(|e| e.into_inner());
        if let Some(n) = m.get_mut(&ip) {
            *n = n.saturating_sub(1);
            if *n == 0 {
                m.remove(&ip);
            }
        }
    }
}

/// Starts the endpoint on its own thread; returns once it listens.
pub fn start(params: NetworkParams) -> anyhow::Result<Network> {
    let tls = tls::server_config(&params.certs)?;
    let (metrics_tx, metrics_rx) = watch::channel(Metrics {
        sim_tick: 0,
        station_tick: 0,
        uptime_s: 0.0,
        haptic_rate_hz: 0.0,
        jitter_p99_ms: 0.0,
        deadline_misses: 0,
        force_n: 0.0,
        faded: true,
        cut_length_mm: 0.0,
        active_points: 0,
        device_connected: false,
    });
    let (events_tx, _) = broadcast::channel(EVENT_QUEUE);
    let (lost_tx, lost_rx) = watch::channel(false);
    let (commands_tx, commands_rx) = std::sync::mpsc::channel();
    let (stop_tx, stop_rx) = watch::channel(false);
    let (ready_tx, ready_rx) = std::sync::mpsc::channel();
    let events = events_tx.clone();
    let thread = std::thread::Builder::new()
        .name("network".into())
        .spawn(move || {
            // Not fatal: the endpoint works anywhere, it just shares CPUs.
            let _ = crate::realtime::pin_thread(&params.cpus);
            let runtime = match tokio::runtime::Builder::new_current_thread()
                .enable_all()
                .build()
            {
                Ok(r) => r,
                Err(e) => {
                    let _ = ready_tx.send(Err(anyhow::anyhow!("tokio runtime: {e}")));
                    return;
                }
            };
            runtime.block_on(async move {
                let endpoint = match endpoint(&params, tls) {
                    Ok(e) => e,
                    Err(e) => {
                        let _ = ready_tx.send(Err(e));
                        return;
                    }
                };
                let _ = ready_tx.send(endpoint.local_addr().map_err(Into::into));
                let (frames_tx, frames_rx) = watch::channel(None);
                let reader = spawn_frame_reader(
                    params.cpus.clone(),
                    params.station.clone(),
                    params.frame_hz,
                    frames_tx,
                    stop_rx.clone(),
                );
                let feeds = SessionFeeds {
                    metrics: metrics_rx,
                    events,
                    frames: frames_rx,
                    stream_lost: lost_rx,
                    commands: commands_tx,
                };
                accept_loop(&endpoint, &params, feeds, stop_rx).await;
                endpoint.close(0u32.into(), b"server stopping");
                endpoint.wait_idle().await;
                let _ = reader.join();
            });
        })
        .context("cannot start the network thread")?;
    let local_addr = ready_rx
        .recv()
        .context("the network thread ended before it listened")??;
    Ok(Network {
        local_addr,
        feeds: NetworkFeeds {
            metrics: metrics_tx,
            events: events_tx,
            stream_lost: lost_tx,
        },
        commands: commands_rx,
        stop: stop_tx,
        thread: Some(thread),
    })
}

fn endpoint(params: &NetworkParams, tls: rustls::ServerConfig) -> anyhow::Result<quinn::Endpoint> {
    let crypto = quinn::crypto::rustls::QuicServerConfig::try_from(tls)
        .context("QUIC needs TLS 1.3 with an initial cipher suite")?;
    let mut config = quinn::ServerConfig::with_crypto(Arc::new(crypto));
    let mut transport = quinn::TransportConfig::default();
    transport
        .max_concurrent_bidi_streams(1u32.into())
        .max_concurrent_uni_streams(0u32.into())
        .max_idle_timeout(Some(
            quinn::IdleTimeout::try_from(Duration::from_secs(3)).context("idle timeout")?,
        ))
        .keep_alive_interval(Some(Duration::from_secs(1)))
        // Frames to observers are sent on streams; the window bounds what one slow observer
        // can leave buffered in the server.
        .send_window(4 * 1024 * 1024)
        .stream_receive_window((scalpel_proto::codec::CLIENT_LIMIT as u32 * 4).into())
        .receive_window((scalpel_proto::codec::CLIENT_LIMIT as u32 * 8).into())
        .datagram_receive_buffer_size(None);
    config.transport_config(Arc::new(transport));
    config
        .max_incoming(params.max_connections.max(1))
        .incoming_buffer_size(64 * 1024)
        .incoming_buffer_size_total(4 * 1024 * 1024);
    quinn::Endpoint::server(config, params.listen)
        .with_context(|| format!("cannot listen on {}", params.listen))
}

/// The endpoint's ends of the station's feeds, cloned into every session.
struct SessionFeeds {
    metrics: watch::Receiver<Metrics>,
    events: broadcast::Sender<Event>,
    frames: watch::Receiver<Option<Arc<SourceFrame>>>,
    stream_lost: watch::Receiver<bool>,
    commands: std::sync::mpsc::Sender<CommandRequest>,
}

async fn accept_loop(
    endpoint: &quinn::Endpoint,
    params: &NetworkParams,
    feeds: SessionFeeds,
    mut stop: watch::Receiver<bool>,
) {
    let counts = AddressCounts::default();
    let open = Arc::new(std::sync::atomic::AtomicUsize::new(0));
    loop {
        let incoming = tokio::select! {
            i = endpoint.accept() => match i { Some(i) => i, None => return },
            _ = stop.changed() => return,
        };
        let ip = incoming.remote_address().ip();
        if open.load(std::sync::atomic::Ordering::Relaxed) >= params.max_connections
            || !counts.admit(ip, params.max_per_address)
        {
            incoming.refuse();
            continue;
        }
        open.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        let context = session::SessionContext {
            station: params.station.clone(),
            scene: params.scene.clone(),
            frame_hz_max: params.frame_hz,
            metrics: feeds.metrics.clone(),
            events: feeds.events.subscribe(),
            frames: feeds.frames.clone(),
            stream_lost: feeds.stream_lost.clone(),
            commands: feeds.commands.clone(),
            stop: stop.clone(),
        };
        let admitted = Admitted {
            counts: counts.clone(),
            open: open.clone(),
            ip,
        };
        tokio::spawn(async move {
            // Released however the session ends, a panic included.
            let _admitted = admitted;
            session::run(incoming, context).await;
        });
    }
}

/// A connection's places in the limits, given back when its session ends.
struct Admitted {
    counts: AddressCounts,
    open: Arc<std::sync::atomic::AtomicUsize>,
    ip: IpAddr,
}

impl Drop for Admitted {
    fn drop(&mut self) {
        self.counts.release(self.ip);
        self.open.fetch_sub(1, std::sync::atomic::Ordering::Relaxed);
    }
}

/// Reads the station's shared-memory frames at up to `frame_hz` into `frames`.
fn spawn_frame_reader(
    cpus: Vec<usize>,
    station: String,
    frame_hz: f64,
    frames: watch::Sender<Option<Arc<SourceFrame>>>,
    stop: watch::Receiver<bool>,
) -> std::thread::JoinHandle<()> {
    std::thread::spawn(move || {
        let _ = crate::realtime::pin_thread(&cpus);
        let mut reader = loop {
            if *stop.borrow() {
                return;
            }
            match scalpel_client::frames::FrameReader::open_as("scalpel-net.frames", &station) {
                Ok(r) => break r,
                Err(_) => std::thread::sleep(Duration::from_millis(200)),
            }
        };
        let period = Duration::from_secs_f64(1.0 / frame_hz.max(1.0));
        let mut next = std::time::Instant::now();
        while !*stop.borrow() {
            match reader.wait(Duration::from_millis(100)) {
                Ok(Some(frame)) if std::time::Instant::now() >= next => {
                    next = std::time::Instant::now() + period;
                    let _ = frames.send(Some(SourceFrame::new(frame)));
                }
                Ok(_) => {}
                // A frame that does not decode is not forwarded; the next one may.
                Err(_) => std::thread::sleep(Duration::from_millis(10)),
            }
        }
    })
}

/// Whether `path` looks like a certificate folder (for the configuration check).
pub fn check_certs(path: &Path) -> anyhow::Result<()> {
    for f in [tls::CA_FILE, tls::SERVER_CERT_FILE, tls::SERVER_KEY_FILE] {
        let p = path.join(f);
        if !p.is_file() {
            anyhow::bail!(
                "{} is missing (make the lab's certificates with `scalpel certs init --dir {}`)",
                p.display(),
                path.display()
            );
        }
    }
    Ok(())
}
