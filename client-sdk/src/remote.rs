//! Remote clients of a station over QUIC (docs/PROTOCOL.md, "Remote clients"): an
//! [`Observer`] receives metrics, events and frames; an [`Instructor`] can also send
//! commands. Both authenticate with a certificate from the lab's CA (`scalpel certs issue`);
//! what they may do is in the certificate, and the server decides.

use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Duration;

use rustls::pki_types::pem::PemObject;
use rustls::pki_types::{CertificateDer, PrivateKeyDer};
use scalpel_proto::codec::{CLIENT_LIMIT, CodecError, SERVER_LIMIT, read_frame, write_frame};
use scalpel_proto::wire::{
    ALPN, Action, ClientMessage, Command, DecodedFrame, Event, FaultSpec, FrameDecoder, LessonPlan,
    LessonScore, Metrics, Outcome, PROTOCOL_VERSION, Role, ScheduledFault, ServerMessage,
};
use thiserror::Error;
use tokio::sync::mpsc;

/// Updates waiting for the application before the oldest metrics are dropped.
const UPDATE_QUEUE: usize = 1024;

/// What went wrong talking to a station.
#[derive(Debug, Error)]
pub enum ClientError {
    /// A certificate or key file.
    #[error("{file}: {detail}")]
    Credentials {
        /// The file.
        file: PathBuf,
        /// What is wrong.
        detail: String,
    },
    /// TLS or QUIC set-up.
    #[error("{0}")]
    Setup(String),
    /// The connection failed or was closed.
    #[error("connection: {0}")]
    Connection(String),
    /// The server refused the client.
    #[error("refused: {0}")]
    Refused(String),
    /// A message that could not be read or written.
    #[error(transparent)]
    Codec(#[from] CodecError),
    /// The server answered something unexpected.
    #[error("protocol: {0}")]
    Protocol(String),
}

/// A client's certificate, key and the lab's CA.
#[derive(Debug, Clone)]
pub struct Credentials {
    /// The lab's CA certificate.
    pub ca: PathBuf,
    /// The client's certificate.
    pub cert: PathBuf,
    /// The client's key.
    pub key: PathBuf,
}

impl Credentials {
    /// The files `scalpel certs` made for `name` in `dir`.
    pub fn from_dir(dir: &Path, name: &str) -> Self {
        Self {
            ca: dir.join("ca.pem"),
            cert: dir.join(format!("{name}.pem")),
            key: dir.join(format!("{name}.key")),
        }
    }
}

/// Most bytes a certificate or key file may have (a PEM chain is a few kilobytes; a wrong
/// path must not be read whole).
const PEM_MAX_BYTES: u64 = 1 << 20;

/// The bytes of a PEM file, at most [`PEM_MAX_BYTES`] of a regular file.
fn read_pem(path: &Path) -> Result<Vec<u8>, ClientError> {
    use std::io::Read;
    let bad = |detail: String| ClientError::Credentials {
        file: path.to_owned(),
        detail,
    };
    // Before opening: opening a FIFO waits for a writer.
    if !std::fs::metadata(path)
        .map_err(|e| bad(e.to_string()))?
        .is_file()
    {
        return Err(bad("not a regular file".into()));
    }
    let file = std::fs::File::open(path).map_err(|e| bad(e.to_string()))?;
    let mut bytes = Vec::new();
    file.take(PEM_MAX_BYTES + 1)
        .read_to_end(&mut bytes)
        .map_err(|e| bad(e.to_string()))?;
    if bytes.len() as u64 > PEM_MAX_BYTES {
        return Err(bad(format!("over {PEM_MAX_BYTES} bytes: not a PEM file")));
    }
    Ok(bytes)
}

fn certs(path: &Path) -> Result<Vec<CertificateDer<'static>>, ClientError> {
    let bad = |detail: String| ClientError::Credentials {
        file: path.to_owned(),
        detail,
    };
    let certs: Vec<_> = CertificateDer::pem_slice_iter(&read_pem(path)?)
        .collect::<Result<_, _>>()
        .map_err(|e| bad(e.to_string()))?;
    if certs.is_empty() {
        return Err(bad("no certificate in it".into()));
    }
    Ok(certs)
}

fn provider() -> Arc<rustls::crypto::CryptoProvider> {
    Arc::new(rustls::crypto::ring::default_provider())
}

