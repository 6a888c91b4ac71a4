//! One remote client's connection: the handshake on the control stream, then telemetry
//! (metrics at 10 Hz and events) on one server-opened stream, frames on a stream each, and
//! the client's requests on the control stream. A malformed or oversized message closes
//! this connection only, with a code and a reason.

use std::sync::Arc;
use std::time::Duration;

use rustls::pki_types::CertificateDer;
use scalpel_proto::codec::{CLIENT_LIMIT, SERVER_LIMIT, read_frame, write_frame};
use scalpel_proto::wire::{
    ClientMessage, Command, Event, EventKind, LessonPlan, LessonScore, MAX_TEXT, Metrics, Outcome,
    PROTOCOL_VERSION, Role, ServerMessage,
};
use tokio::sync::{broadcast, watch};

use super::observer_frames::{FrameEncoder, SourceFrame};
use super::seq_window::SeqWindow;
use super::tls;

/// The lowest frame rate an observer may ask for (Hz): a frame every ten seconds.
pub const MIN_FRAME_HZ: f32 = 0.1;

/// Connection close codes (QUIC application error codes).
pub mod close {
    /// Normal close.
    pub const DONE: u32 = 0;
    /// A malformed, oversized or unexpected message.
    pub const PROTOCOL: u32 = 1;
    /// The certificate carries no role, or a name that cannot be shown (`tls::identity`).
    pub const FORBIDDEN: u32 = 2;
    /// Another protocol version.
    pub const VERSION: u32 = 3;
    /// The server is stopping.
    pub const STOPPING: u32 = 4;
    /// The station is at its limit of connections (the reason says which).
    pub const BUSY: u32 = 5;
}

/// Time allowed for the control stream, and then for the `Hello`, once TLS is through.
const HANDSHAKE_TIMEOUT: Duration = Duration::from_secs(5);
/// Metrics interval.
const METRICS_PERIOD: Duration = Duration::from_millis(100);

/// What a session needs from the endpoint.
pub struct SessionContext {
    /// Station name.
    pub station: String,
    /// Scene name.
    pub scene: String,
    /// Most frames per second an observer may ask for.
    pub frame_hz_max: f64,
    /// Latest metrics.
    pub metrics: watch::Receiver<Metrics>,
    /// Events.
    pub events: broadcast::Receiver<Event>,
    /// Latest frame.
    pub frames: watch::Receiver<Option<Arc<SourceFrame>>>,
    /// An observer-stream-loss fault is in effect.
    pub stream_lost: watch::Receiver<bool>,
    /// The lesson the station runs, if any.
    pub lesson: Option<Arc<LessonPlan>>,
    /// Its running score.
    pub score: watch::Receiver<Option<LessonScore>>,
    /// Instructors' commands to the station.
    pub commands: std::sync::mpsc::Sender<super::CommandRequest>,
    /// Server stopping.
    pub stop: watch::Receiver<bool>,
}

/// Why a session ended early.
#[derive(Debug)]
struct Closed(u32, String);

/// Runs one connection, its TLS handshake done, to its end. A certificate refused (no
/// role, a name that cannot be shown) is `Err` with the reason, for the station's log.
pub async fn run(conn: &quinn::Connection, mut ctx: SessionContext) -> Result<(), String> {
    let result = serve(conn, &mut ctx).await;
    let (code, reason) = match result {
        Ok(()) => (close::DONE, String::from("bye")),
        Err(Closed(code, reason)) => (code, reason),
    };
    conn.close(code.into(), reason.as_bytes());
    if code == close::FORBIDDEN {
        return Err(reason);
    }
    Ok(())
}

