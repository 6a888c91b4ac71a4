//! A station's shared-memory services (iceoryx2 0.10.0, `ipc` service type).
//!
//! ```text
//!  scalpel/<station>/device/pose     DevicePose   device ─► server   1 kHz
//!  scalpel/<station>/device/force    DeviceForce  server ─► device   1 kHz
//!  scalpel/<station>/render/frames   [u8] + FrameHeader  server ─► renderers (frames.rate_hz)
//!  scalpel/<station>/render/events   event id 1 = a new frame was sent
//!  scalpel/<station>/device/connect  DeviceHello → DeviceWelcome   device ─► server, once
//! ```
//!
//! The builder settings here are the service contract: every process (Rust or not) opens
//! the services with exactly these (docs/PROTOCOL.md). The station's server makes them
//! (`ownership`); every other process only opens them. All layouts start with
//! `layout_version`; a reader drops a sample whose version it does not know.

use iceoryx2::node::NodeView;
use iceoryx2::port::event_id::EventId;
use iceoryx2::prelude::*;
use iceoryx2::service::builder::event::{
    Builder as EventBuilder, EventCreateError, EventOpenError,
};
use iceoryx2::service::builder::publish_subscribe::{
    Builder as PubSubBuilder, PublishSubscribeCreateError, PublishSubscribeOpenError,
};
use iceoryx2::service::builder::request_response::{
    RequestResponseCreateError, RequestResponseOpenError,
};
use iceoryx2::service::port_factory::event::PortFactory as EventFactory;
use iceoryx2::service::port_factory::publish_subscribe::PortFactory as PubSubFactory;
use thiserror::Error;

pub mod connect;
pub mod ownership;

/// The layout version of every type here. Bumped on any change of a field's meaning,
/// order or size.
pub const LAYOUT_VERSION: u32 = 2;

/// Longest station name (it becomes part of service and node names).
pub const MAX_STATION_NAME: usize = 48;

/// Pose service: publishers. The server takes poses only from the device that connected
/// (`connect`); room for more than one, so that a process publishing without having
/// connected does not lock the device out by holding the only place.
pub const POSE_MAX_PUBLISHERS: usize = 4;
/// Pose service: subscribers (the server's haptic thread and a spare for a monitor).
pub const POSE_MAX_SUBSCRIBERS: usize = 2;
/// Force service: subscribers (the device and a spare for a recorder).
pub const FORCE_MAX_SUBSCRIBERS: usize = 2;
/// Pose and force: samples a subscriber holds before the oldest is overwritten.
pub const DEVICE_BUFFER: usize = 4;
/// Frame service: renderers attached at once.
pub const FRAME_MAX_SUBSCRIBERS: usize = 8;
/// Frame service: frames a renderer holds before the oldest is overwritten.
pub const FRAME_BUFFER: usize = 2;
/// Frame service: frames a renderer is handed when the publisher next sends after it
/// attached (the last one sent).
pub const FRAME_HISTORY: usize = 1;
/// Frame events: listeners at once.
pub const FRAME_MAX_LISTENERS: usize = 8;
/// Event id announcing a new frame.
pub const EVENT_NEW_FRAME: usize = 1;

/// A device sample: where the tool is. Sent by the device at its rate (1 kHz).
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend)]
#[type_name("ScalpelDevicePose")]
#[repr(C)]
pub struct DevicePose {
    /// [`LAYOUT_VERSION`].
    pub layout_version: u32,
    /// Reserved, 0.
    pub flags: u32,
    /// The device's sample counter, from 1.
    pub seq: u64,
    /// The device's monotonic clock when it sampled (ns).
    pub device_time_ns: u64,
    /// Blade tip in the scene's frame (m).
    pub tip_m: [f64; 3],
    /// Tool orientation, unit quaternion (x, y, z, w); the blade's edge runs along the
    /// tool's local +z axis from the tip, its back toward local −x.
    pub orientation_xyzw: [f64; 4],
}

/// Force flag: the output stage's watchdog is fading the force (device or simulation lost).
pub const FORCE_FADED: u32 = 1;
/// Force flag: the request was not finite and was replaced by zero.
pub const FORCE_NAN_GUARDED: u32 = 2;