/// The QUIC client configuration for `credentials` (`None`: no client certificate, which a
/// station refuses; for tests of exactly that).
pub fn client_config(
    credentials: Option<&Credentials>,
    ca: &Path,
) -> Result<quinn::ClientConfig, ClientError> {
    let mut roots = rustls::RootCertStore::empty();
    for c in certs(ca)? {
        roots.add(c).map_err(|e| ClientError::Credentials {
            file: ca.to_owned(),
            detail: e.to_string(),
        })?;
    }
    let builder = rustls::ClientConfig::builder_with_provider(provider())
        .with_protocol_versions(&[&rustls::version::TLS13])
        .map_err(|e| ClientError::Setup(e.to_string()))?
        .with_root_certificates(roots);
    let mut tls = match credentials {
        Some(c) => {
            let key = PrivateKeyDer::from_pem_slice(&read_pem(&c.key)?).map_err(|e| {
                ClientError::Credentials {
                    file: c.key.clone(),
                    detail: e.to_string(),
                }
            })?;
            builder
                .with_client_auth_cert(certs(&c.cert)?, key)
                .map_err(|e| ClientError::Credentials {
                    file: c.cert.clone(),
                    detail: e.to_string(),
                })?
        }
        None => builder.with_no_client_auth(),
    };
    tls.alpn_protocols = vec![ALPN.to_vec()];
    tls.enable_early_data = false;
    let crypto = quinn::crypto::rustls::QuicClientConfig::try_from(tls)
        .map_err(|e| ClientError::Setup(e.to_string()))?;
    let mut config = quinn::ClientConfig::new(Arc::new(crypto));
    let mut transport = quinn::TransportConfig::default();
    transport.keep_alive_interval(Some(Duration::from_secs(1)));
    config.transport_config(Arc::new(transport));
    Ok(config)
}

/// What the server said about this client.
#[derive(Debug, Clone, PartialEq)]
pub struct Welcome {
    /// The station.
    pub station: String,
    /// Its scene.
    pub scene: String,
    /// What this client may do.
    pub role: Role,
    /// Who the server takes it to be.
    pub identity: String,
}

/// Something from the station.
#[derive(Debug, Clone, PartialEq)]
pub enum Update {
    /// Figures (10 Hz).
    Metrics(Metrics),
    /// An event.
    Event(Event),
    /// A frame, rebuilt from the keyframe.
    Frame(DecodedFrame),
    /// The lesson the station runs (first, when it runs one).
    Lesson(Box<LessonPlan>),
    /// The trainee's running score (10 Hz, with a lesson).
    Score(LessonScore),
}

/// A failed handshake as the client error. QUIC's refusal of a connection has no room for
/// a reason: a station refuses one before its TLS handshake when its handshakes in flight
/// are at their limit (or it is stopping), so that is said. (Over the connection limits
/// the station closes the connection after the handshake, with the reason.)
fn refusal(e: quinn::ConnectionError) -> ClientError {
    match &e {
        quinn::ConnectionError::ConnectionClosed(c)
            if c.error_code == quinn::TransportErrorCode::CONNECTION_REFUSED =>
        {
            ClientError::Refused(
                "the station refused the connection before its handshake: at its limit of \
                 handshakes in flight (`network.max_handshakes`, \
                 `network.max_handshakes_per_address` from one address: someone may be \
                 flooding it), or stopping; try again in a few seconds"
                    .into(),
            )
        }
        _ => ClientError::Connection(e.to_string()),
    }
}

/// Longest [`Session::connect`] waits for the station's welcome (a TLS handshake and two
/// messages take milliseconds, on a busy debug build a second).
pub const CONNECT_TIMEOUT: Duration = Duration::from_secs(10);

/// A connection to a station, shared by [`Observer`] and [`Instructor`].
pub struct Session {
    endpoint: quinn::Endpoint,
    connection: quinn::Connection,
    send: quinn::SendStream,
    recv: quinn::RecvStream,
    updates: mpsc::Receiver<Update>,
    welcome: Welcome,
    next_seq: u64,
}

impl Session {
    /// Connects with `credentials` (see [`Session::connect`]).
    pub async fn connect_with(
        addr: SocketAddr,
        server_name: &str,
        credentials: &Credentials,
        client: &str,
    ) -> Result<Self, ClientError> {
        let config = client_config(Some(credentials), &credentials.ca)?;
        Self::connect(addr, server_name, config, client).await
    }

    /// Connects, authenticates and says hello. `server_name` must be a name in the server's
    /// certificate (`localhost` for one made by `scalpel certs init`). Gives up after
    /// [`CONNECT_TIMEOUT`] without a welcome: nothing listening at `addr` answers nothing over
    /// UDP, and QUIC's idle timeout alone would keep the caller waiting 30 s.
    pub async fn connect(
        addr: SocketAddr,
        server_name: &str,
        config: quinn::ClientConfig,
        client: &str,
    ) -> Result<Self, ClientError> {
        tokio::time::timeout(
            CONNECT_TIMEOUT,
            Self::handshake(addr, server_name, config, client),
        )
        .await
        .unwrap_or_else(|_| {
            Err(ClientError::Connection(format!(
                "no answer from {addr} within {} s: is a station listening there (its \
                 `network.listen`, and the `observers` feature in its scene)?",
                CONNECT_TIMEOUT.as_secs()
            )))
        })
    }

