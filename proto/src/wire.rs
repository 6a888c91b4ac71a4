//! The QUIC wire protocol between a station server and its remote clients (observers and
//! instructors): message types, serde-encoded by [`crate::codec`] (bincode 2, standard
//! configuration, length-prefixed frames with a size limit). docs/PROTOCOL.md describes
//! the streams and the byte layout; `tests` pin the bytes of every message kind.
//!
//! Streams of one connection:
//! - **control** (bidirectional, opened by the client): `Hello` → `Welcome` (or `Refused`),
//!   then the client's `Subscribe` / `Command`s and the server's `Ack`s and `Faults`.
//! - **telemetry** (unidirectional, opened by the server after `Welcome`): the station's
//!   `Lesson` first when it runs one, then `Metrics` (and with a lesson, `Score`) at 10 Hz
//!   and `Event`s as they happen.
//! - **frames** (one unidirectional stream per frame, opened by the server): one
//!   `ObserverFrame` each; a frame still in flight when the next is due makes the server
//!   skip the new one (latest wins, nothing queues).

use serde::{Deserialize, Serialize};

/// Protocol version; `Hello` and `Welcome` carry it and a mismatch is refused. 2 added
/// `Metrics::station_tick` and `ObserverFrame::server_time_ns` and made faults real; 3
/// added the lesson (`Lesson`, `Score`, and the force-limit and no-go event kinds).
pub const PROTOCOL_VERSION: u16 = 3;
/// TLS application protocol (ALPN).
pub const ALPN: &[u8] = b"scalpel/1";
/// Longest free text a client may send (client names).
pub const MAX_TEXT: usize = 256;

/// What a client is allowed to do; it comes from its certificate, never from the client.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum Role {
    /// Receives frames, metrics and events.
    Observer,
    /// An observer that may also schedule and clear faults.
    Instructor,
}

/// Client → server on the control stream.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub enum ClientMessage {
    /// The first message.
    Hello {
        /// [`PROTOCOL_VERSION`] of the client.
        protocol_version: u16,
        /// A name for logs (at most [`MAX_TEXT`] bytes).
        client: String,
    },
    /// Frames per second wanted (0 = none; the server caps it).
    Subscribe {
        /// Frames per second.
        frame_hz: f32,
    },
    /// An instructor command.
    Command(Command),
}

/// An instructor command, numbered: the server refuses a `seq` not above the last one it
/// accepted from this identity (replays and reordering).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Command {
    /// Sequence number, increasing per identity.
    pub seq: u64,
    /// What to do.
    pub action: Action,
}

/// What an instructor asks for.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub enum Action {
    /// Schedule a fault.
    Schedule(FaultSpec),
    /// Clear one fault (by id) or all (`None`).
    Clear {
        /// The fault's id, from its `Ack`.
        id: Option<u64>,
    },
    /// List the scheduled and active faults.
    List,
}

/// A fault to schedule.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FaultSpec {
    /// The fault.
    pub fault: Fault,
    /// When it starts.
    pub start: Start,
    /// How long it lasts (ms; 0 = until cleared).
    pub duration_ms: u32,
}

/// When a fault starts.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum Start {
    /// At once.
    Now,
    /// At this station tick: the station's 1 ms clock since the server started
    /// ([`Metrics::station_tick`]). It keeps counting while the simulation stalls or slows
    /// down, so a fault's start and end never wait on another fault.
    AtTick(u64),
}

/// The fault vocabulary (ARCHITECTURE.md).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub enum Fault {
    /// No device samples reach the haptic loop.
    DeviceDropout,
    /// Device samples arrive this late.
    DeviceLatency {
        /// Added latency (ms).
        ms: f32,
    },
    /// Gaussian noise on the device position.
    PoseNoise {
        /// Standard deviation (mm).
        sigma_mm: f32,
    },
    /// A force spike requested of the output stage (which still limits it).
    ForceSpike {
        /// Spike magnitude (N).
        newtons: f32,
    },
    /// The device's force saturates lower than its limit.
    ForceSaturation {
        /// Saturation (N).
        max_n: f32,
    },
    /// Tissue stiffness scaled, ramped in and out.
    TissueStiffness {
        /// Factor on Young's modulus.
        factor: f32,
        /// Ramp time (ms).
        ramp_ms: u32,
    },
    /// The simulation stops ticking.
    SimStall,
    /// The simulation runs slower than real time.
    SimSlowdown {
        /// Wall time per simulated time.
        factor: f32,
    },
    /// Render frames stop changing.
    RendererFreeze,
    /// Observers get no frames or metrics.
    ObserverStreamLoss,
}