/// The force to render. Sent by the server on every haptic tick.
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend)]
#[type_name("ScalpelDeviceForce")]
#[repr(C)]
pub struct DeviceForce {
    /// [`LAYOUT_VERSION`].
    pub layout_version: u32,
    /// [`FORCE_FADED`], [`FORCE_NAN_GUARDED`].
    pub flags: u32,
    /// The server's haptic tick, on the station clock (ms since the server started: the
    /// clock instructors schedule faults on). It increases from one force to the next.
    pub tick: u64,
    /// `seq` of the last pose the server used (0: none yet).
    pub pose_seq: u64,
    /// The server's CLOCK_MONOTONIC at the haptic tick that computed this force (ns): a
    /// device can put its own sampling just before the server's ticks.
    pub tick_time_ns: u64,
    /// The server's CLOCK_MONOTONIC just before it sent this sample (ns): with the pose's
    /// `device_time_ns`, a device on the machine gets its pose-to-force latency without
    /// having to watch for the answer.
    pub sent_time_ns: u64,
    /// Force on the user's hand in the scene's frame (N), after the output stage: finite,
    /// at most the station's F_max, rate-limited.
    pub force_n: [f64; 3],
}

/// Frame flag: the tool pose fields are valid.
pub const FRAME_TOOL_PRESENT: u32 = 1;
/// Frame flag: the blade is cutting.
pub const FRAME_CUTTING: u32 = 2;

/// The header of a render frame (iceoryx2 user header). The payload is a byte slice laid
/// out as [`FrameLayout`] says: positions, normals, triangles, material ids.
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend)]
#[type_name("ScalpelFrameHeader")]
#[repr(C)]
pub struct FrameHeader {
    /// [`LAYOUT_VERSION`].
    pub layout_version: u32,
    /// [`FRAME_TOOL_PRESENT`], [`FRAME_CUTTING`].
    pub flags: u32,
    /// Frame counter, from 1.
    pub frame: u64,
    /// Simulation ticks so far.
    pub sim_tick: u64,
    /// Server's monotonic clock when the frame was written (ns).
    pub server_time_ns: u64,
    /// The device's sample counter of the tool pose the frame's blade answers (0: none).
    pub pose_seq: u64,
    /// When the server's haptic thread took that pose (CLOCK_MONOTONIC, ns; 0: none):
    /// a renderer on the same machine gets its pose-to-screen latency from it.
    pub pose_received_ns: u64,
    /// Surface vertices.
    pub n_vertices: u32,
    /// Surface triangles.
    pub n_triangles: u32,
    /// Byte offsets in the payload of the four arrays (see [`FrameLayout`]).
    pub positions_offset: u32,
    /// See `positions_offset`.
    pub normals_offset: u32,
    /// See `positions_offset`.
    pub triangles_offset: u32,
    /// See `positions_offset`.
    pub materials_offset: u32,
    /// Blade tip (m).
    pub tool_tip_m: [f32; 3],
    /// Blade length (m).
    pub blade_length_m: f32,
    /// Tool orientation (x, y, z, w).
    pub tool_orientation_xyzw: [f32; 4],
    /// The force the simulation computed on the tool (N), before the output stage.
    pub force_n: [f32; 3],
    /// Blade travel while cutting, summed (mm).
    pub cut_length_mm: f32,
}

/// Material id of the organ's outer surface.
pub const MATERIAL_SURFACE: u8 = 0;
/// Material id of wound walls.
pub const MATERIAL_WOUND: u8 = 1;

/// Where the arrays of a frame sit in its payload (all little-endian):
/// `positions: [f32; 3·n_vertices]` (m), `normals: [f32; 3·n_vertices]` (unit),
/// `triangles: [u32; 3·n_triangles]` (counter-clockwise seen from outside),
/// `materials: [u8; n_triangles]`, then padding to 4 bytes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FrameLayout {
    /// Vertices.
    pub n_vertices: usize,
    /// Triangles.
    pub n_triangles: usize,
    /// Byte offset of the positions.
    pub positions: usize,
    /// Byte offset of the normals.
    pub normals: usize,
    /// Byte offset of the triangles.
    pub triangles: usize,
    /// Byte offset of the material ids.
    pub materials: usize,
    /// Payload length in bytes.
    pub len: usize,
}

impl FrameLayout {
    /// The layout for a surface of this size.
    pub fn new(n_vertices: usize, n_triangles: usize) -> Self {
        let positions = 0;
        let normals = positions + 12 * n_vertices;
        let triangles = normals + 12 * n_vertices;
        let materials = triangles + 12 * n_triangles;
        let len = (materials + n_triangles).next_multiple_of(4);
        Self {
            n_vertices,
            n_triangles,
            positions,
            normals,
            triangles,
            materials,
            len,
        }
    }