    async fn handshake(
        addr: SocketAddr,
        server_name: &str,
        config: quinn::ClientConfig,
        client: &str,
    ) -> Result<Self, ClientError> {
        let bind: SocketAddr = if addr.is_ipv6() {
            "[::]:0".parse().expect("an address")
        } else {
            "0.0.0.0:0".parse().expect("an address")
        };
        let mut endpoint =
            quinn::Endpoint::client(bind).map_err(|e| ClientError::Setup(e.to_string()))?;
        endpoint.set_default_client_config(config);
        let connection = endpoint
            .connect(addr, server_name)
            .map_err(|e| ClientError::Setup(e.to_string()))?
            .await
            .map_err(refusal)?;
        let (mut send, mut recv) = connection
            .open_bi()
            .await
            .map_err(|e| ClientError::Connection(e.to_string()))?;
        write_frame::<_, CLIENT_LIMIT>(
            &mut send,
            &ClientMessage::Hello {
                protocol_version: PROTOCOL_VERSION,
                client: client.chars().take(64).collect(),
            },
        )
        .await?;
        let welcome = match read_frame::<ServerMessage, SERVER_LIMIT>(&mut recv).await {
            Ok(Some(ServerMessage::Welcome {
                station,
                scene,
                role,
                identity,
                ..
            })) => Welcome {
                station,
                scene,
                role,
                identity,
            },
            Ok(Some(ServerMessage::Refused { reason })) => {
                return Err(ClientError::Refused(reason));
            }
            Ok(Some(other)) => {
                return Err(ClientError::Protocol(format!(
                    "expected Welcome, got {other:?}"
                )));
            }
            Ok(None) | Err(_) => {
                // The server closes a refused connection; its reason is the close reason.
                let reason = connection.closed().await;
                return Err(ClientError::Refused(reason.to_string()));
            }
        };
        let (tx, updates) = mpsc::channel(UPDATE_QUEUE);
        tokio::spawn(receive_streams(connection.clone(), tx));
        Ok(Self {
            endpoint,
            connection,
            send,
            recv,
            updates,
            welcome,
            // Each connection numbers its commands afresh (the server keeps a window per
            // connection, docs/PROTOCOL.md).
            next_seq: 1,
        })
    }

    /// What the server said about this client.
    pub fn welcome(&self) -> &Welcome {
        &self.welcome
    }

    /// Asks for frames at `frame_hz` (0: none; the server caps it).
    pub async fn subscribe(&mut self, frame_hz: f32) -> Result<(), ClientError> {
        write_frame::<_, CLIENT_LIMIT>(&mut self.send, &ClientMessage::Subscribe { frame_hz })
            .await
            .map_err(Into::into)
    }

    /// The next update; `None` once the connection is gone.
    pub async fn next(&mut self) -> Option<Update> {
        self.updates.recv().await
    }

    /// The `seq` the next command gets. The server refuses one this connection used, or
    /// one more than 64 below the highest it used: setting it lower replays (what a test
    /// of that refusal does).
    pub fn set_next_seq(&mut self, seq: u64) {
        self.next_seq = seq;
    }

    /// Sends a command and waits for its answer (and the fault list for `List`).
    pub async fn command(
        &mut self,
        action: Action,
    ) -> Result<(Outcome, Option<Vec<ScheduledFault>>), ClientError> {
        let seq = self.next_seq;
        self.next_seq = seq.saturating_add(1);
        let listing = matches!(action, Action::List);
        write_frame::<_, CLIENT_LIMIT>(
            &mut self.send,
            &ClientMessage::Command(Command { seq, action }),
        )
        .await?;
        let outcome = match read_frame::<ServerMessage, SERVER_LIMIT>(&mut self.recv).await? {
            Some(ServerMessage::Ack { seq: s, outcome }) if s == seq => outcome,
            Some(other) => {
                return Err(ClientError::Protocol(format!(
                    "expected the Ack of command {seq}, got {other:?}"
                )));
            }
            None => return Err(ClientError::Connection("closed".into())),
        };
        let faults = if listing && outcome == Outcome::Listed {
            match read_frame::<ServerMessage, SERVER_LIMIT>(&mut self.recv).await? {
                Some(ServerMessage::Faults { faults }) => Some(faults),
                other => {
                    return Err(ClientError::Protocol(format!(
                        "expected the fault list, got {other:?}"
                    )));
                }
            }
        } else {
            None
        };
        Ok((outcome, faults))
    }

