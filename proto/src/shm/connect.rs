//! The device's connect handshake (`scalpel/<station>/device/connect`, request-response).
//!
//! A pose is taken only from the device the station accepted: before it publishes, a device
//! sends a [`DeviceHello`] and the server answers a [`DeviceWelcome`]; the server then takes
//! poses only from the node that said hello (the node id in each sample's header), and one
//! device at a time. Issue 45: any process that made a pose publisher was taken for the
//! device ("device connected"), and one that made it first locked the real device out.

use iceoryx2::prelude::*;
use iceoryx2::service::port_factory::request_response::PortFactory as RequestResponseFactory;

use super::{LAYOUT_VERSION, ShmError, iceoryx, service_name};

/// Longest device name in a hello (bytes, UTF-8, zero-padded).
pub const DEVICE_NAME_BYTES: usize = 32;
/// Longest reason in a welcome (bytes, UTF-8, zero-padded).
pub const REASON_BYTES: usize = 120;
/// Devices that may be asking at once (clients of the connect service).
pub const CONNECT_MAX_CLIENTS: usize = 8;

/// A device asks to be the station's device.
#[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("ScalpelDeviceHello")]
#[repr(C)]
pub struct DeviceHello {
    /// [`LAYOUT_VERSION`] of the device's samples.
    pub layout_version: u32,
    /// Reserved, 0.
    pub flags: u32,
    /// The device's name for the station's log (UTF-8, zero-padded).
    pub name: [u8; DEVICE_NAME_BYTES],
}

/// Welcome flag: the station takes this device's poses.
pub const WELCOME_ACCEPTED: u32 = 1;

/// The station's answer.
#[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("ScalpelDeviceWelcome")]
#[repr(C)]
pub struct DeviceWelcome {
    /// [`LAYOUT_VERSION`] of the station.
    pub layout_version: u32,
    /// [`WELCOME_ACCEPTED`], or 0 with the reason.
    pub flags: u32,
    /// Why not (UTF-8, zero-padded).
    pub reason: [u8; REASON_BYTES],
}

/// `text` in `N` zero-padded bytes, cut at a character boundary.
fn padded<const N: usize>(text: &str) -> [u8; N] {
    let mut out = [0u8; N];
    let mut end = text.len().min(N);
    while !text.is_char_boundary(end) {
        end -= 1;
    }
    out[..end].copy_from_slice(&text.as_bytes()[..end]);
    out
}

/// Zero-padded bytes as text (lossy).
fn unpadded(bytes: &[u8]) -> String {
    let end = bytes.iter().position(|&b| b == 0).unwrap_or(bytes.len());
    String::from_utf8_lossy(&bytes[..end]).into_owned()
}

impl DeviceHello {
    /// A hello from the device `name`.
    pub fn new(name: &str) -> Self {
        Self {
            layout_version: LAYOUT_VERSION,
            flags: 0,
            name: padded(name),
        }
    }

    /// The device's name.
    pub fn name(&self) -> String {
        unpadded(&self.name)
    }
}

impl DeviceWelcome {
    /// The station takes the device.
    pub fn accepted() -> Self {
        Self {
            layout_version: LAYOUT_VERSION,
            flags: WELCOME_ACCEPTED,
            reason: [0; REASON_BYTES],
        }
    }

    /// The station refuses the device, saying why.
    pub fn refused(reason: &str) -> Self {
        Self {
            layout_version: LAYOUT_VERSION,
            flags: 0,
            reason: padded(reason),
        }
    }

    /// Whether the station takes the device.
    pub fn is_accepted(&self) -> bool {
        self.flags & WELCOME_ACCEPTED != 0
    }

    /// Why not.
    pub fn reason(&self) -> String {
        unpadded(&self.reason)
    }
}

/// The connect service of a running station (a device opens it; the server creates it:
/// `ownership::claim`).
pub fn connect_service(
    node: &Node<ipc::Service>,
    station: &str,
) -> Result<RequestResponseFactory<ipc::Service, DeviceHello, (), DeviceWelcome, ()>, ShmError> {
    let name = service_name(station, "device/connect")?;
    super::opened(station, &name, connect_builder(node, &name).open())
}

/// The builder with the contract's settings.
pub(super) fn connect_builder(
    node: &Node<ipc::Service>,
    name: &ServiceName,
) -> iceoryx2::service::builder::request_response::Builder<
    DeviceHello,
    (),
    DeviceWelcome,
    (),
    ipc::Service,
> {
    node.service_builder(name)
        .request_response::<DeviceHello, DeviceWelcome>()
        .max_servers(1)
        .max_clients(CONNECT_MAX_CLIENTS)
}

/// Connects `node` to `station` as its device `name`: says hello and waits up to `timeout`
/// for the welcome. After `Ok`, the station takes poses from publishers of this node.
pub fn hello(
    node: &Node<ipc::Service>,
    station: &str,
    name: &str,
    timeout: std::time::Duration,
) -> Result<(), ShmError> {
    let service = connect_service(node, station)?;
    let client = service
        .client_builder()
        .create()
        .map_err(|e| handshake_error(station, e))?;
    let pending = client
        .send_copy(DeviceHello::new(name))
        .map_err(|e| handshake_error(station, e))?;
    let end = std::time::Instant::now() + timeout;
    loop {
        if let Some(response) = pending.receive().map_err(|e| handshake_error(station, e))? {
            let welcome = *response.payload();
            return if welcome.is_accepted() {
                Ok(())
            } else {
                Err(ShmError::Refused {
                    station: station.to_string(),
                    reason: welcome.reason(),
                })
            };
        }
        if std::time::Instant::now() > end {
            return Err(handshake_error(
                station,
                format!("no welcome within {} s", timeout.as_secs_f64()),
            ));
        }
        std::thread::sleep(std::time::Duration::from_millis(1));
    }
}

/// Wraps an iceoryx2 error of the handshake.
pub fn handshake_error(station: &str, e: impl std::fmt::Debug) -> ShmError {
    iceoryx("connecting to station", station, e)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_and_reasons_are_cut_and_read_back() {
        assert_eq!(DeviceHello::new("mock").name(), "mock");
        let long = "é".repeat(40);
        let h = DeviceHello::new(&long);
        assert_eq!(h.name(), "é".repeat(16));
        let w = DeviceWelcome::refused("busy");
        assert!(!w.is_accepted());
        assert_eq!(w.reason(), "busy");
        assert!(DeviceWelcome::accepted().is_accepted());
        assert_eq!(size_of::<DeviceHello>(), 40);
        assert_eq!(size_of::<DeviceWelcome>(), 128);
    }
}