    /// The layout a header announces, if it is consistent with a payload of `len` bytes.
    pub fn of(header: &FrameHeader, len: usize) -> Result<Self, ShmError> {
        if header.layout_version != LAYOUT_VERSION {
            return Err(ShmError::Version {
                found: header.layout_version,
            });
        }
        let layout = Self::new(header.n_vertices as usize, header.n_triangles as usize);
        let offsets = [
            (header.positions_offset, layout.positions),
            (header.normals_offset, layout.normals),
            (header.triangles_offset, layout.triangles),
            (header.materials_offset, layout.materials),
        ];
        if layout.len != len || offsets.iter().any(|&(h, l)| h as usize != l) {
            return Err(ShmError::Layout {
                detail: format!(
                    "frame {}: {} vertices and {} triangles need {} bytes at offsets {:?}, the sample has {} bytes at {:?}",
                    header.frame,
                    header.n_vertices,
                    header.n_triangles,
                    layout.len,
                    offsets.map(|o| o.1),
                    len,
                    offsets.map(|o| o.0)
                ),
            });
        }
        Ok(layout)
    }

    /// Fills the header's counts and offsets.
    pub fn describe(&self, header: &mut FrameHeader) {
        header.n_vertices = self.n_vertices as u32;
        header.n_triangles = self.n_triangles as u32;
        header.positions_offset = self.positions as u32;
        header.normals_offset = self.normals as u32;
        header.triangles_offset = self.triangles as u32;
        header.materials_offset = self.materials as u32;
    }
}

/// Something wrong on the shared-memory side.
#[derive(Debug, Error)]
pub enum ShmError {
    /// A station name that cannot name services.
    #[error(
        "station name {name:?}: {why} (use 1 to {MAX_STATION_NAME} letters, digits, '-' or '_')"
    )]
    StationName {
        /// The name given.
        name: String,
        /// What is wrong.
        why: &'static str,
    },
    /// iceoryx2 refused (creating a node, opening a service, a port...).
    #[error("{what} {service}: {detail}")]
    Iceoryx {
        /// What was being done.
        what: &'static str,
        /// The service or node.
        service: String,
        /// iceoryx2's error.
        detail: String,
    },
    /// The station's service does not exist: its server is not running.
    #[error(
        "station {station} is not running on this machine (no service {service}: its server makes them when it starts)"
    )]
    NoStation {
        /// The station.
        station: String,
        /// The service looked for.
        service: String,
    },
    /// The station refused a device that said hello.
    #[error("station {station} refused the device: {reason}")]
    Refused {
        /// The station.
        station: String,
        /// Why.
        reason: String,
    },
    /// Another process holds a service the station's server must make.
    #[error("{service}: {detail}")]
    Taken {
        /// The service.
        service: String,
        /// Who holds it and what to do.
        detail: String,
    },
    /// A sample of a layout version this build does not know.
    #[error("layout version {found}, this build reads version {LAYOUT_VERSION}")]
    Version {
        /// The version found.
        found: u32,
    },
    /// A frame whose header does not match its payload.
    #[error("inconsistent frame: {detail}")]
    Layout {
        /// What does not match.
        detail: String,
    },
}

/// Checks a station name.
pub fn check_station(name: &str) -> Result<(), ShmError> {
    let why = if name.is_empty() {
        Some("empty")
    } else if name.len() > MAX_STATION_NAME {
        Some("too long")
    } else if !name
        .bytes()
        .all(|b| b.is_ascii_alphanumeric() || b == b'-' || b == b'_')
    {
        Some("has a character other than a letter, digit, '-' or '_'")
    } else {
        None
    };
    match why {
        Some(why) => Err(ShmError::StationName {
            name: name.to_string(),
            why,
        }),
        None => Ok(()),
    }
}

/// The service `scalpel/<station>/<what>`.
pub fn service_name(station: &str, what: &str) -> Result<ServiceName, ShmError> {
    check_station(station)?;
    let name = format!("scalpel/{station}/{what}");
    ServiceName::new(&name).map_err(|e| iceoryx("naming service", &name, e))
}

