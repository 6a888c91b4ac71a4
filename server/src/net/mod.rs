//! The QUIC endpoint for remote observers and instructors (quinn on a tokio runtime of its
//! own, on the network thread; nothing here touches the real-time threads). Protocol:
//! `scalpel_proto::wire` and docs/PROTOCOL.md.
//!
//! Security: mutual TLS against the lab's CA, the role from the client certificate, default
//! deny (`tls`). Admission (`admission`): an address is validated by a QUIC Retry first,
//! then holds a place in a small budget of handshakes in flight (`max_handshakes`,
//! `max_handshakes_per_address`) until its TLS handshake ends, and only a finished
//! handshake takes one of `max_connections` (`max_per_address` from one address); refusals
//! go to the station's log (`refusal_log`). Limits: 64 KiB per client message, one control
//! stream per connection, no streams opened by clients besides it, an idle connection
//! closed after 3 s. A malformed or oversized message closes only its connection.

pub mod admission;
pub mod observer_frames;
pub mod refusal_log;
pub mod seq_window;
pub mod session;
pub mod tls;

use std::net::SocketAddr;
use std::path::Path;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use anyhow::Context;
use scalpel_proto::wire::{Event, Metrics};
use tokio::sync::{broadcast, watch};

use admission::{Admission, Budgets, HANDSHAKE_TIMEOUT, Refusal};
use observer_frames::SourceFrame;
use refusal_log::RefusalLog;

/// Events in flight to each observer; a slower one skips (its stream says how many).
const EVENT_QUEUE: usize = 256;
/// Connection attempts the endpoint holds before the accept loop decides on them.
const MAX_INCOMING: usize = 1024;

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
    /// TLS handshakes in flight at once.
    pub max_handshakes: usize,
    /// TLS handshakes in flight from one address.
    pub max_handshakes_per_address: usize,
    /// The station.
    pub station: String,
    /// The scene.
    pub scene: String,
    /// CPUs for the network threads (empty: any); the station keeps them off the haptic
    /// thread's CPU.
    pub cpus: Vec<usize>,
    /// The lesson the station runs, sent first to every observer.
    pub lesson: Option<scalpel_proto::wire::LessonPlan>,
}

/// What the station hands the endpoint; the station keeps the senders.
pub struct NetworkFeeds {
    /// The latest metrics (the main thread updates them at 10 Hz).
    pub metrics: watch::Sender<Metrics>,
    /// Events.
    pub events: broadcast::Sender<Event>,
    /// An observer-stream-loss fault is in effect: no frames, no metrics.
    pub stream_lost: watch::Sender<bool>,
    /// The lesson's running score (none until the station has one).
    pub score: watch::Sender<Option<scalpel_proto::wire::LessonScore>>,
}

/// An instructor's command on its way to the station's fault book (main thread), and
/// where its answer goes.
pub struct CommandRequest {
    /// Who sent it (certificate common name).
    pub by: String,
    /// Their role (from the certificate): the station refuses and journals an observer's.
    pub role: scalpel_proto::wire::Role,
    /// Refused by the connection already (its `seq`, `seq_window`): the station journals
    /// and counts it with this reason, and carries nothing out.
    pub refused: Option<String>,
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
    /// Lines for the station's log (refused connections, said in full or summed up).
    pub log: std::sync::mpsc::Receiver<String>,
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
    let (score_tx, score_rx) = watch::channel(None);
    let (commands_tx, commands_rx) = std::sync::mpsc::channel();
    let (log_tx, log_rx) = std::sync::mpsc::channel();
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
                    score: score_rx,
                    commands: commands_tx,
                };
                accept_loop(&endpoint, &params, feeds, log_tx, stop_rx).await;
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
            score: score_tx,
        },
        commands: commands_rx,
        log: log_rx,
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
    // Incoming connections not yet decided: each is retried, refused or accepted as soon
    // as the accept loop sees it, so this only needs to cover a burst between two of its
    // turns (quinn drops Initials beyond it silently).
    config
        .max_incoming(MAX_INCOMING)
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
    score: watch::Receiver<Option<scalpel_proto::wire::LessonScore>>,
    commands: std::sync::mpsc::Sender<CommandRequest>,
}