/// Longest a fault may be scheduled ahead or last (ms): an hour.
pub const MAX_FAULT_MS: u64 = 3_600_000;

impl Fault {
    /// Every kind, with parameters at their example values (documentation, CLI, tests).
    pub const EXAMPLES: [Fault; 10] = [
        Fault::DeviceDropout,
        Fault::DeviceLatency { ms: 50.0 },
        Fault::PoseNoise { sigma_mm: 1.0 },
        Fault::ForceSpike { newtons: 10.0 },
        Fault::ForceSaturation { max_n: 1.0 },
        Fault::TissueStiffness {
            factor: 2.0,
            ramp_ms: 200,
        },
        Fault::SimStall,
        Fault::SimSlowdown { factor: 4.0 },
        Fault::RendererFreeze,
        Fault::ObserverStreamLoss,
    ];

    /// The kind's name, as the CLI and the docs spell it.
    pub fn kind(&self) -> &'static str {
        match self {
            Fault::DeviceDropout => "device-dropout",
            Fault::DeviceLatency { .. } => "device-latency",
            Fault::PoseNoise { .. } => "pose-noise",
            Fault::ForceSpike { .. } => "force-spike",
            Fault::ForceSaturation { .. } => "force-saturation",
            Fault::TissueStiffness { .. } => "tissue-stiffness",
            Fault::SimStall => "sim-stall",
            Fault::SimSlowdown { .. } => "sim-slowdown",
            Fault::RendererFreeze => "renderer-freeze",
            Fault::ObserverStreamLoss => "observer-stream-loss",
        }
    }

    /// Checks the parameters: finite and within the ranges docs/PROTOCOL.md gives. The
    /// error says which parameter and what is allowed.
    pub fn check(&self) -> Result<(), String> {
        let within = |name: &str, v: f32, lo: f32, hi: f32| {
            if v.is_finite() && (lo..=hi).contains(&v) {
                Ok(())
            } else {
                Err(format!(
                    "{}: {name} {v} is outside {lo}..={hi}",
                    self.kind()
                ))
            }
        };
        match *self {
            Fault::DeviceLatency { ms } => within("ms", ms, 0.0, 1000.0),
            Fault::PoseNoise { sigma_mm } => within("sigma_mm", sigma_mm, 0.0, 20.0),
            Fault::ForceSpike { newtons } => within("newtons", newtons, 0.0, 1000.0),
            Fault::ForceSaturation { max_n } => within("max_n", max_n, 0.0, 1000.0),
            Fault::TissueStiffness { factor, ramp_ms } => {
                // server/src/faults.rs keeps the combined factor of several in this range.
                within("factor", factor, 0.1, 10.0)?;
                if u64::from(ramp_ms) > 60_000 {
                    return Err(format!("tissue-stiffness: ramp_ms {ramp_ms} is over 60000"));
                }
                Ok(())
            }
            Fault::SimSlowdown { factor } => within("factor", factor, 1.0, 100.0),
            Fault::DeviceDropout
            | Fault::SimStall
            | Fault::RendererFreeze
            | Fault::ObserverStreamLoss => Ok(()),
        }
    }
}