/// Wraps an iceoryx2 error: what was being done, to which service or node.
pub fn iceoryx(what: &'static str, service: &str, e: impl std::fmt::Debug) -> ShmError {
    ShmError::Iceoryx {
        what,
        service: service.to_string(),
        detail: format!("{e:?}"),
    }
}

/// A node for one role of one process at a station, e.g. `scalpel-server.haptic.lab1`.
/// Creating it removes what dead nodes left behind (a killed server or device).
pub fn node(role: &str, station: &str) -> Result<Node<ipc::Service>, ShmError> {
    check_station(station)?;
    let name = format!("{role}.{station}");
    let node_name = NodeName::new(&name).map_err(|e| iceoryx("naming node", &name, e))?;
    NodeBuilder::new()
        .name(&node_name)
        .signal_handling_mode(SignalHandlingMode::Disabled)
        .create::<ipc::Service>()
        .map_err(|e| iceoryx("creating node", &name, e))
}

/// Quietens iceoryx2's own logging to errors (its warnings, e.g. "no config file
/// was loaded", are noise to a user); `IOX2_LOG_LEVEL` overrides it.
pub fn quiet_logging() {
    set_log_level_from_env_or(LogLevel::Error);
}

/// A node seen on this machine.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct NodeSeen {
    /// Its name, e.g. `scalpel-viewer.lab1`.
    pub name: String,
    /// Its process is alive.
    pub alive: bool,
}

/// The nodes of `station` on this machine, alive or dead (not yet cleaned up).
pub fn station_nodes(station: &str) -> Result<Vec<NodeSeen>, ShmError> {
    check_station(station)?;
    let suffix = format!(".{station}");
    let mut seen = Vec::new();
    Node::<ipc::Service>::list(Config::global_config(), |state| {
        let (name, alive) = match &state {
            NodeState::Alive(v) => (v.details().as_ref().map(|d| d.name().to_string()), true),
            NodeState::Dead(v) => (v.details().as_ref().map(|d| d.name().to_string()), false),
            _ => (None, false),
        };
        if let Some(name) = name.filter(|n| n.ends_with(&suffix)) {
            seen.push(NodeSeen { name, alive });
        }
        CallbackProgression::Continue
    })
    .map_err(|e| iceoryx("listing nodes of", station, e))?;
    Ok(seen)
}

/// Opens `name` of `station` (made by the station's server: `ownership::claim`); a
/// service that does not exist means the station is not running.
pub(crate) fn opened<F, E: ServiceError>(
    station: &str,
    name: &ServiceName,
    result: Result<F, E>,
) -> Result<F, ShmError> {
    result.map_err(|e| {
        if e.missing() {
            ShmError::NoStation {
                station: station.to_string(),
                service: name.as_str().to_string(),
            }
        } else {
            iceoryx("opening", name.as_str(), e)
        }
    })
}

/// iceoryx2's open and create errors, as far as opening and claiming need to tell them apart.
pub(crate) trait ServiceError: std::fmt::Debug {
    /// The service does not exist.
    fn missing(&self) -> bool {
        false
    }
    /// The service exists already.
    fn exists(&self) -> bool {
        false
    }
}

impl ServiceError for PublishSubscribeOpenError {
    fn missing(&self) -> bool {
        matches!(self, Self::DoesNotExist)
    }
}
impl ServiceError for EventOpenError {
    fn missing(&self) -> bool {
        matches!(self, Self::DoesNotExist)
    }
}
impl ServiceError for RequestResponseOpenError {
    fn missing(&self) -> bool {
        matches!(self, Self::DoesNotExist)
    }
}
impl ServiceError for PublishSubscribeCreateError {
    fn exists(&self) -> bool {
        matches!(self, Self::AlreadyExists)
    }
}
impl ServiceError for EventCreateError {
    fn exists(&self) -> bool {
        matches!(self, Self::AlreadyExists)
    }
}
impl ServiceError for RequestResponseCreateError {
    fn exists(&self) -> bool {
        matches!(self, Self::AlreadyExists)
    }
}

/// The pose service's builder with the contract's settings (`open` it; only the station's
/// server creates it).
pub fn pose_builder(
    node: &Node<ipc::Service>,
    name: &ServiceName,
) -> PubSubBuilder<DevicePose, (), ipc::Service> {
    node.service_builder(name)
        .publish_subscribe::<DevicePose>()
        .max_publishers(POSE_MAX_PUBLISHERS)
        .max_subscribers(POSE_MAX_SUBSCRIBERS)
        .subscriber_max_buffer_size(DEVICE_BUFFER)
        .history_size(0)
}