fn identity(conn: &quinn::Connection) -> Result<(Role, String), String> {
    let certs = conn
        .peer_identity()
        .and_then(|i| i.downcast::<Vec<CertificateDer<'static>>>().ok())
        .ok_or("no client certificate")?;
    tls::identity(certs.first().ok_or("no client certificate")?)
}

async fn serve(conn: &quinn::Connection, ctx: &mut SessionContext) -> Result<(), Closed> {
    let (role, name) = identity(conn).map_err(|reason| Closed(close::FORBIDDEN, reason))?;
    let (mut send, mut recv) = tokio::time::timeout(HANDSHAKE_TIMEOUT, conn.accept_bi())
        .await
        .map_err(|_| Closed(close::PROTOCOL, "no control stream".into()))?
        .map_err(|e| Closed(close::PROTOCOL, format!("control stream: {e}")))?;
    let hello = tokio::time::timeout(
        HANDSHAKE_TIMEOUT,
        read_frame::<ClientMessage, CLIENT_LIMIT>(&mut recv),
    )
    .await
    .map_err(|_| Closed(close::PROTOCOL, "no Hello".into()))?
    .map_err(|e| Closed(close::PROTOCOL, format!("Hello: {e}")))?;
    match hello {
        Some(ClientMessage::Hello {
            protocol_version,
            client,
        }) if client.len() <= MAX_TEXT => {
            if protocol_version != PROTOCOL_VERSION {
                let reason = format!(
                    "protocol version {protocol_version}; this server speaks {PROTOCOL_VERSION}"
                );
                let _ = write_frame::<_, SERVER_LIMIT>(
                    &mut send,
                    &ServerMessage::Refused {
                        reason: reason.clone(),
                    },
                )
                .await;
                return Err(Closed(close::VERSION, reason));
            }
        }
        Some(ClientMessage::Hello { client, .. }) => {
            return Err(Closed(
                close::PROTOCOL,
                format!(
                    "Hello: the client name is {} bytes, at most {MAX_TEXT}",
                    client.len()
                ),
            ));
        }
        _ => {
            return Err(Closed(
                close::PROTOCOL,
                "the first message must be a Hello".into(),
            ));
        }
    }
    write_frame::<_, SERVER_LIMIT>(
        &mut send,
        &ServerMessage::Welcome {
            protocol_version: PROTOCOL_VERSION,
            station: ctx.station.clone(),
            scene: ctx.scene.clone(),
            role,
            identity: name.clone(),
        },
    )
    .await
    .map_err(|e| Closed(close::PROTOCOL, format!("Welcome: {e}")))?;

    let (frame_hz_tx, frame_hz_rx) = watch::channel(0.0f64);
    let telemetry = telemetry(
        conn,
        Feeds {
            metrics: ctx.metrics.clone(),
            events: ctx.events.resubscribe(),
            stream_lost: ctx.stream_lost.clone(),
            lesson: ctx.lesson.clone(),
            score: ctx.score.clone(),
        },
    );
    let frames = frames(
        conn,
        ctx.frames.clone(),
        frame_hz_rx,
        ctx.stream_lost.clone(),
    );
    let mut who = Instructing {
        role,
        name: name.clone(),
        commands: ctx.commands.clone(),
        window: SeqWindow::default(),
    };
    let control = control(
        &mut send,
        &mut recv,
        &mut who,
        ctx.frame_hz_max,
        frame_hz_tx,
    );
    let mut stop = ctx.stop.clone();
    tokio::select! {
        r = control => r,
        r = telemetry => r,
        r = frames => r,
        _ = stop.changed() => Err(Closed(close::STOPPING, "server stopping".into())),
        _ = conn.closed() => Ok(()),
    }
}

/// Who sends commands on this connection, where they go, and the `seq`s it used.
struct Instructing {
    role: Role,
    name: String,
    commands: std::sync::mpsc::Sender<super::CommandRequest>,
    window: SeqWindow,
}

/// Time the station has to answer a command (its main thread takes them every 10 ms).
const COMMAND_TIMEOUT: Duration = Duration::from_secs(2);

impl Instructing {
    /// The station's answer to `command`: the Ack, and the fault list for `List`.
    async fn carry_out(&mut self, command: Command) -> Vec<ServerMessage> {
        let seq = command.seq;
        let rejected = |reason: &str| {
            vec![ServerMessage::Ack {
                seq,
                outcome: Outcome::Rejected {
                    reason: reason.into(),
                },
            }]
        };
        // The station answers every command, an observer's too (refused, and journaled
        // with who tried); one whose `seq` this connection refuses goes there to be
        // journaled and counted, not carried out.
        let (reply, answer) = tokio::sync::oneshot::channel();
        let request = super::CommandRequest {
            role: self.role,
            by: self.name.clone(),
            refused: self.window.check(seq).err(),
            command,
            reply,
        };
        if self.commands.send(request).is_err() {
            return rejected("the station is stopping");
        }
        match tokio::time::timeout(COMMAND_TIMEOUT, answer).await {
            Ok(Ok((outcome, listed))) => {
                if !matches!(outcome, Outcome::Rejected { .. }) {
                    self.window.take(seq);
                }
                let mut out = vec![ServerMessage::Ack { seq, outcome }];
                if let Some(faults) = listed {
                    out.push(ServerMessage::Faults { faults });
                }
                out
            }
            _ => rejected("the station did not answer in time"),
        }
    }
}

/// The client's requests, answered in order.
async fn control(
    send: &mut quinn::SendStream,
    recv: &mut quinn::RecvStream,
    who: &mut Instructing,
    frame_hz_max: f64,
    frame_hz: watch::Sender<f64>,
) -> Result<(), Closed> {
    loop {
        let message = read_frame::<ClientMessage, CLIENT_LIMIT>(recv)
            .await
            .map_err(|e| Closed(close::PROTOCOL, format!("control stream: {e}")))?;
        let replies = match message {
            None => return Ok(()),
            Some(ClientMessage::Subscribe { frame_hz: hz }) => {
                // 0 is none; a rate near zero is a period of centuries (it panicked the
                // frame loop's Duration).
                if !(hz == 0.0 || (MIN_FRAME_HZ..=f32::MAX).contains(&hz)) {
                    return Err(Closed(
                        close::PROTOCOL,
                        format!(
                            "Subscribe: frame_hz {hz} is not a rate: 0 (none) or at least {MIN_FRAME_HZ}"
                        ),
                    ));
                }
                let _ = frame_hz.send(f64::from(hz).min(frame_hz_max));
                continue;
            }
            Some(ClientMessage::Command(command)) => who.carry_out(command).await,
            Some(ClientMessage::Hello { .. }) => {
                return Err(Closed(close::PROTOCOL, "a second Hello".into()));
            }
        };
        for reply in &replies {
            write_frame::<_, SERVER_LIMIT>(send, reply)
                .await
                .map_err(|e| Closed(close::PROTOCOL, format!("control stream: {e}")))?;
        }
    }
}

/// Metrics at 10 Hz and events as they come, on one stream (no metrics while an
/// observer-stream-loss fault is in effect; events still go out).
/// What the telemetry stream carries.
struct Feeds {
    metrics: watch::Receiver<Metrics>,
    events: broadcast::Receiver<Event>,
    stream_lost: watch::Receiver<bool>,
    lesson: Option<Arc<LessonPlan>>,
    score: watch::Receiver<Option<LessonScore>>,
}

async fn telemetry(conn: &quinn::Connection, feeds: Feeds) -> Result<(), Closed> {
    let Feeds {
        metrics,
        mut events,
        stream_lost,
        lesson,
        score,
    } = feeds;
    let mut stream = conn
        .open_uni()
        .await
        .map_err(|e| Closed(close::PROTOCOL, format!("telemetry stream: {e}")))?;
    let write = async |stream: &mut quinn::SendStream, message: &ServerMessage| {
        write_frame::<_, SERVER_LIMIT>(stream, message)
            .await
            .map_err(|e| Closed(close::PROTOCOL, format!("telemetry stream: {e}")))
    };
    // The lesson first: an observer reads every score against it.
    if let Some(plan) = &lesson {
        write(&mut stream, &ServerMessage::Lesson((**plan).clone())).await?;
    }
    let mut tick = tokio::time::interval(METRICS_PERIOD);
    tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Skip);
    loop {
        let message = tokio::select! {
            _ = tick.tick() => {
                let m = *metrics.borrow();
                // Nothing to report before the station's first figures (a client that
                // connects in its first tenth of a second).
                if m.uptime_s <= 0.0 || *stream_lost.borrow() {
                    continue;
                }
                let s = *score.borrow();
                if let Some(s) = s {
                    write(&mut stream, &ServerMessage::Score(s)).await?;
                }
                ServerMessage::Metrics(m)
            }
            e = events.recv() => match e {
                Ok(e) => ServerMessage::Event(e),
                Err(broadcast::error::RecvError::Lagged(n)) => ServerMessage::Event(Event {
                    sim_tick: metrics.borrow().sim_tick,
                    uptime_s: metrics.borrow().uptime_s,
                    kind: EventKind::Notice,
                    detail: format!("{n} events skipped (this observer was slow)"),
                }),
                Err(broadcast::error::RecvError::Closed) => return Ok(()),
            },
        };
        write(&mut stream, &message).await?;
    }
}