async fn accept_loop(
    endpoint: &quinn::Endpoint,
    params: &NetworkParams,
    feeds: SessionFeeds,
    log: std::sync::mpsc::Sender<String>,
    mut stop: watch::Receiver<bool>,
) {
    let admission = Admission::new(Budgets {
        handshakes: params.max_handshakes,
        handshakes_per_address: params.max_handshakes_per_address,
        connections: params.max_connections,
        connections_per_address: params.max_per_address,
    });
    let started = tokio::time::Instant::now();
    let refusals = Refusals {
        log: Arc::new(Mutex::new(RefusalLog::new(*admission.budgets(), 0))),
        out: log,
        started,
    };
    let mut summaries = tokio::time::interval(Duration::from_millis(refusal_log::SUMMARY_EVERY_MS));
    summaries.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Skip);
    loop {
        let incoming = tokio::select! {
            i = endpoint.accept() => match i { Some(i) => i, None => break },
            _ = summaries.tick() => {
                refusals.summarise(false);
                continue;
            }
            _ = stop.changed() => break,
        };
        let ip = incoming.remote_address().ip();
        // An address not yet validated gets a Retry and costs nothing more: a spoofed
        // one never sees the token.
        if !incoming.remote_address_validated() && incoming.may_retry() {
            if incoming.retry().is_ok() {
                refusals.with(|l| l.retried());
            }
            continue;
        }
        let place = match admission.handshake(ip) {
            Ok(place) => place,
            Err(why) => {
                incoming.refuse();
                refusals.refused(ip, why, None);
                continue;
            }
        };
        let connecting = match incoming.accept() {
            Ok(c) => c,
            Err(e) => {
                refusals.refused(ip, Refusal::Tls, Some(&e.to_string()));
                continue;
            }
        };
        let context = session::SessionContext {
            station: params.station.clone(),
            scene: params.scene.clone(),
            frame_hz_max: params.frame_hz,
            metrics: feeds.metrics.clone(),
            events: feeds.events.subscribe(),
            frames: feeds.frames.clone(),
            stream_lost: feeds.stream_lost.clone(),
            lesson: params.lesson.clone().map(Arc::new),
            score: feeds.score.clone(),
            commands: feeds.commands.clone(),
            stop: stop.clone(),
        };
        let (admission, refusals) = (admission.clone(), refusals.clone());
        tokio::spawn(async move {
            let conn = match tokio::time::timeout(HANDSHAKE_TIMEOUT, connecting).await {
                Ok(Ok(c)) => c,
                Ok(Err(e)) => return refusals.refused(ip, Refusal::Tls, Some(&e.to_string())),
                // Dropping the handshake closes it.
                Err(_) => return refusals.refused(ip, Refusal::Timeout, None),
            };
            // Held until the session ends, however it ends (a panic included).
            let _place = match admission.connect(place) {
                Ok(place) => place,
                Err(why) => {
                    let reason = why.describe(admission.budgets());
                    conn.close(session::close::BUSY.into(), reason.as_bytes());
                    return refusals.refused(ip, why, None);
                }
            };
            if let Err(reason) = session::run(&conn, context).await {
                refusals.refused(ip, Refusal::Forbidden, Some(&reason));
            }
        });
    }
    refusals.summarise(true);
}

/// The refusal log, shared by the accept loop and the handshakes' tasks, and where its
/// lines go (the station's main thread).
#[derive(Clone)]
struct Refusals {
    log: Arc<Mutex<RefusalLog>>,
    out: std::sync::mpsc::Sender<String>,
    started: tokio::time::Instant,
}

impl Refusals {
    fn with<T>(&self, f: impl FnOnce(&mut RefusalLog) -> T) -> T {
        f(&mut self.log.lock().unwrap_or_else(|e| e.into_inner()))
    }

    fn now_ms(&self) -> u64 {
        self.started.elapsed().as_millis() as u64
    }

    fn refused(&self, ip: std::net::IpAddr, why: Refusal, detail: Option<&str>) {
        let now = self.now_ms();
        if let Some(line) = self.with(|l| l.refused(now, ip, why, detail)) {
            let _ = self.out.send(line);
        }
    }

    fn summarise(&self, last: bool) {
        let now = self.now_ms();
        if let Some(line) = self.with(|l| l.summary(now, last)) {
            let _ = self.out.send(line);
        }
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
            match scalpel_client::frame_reader::FrameReader::open_as("scalpel-net.frames", &station)
            {
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
