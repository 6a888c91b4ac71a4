//! Notices a shared-memory device come and go. A device process that exits cleanly
//! removes its publisher; one that is killed leaves it behind, and only iceoryx2's
//! dead-node cleanup removes it (dependencies.md §6). The monitor runs the cleanup on
//! every poll (the main thread polls every 50 ms), so a killed device — or viewer — is
//! cleaned within a poll or two, and a restarted device is seen as a new connection.

use iceoryx2::prelude::*;
use iceoryx2::service::port_factory::PortFactory as _;
use iceoryx2::service::port_factory::publish_subscribe::PortFactory;
use scalpel_proto::shm::{self, DevicePose};

/// A change the monitor saw.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DeviceEvent {
    /// A device publishes poses.
    Connected,
    /// The device's publisher is gone (it exited, or it died and was cleaned up).
    Lost,
}

/// Watches a station's pose service.
pub struct DeviceMonitor {
    service: PortFactory<ipc::Service, DevicePose, ()>,
    connected: bool,
    cleaned: u64,
    node: Node<ipc::Service>,
}

impl DeviceMonitor {
    /// Watches the device services of `station`.
    pub fn open(station: &str) -> Result<Self, shm::ShmError> {
        let node = shm::node("scalpel-server.monitor", station)?;
        let service = shm::pose_service(&node, station)?;
        Ok(Self {
            service,
            connected: false,
            cleaned: 0,
            node,
        })
    }

    /// Cleans up after dead nodes, then reports a change of the device's presence.
    pub fn poll(&mut self) -> Option<DeviceEvent> {
        self.cleaned += self.node.try_cleanup_dead_nodes().cleanups;
        let connected = self.service.dynamic_config().number_of_publishers() > 0;
        if connected == self.connected {
            return None;
        }
        self.connected = connected;
        Some(if connected {
            DeviceEvent::Connected
        } else {
            DeviceEvent::Lost
        })
    }

    /// A device publishes poses (as of the last poll).
    pub fn connected(&self) -> bool {
        self.connected
    }

    /// Dead nodes (of any process at any station) cleaned up so far.
    pub fn dead_nodes_cleaned(&self) -> u64 {
        self.cleaned
    }
}