/// Server → client.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub enum ServerMessage {
    /// The handshake's answer.
    Welcome {
        /// [`PROTOCOL_VERSION`] of the server.
        protocol_version: u16,
        /// The station.
        station: String,
        /// The scene.
        scene: String,
        /// What the client may do (from its certificate).
        role: Role,
        /// The client's identity (its certificate's common name).
        identity: String,
    },
    /// The connection is refused; the server closes it.
    Refused {
        /// Why.
        reason: String,
    },
    /// The answer to a `Command`.
    Ack {
        /// The command's `seq`.
        seq: u64,
        /// What happened.
        outcome: Outcome,
    },
    /// Scheduled and active faults (answer to `List`).
    Faults {
        /// The faults.
        faults: Vec<ScheduledFault>,
    },
    /// Station figures, 10 Hz.
    Metrics(Metrics),
    /// Something happened.
    Event(Event),
    /// A frame of the surface (on its own stream).
    Frame(ObserverFrame),
    /// The lesson the station runs: first on the telemetry stream (protocol 3).
    Lesson(LessonPlan),
    /// The trainee's running metrics and score, 10 Hz while a lesson runs (protocol 3).
    Score(LessonScore),
}

/// A lesson as observers see it (docs/LESSONS.md): lengths in mm, mesh coordinates.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LessonPlan {
    /// The lesson's name.
    pub name: String,
    /// What the trainee is asked.
    pub description: String,
    /// Who trains at the station (empty: not named).
    pub trainee: String,
    /// The planned incisions.
    pub incisions: Vec<PlannedPath>,
    /// Structures that must not be cut.
    pub no_go: Vec<NoGoStructure>,
    /// Force limits on the force sent to the device (N).
    pub warning_n: f32,
    /// Critical limit (N).
    pub critical_n: f32,
    /// Time limit (s).
    pub time_limit_s: f32,
    /// Lowest passing score.
    pub min_score: f32,
}

/// A planned incision on the organ's rest surface.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PlannedPath {
    /// Its name.
    pub name: String,
    /// Points along it every 2 mm or so, on the surface (mm).
    pub points_mm: Vec<[f32; 3]>,
    /// Target depth (mm).
    pub depth_mm: f32,
    /// Allowed depth error (mm).
    pub depth_tolerance_mm: f32,
    /// Allowed distance from the path (mm).
    pub deviation_mm: f32,
}

/// A no-go structure.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct NoGoStructure {
    /// Its name.
    pub name: String,
    /// A ball (`from == to`) or a capsule round the segment `from`–`to` (mm).
    pub from_mm: [f32; 3],
    /// The segment's other end (mm).
    pub to_mm: [f32; 3],
    /// Radius (mm).
    pub radius_mm: f32,
}

/// The trainee's metrics and score now (docs/LESSONS.md, "Metrics").
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct LessonScore {
    /// Simulation tick of the figures.
    pub sim_tick: u64,
    /// From the blade's first entry to its last exit (s).
    pub time_s: f32,
    /// RMS distance of the cut from the path (mm).
    pub rms_deviation_mm: f32,
    /// Largest distance (mm).
    pub max_deviation_mm: f32,
    /// RMS depth error (mm).
    pub rms_depth_error_mm: f32,
    /// Depth error of largest size, + too deep (mm).
    pub max_depth_error_mm: f32,
    /// Share of the plan cut (%).
    pub completed_percent: f32,
    /// Strokes.
    pub strokes: u32,
    /// Tool path over planned length.
    pub economy: f32,
    /// Times over the warning force.
    pub warning_events: u32,
    /// Times over the critical force.
    pub critical_events: u32,
    /// Largest force sent (N).
    pub peak_force_n: f32,
    /// Contacts with no-go structures.
    pub no_go_contacts: u32,
    /// No-go structures cut into.
    pub no_go_cuts: u32,
    /// Largest lip turn (degrees).
    pub lip_turn_deg: f32,
    /// Separate wounds.
    pub wounds: u32,
    /// Cut area outside the planned band (mm²).
    pub off_band_area_mm2: f32,
    /// Score, 0–100.
    pub score: f32,
    /// Every pass criterion holds.
    pub passed: bool,
    /// The criteria missed, a bit each (docs/LESSONS.md, "Score").
    pub shortfalls: u16,
}

/// What became of a command.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub enum Outcome {
    /// Scheduled, with this id.
    Scheduled {
        /// The fault's id.
        id: u64,
    },
    /// Cleared this many faults.
    Cleared {
        /// How many.
        count: u32,
    },
    /// The list follows in a `Faults` message.
    Listed,
    /// Refused.
    Rejected {
        /// Why.
        reason: String,
    },
}

