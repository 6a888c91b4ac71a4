//! The station's shared memory, seen from its main thread: it makes (claims) the station's
//! services before anything else runs and holds them for the station's run
//! (`scalpel_proto::shm::ownership`), answers devices that connect, and notices the device
//! come and go.
//!
//! A device connects through the handshake on `device/connect` (docs/PROTOCOL.md): the
//! first to say hello while no device is connected is accepted, and from then on the haptic
//! thread takes poses from its node only ([`DeviceGate`]). A device process that exits
//! cleanly removes its publisher; one that is killed leaves it behind, and only iceoryx2's
//! dead-node cleanup removes it (dependencies.md §6). The monitor runs the cleanup on every
//! poll (the main thread polls every 10 ms), so a killed device — or viewer — is cleaned
//! within a poll or two, and the device is lost when no publisher of its node is left.

use std::sync::Arc;

use iceoryx2::port::server::Server;
use iceoryx2::prelude::*;
use scalpel_proto::shm::connect::{DeviceHello, DeviceWelcome};
use scalpel_proto::shm::ownership::{self, StationServices};
use scalpel_proto::shm::{self, LAYOUT_VERSION};

use crate::shm_device::DeviceGate;

/// Time an accepted device has to make its pose publisher before it counts as gone (s):
/// it makes it right after the welcome, within milliseconds.
const PUBLISHER_GRACE_S: f64 = 2.0;

/// A change the monitor saw.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum DeviceEvent {
    /// A device connected (its name).
    Connected(String),
    /// A device was refused (its name and why).
    Refused(String, String),
    /// The device's publisher is gone (it exited, or it died and was cleaned up).
    Lost,
}

/// The device the station took.
struct Accepted {
    node: u128,
    name: String,
    since_s: f64,
    published: bool,
}

/// The station's services and the device on them.
pub struct DeviceMonitor {
    services: StationServices,
    connect: Server<ipc::Service, DeviceHello, (), DeviceWelcome, ()>,
    gate: Arc<DeviceGate>,
    device: Option<Accepted>,
    cleaned: u64,
    node: Node<ipc::Service>,
}

impl DeviceMonitor {
    /// Makes `station`'s services (refusing, with who holds it, a service another live
    /// process made) and answers devices into `gate`.
    pub fn open(station: &str, gate: Arc<DeviceGate>) -> Result<Self, shm::ShmError> {
        let owner = ownership::owner_node_name(station);
        let role = owner
            .strip_suffix(&format!(".{station}"))
            .unwrap_or("scalpel-server.owner");
        // (Creating the node removes what dead nodes left behind.)
        let node = shm::node(role, station)?;
        let services = ownership::claim(&node, station)?;
        let connect = services
            .connect
            .server_builder()
            .create()
            .map_err(|e| shm::iceoryx("answering devices of station", station, e))?;
        Ok(Self {
            services,
            connect,
            gate,
            device: None,
            cleaned: 0,
            node,
        })
    }

    /// Services a previous server of this station left and this one took over.
    pub fn reused(&self) -> &[String] {
        &self.services.reused
    }

    /// At `now_s`: cleans up after dead nodes, answers devices that said hello, and reports
    /// one change of the device's presence, if any.
    pub fn poll(&mut self, now_s: f64) -> Option<DeviceEvent> {
        self.cleaned += self.node.try_cleanup_dead_nodes().cleanups;
        if let Some(d) = &mut self.device {
            let node = d.node;
            let mut publishing = false;
            self.services.pose.dynamic_config().list_publishers(|p| {
                publishing |= p.node_id.value() == node;
                CallbackProgression::Continue
            });
            d.published |= publishing;
            if !publishing && (d.published || now_s - d.since_s > PUBLISHER_GRACE_S) {
                self.device = None;
                self.gate.accept(None);
                return Some(DeviceEvent::Lost);
            }
        }
        self.answer(now_s)
    }

    /// Answers the first waiting hello (one a poll: a device's is answered within 10 ms).
    fn answer(&mut self, now_s: f64) -> Option<DeviceEvent> {
        let request = self.connect.receive().ok().flatten()?;
        let hello = *request.payload();
        let node = request.header().node_id().value();
        let name = hello.name();
        let refusal = if hello.layout_version != LAYOUT_VERSION {
            Some(format!(
                "layout version {}, this station speaks {LAYOUT_VERSION}",
                hello.layout_version
            ))
        } else {
            self.device
                .as_ref()
                .filter(|d| d.node != node)
                .map(|d| format!("the station has a device already ({})", d.name))
        };
        let welcome = match &refusal {
            Some(reason) => DeviceWelcome::refused(reason),
            None => DeviceWelcome::accepted(),
        };
        // A device that gave up waiting is not there to read it: nothing to do.
        let _ = request.send_copy(welcome);
        match refusal {
            Some(reason) => Some(DeviceEvent::Refused(name, reason)),
            None => {
                let again = self.device.as_ref().is_some_and(|d| d.node == node);
                self.device = Some(Accepted {
                    node,
                    name: name.clone(),
                    since_s: now_s,
                    published: again,
                });
                self.gate.accept(Some(node));
                (!again).then_some(DeviceEvent::Connected(name))
            }
        }
    }

    /// A device is connected (as of the last poll).
    pub fn connected(&self) -> bool {
        self.device.is_some()
    }

    /// Dead nodes (of any process at any station) cleaned up so far.
    pub fn dead_nodes_cleaned(&self) -> u64 {
        self.cleaned
    }
}