/// The force service's builder with the contract's settings.
pub fn force_builder(
    node: &Node<ipc::Service>,
    name: &ServiceName,
) -> PubSubBuilder<DeviceForce, (), ipc::Service> {
    node.service_builder(name)
        .publish_subscribe::<DeviceForce>()
        .max_publishers(1)
        .max_subscribers(FORCE_MAX_SUBSCRIBERS)
        .subscriber_max_buffer_size(DEVICE_BUFFER)
        .history_size(0)
}

/// The frame service's builder with the contract's settings.
pub fn frame_builder(
    node: &Node<ipc::Service>,
    name: &ServiceName,
) -> PubSubBuilder<[u8], FrameHeader, ipc::Service> {
    node.service_builder(name)
        .publish_subscribe::<[u8]>()
        .user_header::<FrameHeader>()
        .max_publishers(1)
        .max_subscribers(FRAME_MAX_SUBSCRIBERS)
        .subscriber_max_buffer_size(FRAME_BUFFER)
        .history_size(FRAME_HISTORY)
}

/// The frame event service's builder with the contract's settings.
pub fn event_builder(node: &Node<ipc::Service>, name: &ServiceName) -> EventBuilder<ipc::Service> {
    node.service_builder(name)
        .event()
        .max_listeners(FRAME_MAX_LISTENERS)
}

/// The pose service of a running station (device ─► server).
pub fn pose_service(
    node: &Node<ipc::Service>,
    station: &str,
) -> Result<PubSubFactory<ipc::Service, DevicePose, ()>, ShmError> {
    let name = service_name(station, "device/pose")?;
    opened(station, &name, pose_builder(node, &name).open())
}

/// The force service of a running station (server ─► device).
pub fn force_service(
    node: &Node<ipc::Service>,
    station: &str,
) -> Result<PubSubFactory<ipc::Service, DeviceForce, ()>, ShmError> {
    let name = service_name(station, "device/force")?;
    opened(station, &name, force_builder(node, &name).open())
}

/// The render frame service of a running station.
pub fn frame_service(
    node: &Node<ipc::Service>,
    station: &str,
) -> Result<PubSubFactory<ipc::Service, [u8], FrameHeader>, ShmError> {
    let name = service_name(station, "render/frames")?;
    opened(station, &name, frame_builder(node, &name).open())
}

/// The render event service of a running station ([`EVENT_NEW_FRAME`]).
pub fn frame_events(
    node: &Node<ipc::Service>,
    station: &str,
) -> Result<EventFactory<ipc::Service>, ShmError> {
    let name = service_name(station, "render/events")?;
    opened(station, &name, event_builder(node, &name).open())
}

/// The new-frame event id.
pub fn new_frame_event() -> EventId {
    EventId::new(EVENT_NEW_FRAME)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn layouts_have_the_documented_sizes() {
        // docs/PROTOCOL.md gives these sizes; a change here is a protocol change.
        assert_eq!(size_of::<DevicePose>(), 80);
        assert_eq!(size_of::<DeviceForce>(), 64);
        assert_eq!(size_of::<FrameHeader>(), 120);
        assert_eq!(align_of::<DevicePose>(), 8);
        assert_eq!(align_of::<FrameHeader>(), 8);
    }

    #[test]
    fn frame_layout_round_trips_through_the_header() {
        let layout = FrameLayout::new(5, 3);
        assert_eq!(layout.len, 60 + 60 + 36 + 4);
        let mut header = FrameHeader {
            layout_version: LAYOUT_VERSION,
            ..Default::default()
        };
        layout.describe(&mut header);
        assert_eq!(FrameLayout::of(&header, layout.len).unwrap(), layout);
        assert!(FrameLayout::of(&header, layout.len + 4).is_err());
        header.layout_version = LAYOUT_VERSION + 1;
        assert!(matches!(
            FrameLayout::of(&header, layout.len),
            Err(ShmError::Version { found }) if found == LAYOUT_VERSION + 1
        ));
    }

    #[test]
    fn station_names_are_checked() {
        assert!(check_station("lab-1_a").is_ok());
        for bad in ["", "a/b", "x y", &"s".repeat(49)] {
            let e = check_station(bad).unwrap_err().to_string();
            assert!(e.contains("station name"), "{e}");
        }
    }
}