/// A fault as the server holds it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ScheduledFault {
    /// Its id.
    pub id: u64,
    /// What was asked, with the start resolved to the station tick it got and, once it has
    /// ended, the duration it had.
    pub spec: FaultSpec,
    /// Who asked (certificate common name).
    pub by: String,
    /// It is in effect now (a stiffness change ramping out after its end included).
    pub active: bool,
}

/// Station figures.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Metrics {
    /// Simulation ticks so far.
    pub sim_tick: u64,
    /// The station clock (ms since the server started); faults are scheduled on it.
    pub station_tick: u64,
    /// Server uptime (s).
    pub uptime_s: f64,
    /// Haptic ticks per second over the last status window.
    pub haptic_rate_hz: f32,
    /// Haptic wake-up lateness p99 over the last window (ms).
    pub jitter_p99_ms: f32,
    /// Deadline misses so far.
    pub deadline_misses: u64,
    /// Force sent to the device (N).
    pub force_n: f32,
    /// The watchdog has the force faded.
    pub faded: bool,
    /// Blade travel while cutting (mm).
    pub cut_length_mm: f32,
    /// Points integrated in the last tick.
    pub active_points: u32,
    /// A device is connected (always true for an in-process device).
    pub device_connected: bool,
}

/// Something that happened at the station.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Event {
    /// Simulation tick when it was seen.
    pub sim_tick: u64,
    /// Server uptime (s).
    pub uptime_s: f64,
    /// What kind.
    pub kind: EventKind,
    /// Details for people.
    pub detail: String,
}

/// Kinds of events.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum EventKind {
    /// The blade started cutting.
    CutStarted,
    /// The tissue ruptured under the blade.
    Rupture,
    /// A device connected.
    DeviceConnected,
    /// The device was lost.
    DeviceLost,
    /// A fault took effect.
    FaultApplied,
    /// A fault ended.
    FaultCleared,
    /// Anything else worth a line (warnings).
    Notice,
    /// The force went over the lesson's warning limit (protocol 3).
    ForceWarning,
    /// The force went over the lesson's critical limit.
    ForceCritical,
    /// The blade's edge touched a no-go structure.
    NoGoContact,
    /// The cut reached into a no-go structure.
    NoGoCut,
}

/// A surface frame for an observer: positions quantized to 16 bits over the frame's box.
/// A keyframe carries the topology and absolute positions; the frames after it carry
/// positions as differences from the keyframe (small numbers, which the varint encoding
/// stores in one or two bytes) until the next keyframe. An observer that (re)connects or
/// lost a frame starts from a keyframe.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ObserverFrame {
    /// Frame counter of this observer's stream, from 1.
    pub frame: u64,
    /// The keyframe this frame is relative to (itself, for a keyframe).
    pub keyframe: u64,
    /// Simulation tick.
    pub sim_tick: u64,
    /// The server's CLOCK_MONOTONIC when the simulation wrote the frame (ns): a client on
    /// the same machine gets its frame latency from it.
    pub server_time_ns: u64,
    /// Triangles and their materials: present in keyframes only.
    pub topology: Option<Topology>,
    /// Quantization origin (m), the keyframe's.
    pub origin_m: [f32; 3],
    /// Quantization step (m), the keyframe's.
    pub step_m: f32,
    /// Keyframe: quantized positions; other frames: differences from the keyframe's.
    pub positions: Vec<[i16; 3]>,
    /// The tool, when present.
    pub tool: Option<ToolState>,
}

/// Triangles of a keyframe.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Topology {
    /// Vertex indices.
    pub triangles: Vec<[u32; 3]>,
    /// Material per triangle (0 surface, 1 wound wall).
    pub materials: Vec<u8>,
}

/// The tool in a frame.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ToolState {
    /// Blade tip (m).
    pub tip_m: [f32; 3],
    /// Orientation (x, y, z, w).
    pub orientation_xyzw: [f32; 4],
    /// Force on the tool (N).
    pub force_n: [f32; 3],
}