    /// Sends raw bytes on the control stream (for tests of malformed input).
    pub async fn send_raw(&mut self, bytes: &[u8]) -> Result<(), ClientError> {
        self.send
            .write_all(bytes)
            .await
            .map_err(|e| ClientError::Connection(e.to_string()))
    }

    /// Bytes received on this connection so far (UDP payloads: everything the server sent,
    /// headers and retransmissions included).
    pub fn bytes_received(&self) -> u64 {
        self.connection.stats().udp_rx.bytes
    }

    /// Waits for the connection to close and says why.
    pub async fn closed(&self) -> String {
        self.connection.closed().await.to_string()
    }

    /// Closes the connection.
    pub fn close(&self) {
        self.connection.close(0u32.into(), b"bye");
    }

    /// Closes the connection and waits (a second at most) until the server has been told:
    /// a short-lived client (one CLI command) that just exits leaves the server holding
    /// its connection slot until the idle timeout.
    pub async fn close_and_wait(&self) {
        self.close();
        let _ = tokio::time::timeout(Duration::from_secs(1), self.endpoint.wait_idle()).await;
    }
}

/// Reads every stream the server opens: the telemetry stream (many messages) and frame
/// streams (one frame each).
async fn receive_streams(connection: quinn::Connection, tx: mpsc::Sender<Update>) {
    let decoder = Arc::new(std::sync::Mutex::new(FrameDecoder::new()));
    while let Ok(mut stream) = connection.accept_uni().await {
        let tx = tx.clone();
        let decoder = decoder.clone();
        tokio::spawn(async move {
            while let Ok(Some(message)) =
                read_frame::<ServerMessage, SERVER_LIMIT>(&mut stream).await
            {
                let update = match message {
                    ServerMessage::Metrics(m) => Update::Metrics(m),
                    ServerMessage::Event(e) => Update::Event(e),
                    ServerMessage::Lesson(l) => Update::Lesson(Box::new(l)),
                    ServerMessage::Score(s) => Update::Score(s),
                    ServerMessage::Frame(f) => {
                        let decoded = decoder.lock().unwrap_or_else(|e| e.into_inner()).decode(&f);
                        match decoded {
                            Some(d) => Update::Frame(d),
                            None => continue,
                        }
                    }
                    _ => continue,
                };
                // A full queue drops metrics (the next come in 0.1 s), never events.
                match &update {
                    Update::Metrics(_) | Update::Score(_) => {
                        let _ = tx.try_send(update);
                    }
                    _ => {
                        if tx.send(update).await.is_err() {
                            return;
                        }
                    }
                }
            }
        });
    }
}

/// A remote observer: metrics, events, frames.
pub struct Observer(pub Session);

impl Observer {
    /// Connects with an observer (or instructor) certificate.
    pub async fn connect(
        addr: SocketAddr,
        server_name: &str,
        credentials: &Credentials,
        client: &str,
    ) -> Result<Self, ClientError> {
        Ok(Self(
            Session::connect_with(addr, server_name, credentials, client).await?,
        ))
    }
}

/// A remote instructor: an observer that can schedule and clear faults.
pub struct Instructor(pub Session);

impl Instructor {
    /// Connects; fails if the certificate is not an instructor's.
    pub async fn connect(
        addr: SocketAddr,
        server_name: &str,
        credentials: &Credentials,
        client: &str,
    ) -> Result<Self, ClientError> {
        let session = Session::connect_with(addr, server_name, credentials, client).await?;
        if session.welcome.role != Role::Instructor {
            return Err(ClientError::Refused(format!(
                "{} is an observer certificate",
                session.welcome.identity
            )));
        }
        Ok(Self(session))
    }

    /// Schedules a fault.
    pub async fn schedule(&mut self, spec: FaultSpec) -> Result<Outcome, ClientError> {
        Ok(self.0.command(Action::Schedule(spec)).await?.0)
    }

    /// Clears one fault or all.
    pub async fn clear(&mut self, id: Option<u64>) -> Result<Outcome, ClientError> {
        Ok(self.0.command(Action::Clear { id }).await?.0)
    }

    /// The scheduled and active faults.
    pub async fn list(&mut self) -> Result<(Outcome, Vec<ScheduledFault>), ClientError> {
        let (outcome, faults) = self.0.command(Action::List).await?;
        Ok((outcome, faults.unwrap_or_default()))
    }
}