/// Frames at the observer's rate, a stream each; a frame still in flight when the next is
/// due makes the server skip the new one (latest wins: nothing queues for a slow observer).
async fn frames(
    conn: &quinn::Connection,
    mut source: watch::Receiver<Option<Arc<SourceFrame>>>,
    mut frame_hz: watch::Receiver<f64>,
    stream_lost: watch::Receiver<bool>,
) -> Result<(), Closed> {
    let mut encoder = FrameEncoder::new();
    let mut in_flight: Option<(tokio::task::JoinHandle<bool>, bool)> = None;
    let mut next_due = tokio::time::Instant::now();
    loop {
        tokio::select! {
            r = source.changed() => if r.is_err() { return Ok(()) },
            r = frame_hz.changed() => if r.is_err() { return Ok(()) } else { continue },
        }
        if *stream_lost.borrow() {
            // Lost: nothing goes out, and the stream starts again from a keyframe.
            encoder.reset();
            continue;
        }
        let hz = *frame_hz.borrow();
        let now = tokio::time::Instant::now();
        if hz <= 0.0 || now < next_due {
            continue;
        }
        if let Some((task, _)) = &in_flight
            && !task.is_finished()
        {
            continue;
        }
        if let Some((task, keyframe)) = in_flight.take() {
            let delivered = task.await.unwrap_or(false);
            if !delivered && keyframe {
                encoder.reset();
            }
        }
        let Some(frame) = source.borrow_and_update().clone() else {
            continue;
        };
        next_due = now + Duration::try_from_secs_f64(1.0 / hz).unwrap_or(Duration::from_secs(10));
        let message = encoder.encode(&frame);
        let keyframe = message.topology.is_some();
        let conn = conn.clone();
        in_flight = Some((
            tokio::spawn(async move {
                let Ok(mut stream) = conn.open_uni().await else {
                    return false;
                };
                write_frame::<_, SERVER_LIMIT>(&mut stream, &ServerMessage::Frame(message))
                    .await
                    .is_ok()
                    && stream.finish().is_ok()
            }),
            keyframe,
        ));
    }
}