/// Quantizes `positions` (m) to 16 bits over their box: returns the origin, the step and
/// the codes. Decoding is `origin + step · (code + 32768)`.
pub fn quantize(positions: &[[f32; 3]]) -> ([f32; 3], f32, Vec<[i16; 3]>) {
    let mut lo = [f32::INFINITY; 3];
    let mut hi = [f32::NEG_INFINITY; 3];
    for p in positions {
        for c in 0..3 {
            lo[c] = lo[c].min(p[c]);
            hi[c] = hi[c].max(p[c]);
        }
    }
    if positions.is_empty() {
        return ([0.0; 3], 1e-6, Vec::new());
    }
    let extent = (0..3).map(|c| hi[c] - lo[c]).fold(0.0f32, f32::max);
    // A little room, so that a frame after the keyframe that moved outwards still fits.
    let margin = 0.25 * extent.max(1e-3);
    let origin = lo.map(|l| l - margin);
    let step = (extent + 2.0 * margin) / 65535.0;
    let codes = positions
        .iter()
        .map(|p| [0, 1, 2].map(|c| quantize_one(p[c], origin[c], step)))
        .collect();
    (origin, step, codes)
}

/// The code of one coordinate (saturating at the ends of the range).
pub fn quantize_one(x: f32, origin: f32, step: f32) -> i16 {
    let q = ((x - origin) / step).round() - 32768.0;
    q.clamp(-32768.0, 32767.0) as i16
}

/// The coordinate of a code.
pub fn dequantize_one(code: i16, origin: f32, step: f32) -> f32 {
    origin + step * (f32::from(code) + 32768.0)
}

/// A frame as an observer reconstructs it.
#[derive(Debug, Clone, PartialEq)]
pub struct DecodedFrame {
    /// Frame counter.
    pub frame: u64,
    /// Simulation tick.
    pub sim_tick: u64,
    /// See [`ObserverFrame::server_time_ns`].
    pub server_time_ns: u64,
    /// It came as a keyframe.
    pub keyframe: bool,
    /// Vertex positions (m), within half a quantization step.
    pub positions: Vec<[f32; 3]>,
    /// Triangles and materials (of the keyframe).
    pub topology: Topology,
    /// The tool.
    pub tool: Option<ToolState>,
}

/// An observer's side of the frame stream: keeps the last keyframe and rebuilds every
/// frame from it.
#[derive(Debug, Default)]
pub struct FrameDecoder {
    key: Option<Keyframe>,
}

/// The keyframe a decoder holds.
#[derive(Debug)]
struct Keyframe {
    frame: u64,
    origin: [f32; 3],
    step: f32,
    codes: Vec<[i16; 3]>,
    topology: Topology,
}

impl FrameDecoder {
    /// A decoder that has no keyframe yet.
    pub fn new() -> Self {
        Self::default()
    }

    /// Decodes `frame`; `None` for a difference frame whose keyframe this decoder does not
    /// have (it arrived late or was skipped: the next keyframe puts it right).
    pub fn decode(&mut self, frame: &ObserverFrame) -> Option<DecodedFrame> {
        if let Some(topology) = &frame.topology {
            if frame.keyframe != frame.frame {
                return None;
            }
            self.key = Some(Keyframe {
                frame: frame.frame,
                origin: frame.origin_m,
                step: frame.step_m,
                codes: frame.positions.clone(),
                topology: topology.clone(),
            });
        }
        let key = self.key.as_ref()?;
        let (origin, step, codes, topology) = (&key.origin, &key.step, &key.codes, &key.topology);
        if key.frame != frame.keyframe || codes.len() != frame.positions.len() {
            return None;
        }
        let positions = if frame.topology.is_some() {
            codes
                .iter()
                .map(|q| [0, 1, 2].map(|c| dequantize_one(q[c], origin[c], *step)))
                .collect()
        } else {
            codes
                .iter()
                .zip(&frame.positions)
                .map(|(k, d)| {
                    [0, 1, 2].map(|c| dequantize_one(k[c].wrapping_add(d[c]), origin[c], *step))
                })
                .collect()
        };
        Some(DecodedFrame {
            frame: frame.frame,
            sim_tick: frame.sim_tick,
            server_time_ns: frame.server_time_ns,
            keyframe: frame.topology.is_some(),
            positions,
            topology: topology.clone(),
            tool: frame.tool,
        })
    }
}
