//! Who owns a station's services: its server. The server creates every service of its
//! station before anything else runs (`create`, with an owner attribute naming the server's
//! owner node); devices and renderers only ever open them. A service that exists already is
//!
//! - **reused** when a previous server of this station made it (its owner node is dead: a
//!   server killed with SIGKILL; a viewer that stayed attached keeps it alive);
//! - **made again** when another process made it and every node holding it is dead;
//! - **refused**, naming the live processes that hold it, when another process made it and
//!   is alive — issue 45: a squatter that made the pose service first was taken for the
//!   device and locked the real one out; one that made the frame service fed renderers its
//!   own frames.
//!
//! iceoryx2 0.10 keeps other users out by file modes (shared memory 0600, static configs
//! 0400); within the station's user every process is trusted (docs/SERVER.md, "Who may use a
//! station's shared memory"). What this adds is that nothing takes the station's place by
//! being there first, and that the server says who did.

use iceoryx2::config::Config;
use iceoryx2::node::NodeView;
use iceoryx2::prelude::*;
use iceoryx2::service::attribute::{AttributeKey, AttributeSpecifier, AttributeValue};
use iceoryx2::service::port_factory::event::PortFactory as EventFactory;
use iceoryx2::service::port_factory::publish_subscribe::PortFactory as PubSubFactory;
use iceoryx2::service::port_factory::request_response::PortFactory as RequestResponseFactory;

use super::connect::{DeviceHello, DeviceWelcome, connect_builder};
use super::{
    DeviceForce, DevicePose, FrameHeader, ServiceError, ShmError, event_builder, force_builder,
    frame_builder, iceoryx, pose_builder, service_name,
};

/// The attribute a server puts on the services it creates.
pub const OWNER_KEY: &str = "scalpel-owner";

/// The node a server holds for its whole run, named in its services' owner attribute.
pub fn owner_node_name(station: &str) -> String {
    format!("scalpel-server.owner.{station}")
}

/// A process holding a service, as far as this user can see it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Holder {
    /// Its node's name (`None`: another user's node, or details missing).
    pub name: Option<String>,
    /// Alive, dead, or `None`: another user's (cannot be told).
    pub alive: Option<bool>,
    /// Its process id.
    pub pid: Option<i32>,
}

impl std::fmt::Display for Holder {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{}",
            self.name.as_deref().unwrap_or("a node of another user")
        )?;
        if let Some(pid) = self.pid {
            write!(f, " (pid {pid})")?;
        }
        Ok(())
    }
}

/// What to do with a service that exists already.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Verdict {
    /// A previous server of this station made it: open it.
    Reuse,
    /// Nothing alive holds it: clean up after the dead and make it again.
    Recreate,
    /// Refuse to start, saying this.
    Refuse(String),
}

/// The verdict on an existing service of `station` whose owner attribute is `owner` and
/// whose nodes are `holders`.
pub fn verdict(station: &str, owner: Option<&str>, holders: &[Holder]) -> Verdict {
    let ours = owner_node_name(station);
    if owner == Some(ours.as_str()) {
        return match holders
            .iter()
            .find(|h| h.alive == Some(true) && h.name.as_deref() == Some(ours.as_str()))
        {
            Some(server) => Verdict::Refuse(format!(
                "another server of station {station} is running ({server})"
            )),
            None => Verdict::Reuse,
        };
    }
    let live: Vec<String> = holders
        .iter()
        .filter(|h| h.alive != Some(false))
        .map(Holder::to_string)
        .collect();
    if live.is_empty() {
        return Verdict::Recreate;
    }
    Verdict::Refuse(format!(
        "another process made it, not this station's server, and holds it: {}. Stop it, or give this station another name; only a station's server creates its services (docs/SERVER.md, \"Who may use a station's shared memory\")",
        live.join(", ")
    ))
}

/// An existing service's owner attribute and the processes holding it.
type Found = (Option<String>, Vec<Holder>);

/// The owner attribute and the nodes of the service `name` (with `pattern`), if it exists.
fn inspect(name: &ServiceName, pattern: MessagingPattern) -> Result<Option<Found>, ShmError> {
    let Some(details) = ipc::Service::details(name, Config::global_config(), pattern)
        .map_err(|e| iceoryx("inspecting", name.as_str(), e))?
    else {
        return Ok(None);
    };
    let key =
        AttributeKey::new(OWNER_KEY.as_bytes()).map_err(|e| iceoryx("naming", OWNER_KEY, e))?;
    let owner = details
        .static_details
        .attributes()
        .key_value(&key, 0)
        .map(|v| String::from_utf8_lossy(v.as_bytes()).into_owned());
    let holders = details
        .dynamic_details
        .map(|d| d.nodes)
        .unwrap_or_default()
        .iter()
        .map(|state| {
            let pid = state
                .node_id()
                .pid::<ipc::Service>()
                .ok()
                .map(|p| p.value());
            let (alive, name) = match state {
                NodeState::Alive(v) => (
                    Some(true),
                    v.details().as_ref().map(|d| d.name().to_string()),
                ),
                NodeState::Dead(v) => (
                    Some(false),
                    v.details().as_ref().map(|d| d.name().to_string()),
                ),
                NodeState::Inaccessible(_) | NodeState::Undefined(_) => (None, None),
            };
            Holder { name, alive, pid }
        })
        .collect();
    Ok(Some((owner, holders)))
}

/// Creates one service with the owner attribute, or settles an existing one (the module
/// docs). `create` and `open` are the service's builder calls.
fn claim_one<F, C: ServiceError, O: ServiceError>(
    node: &Node<ipc::Service>,
    station: &str,
    name: &ServiceName,
    pattern: MessagingPattern,
    create: impl Fn(&AttributeSpecifier) -> Result<F, C>,
    open: impl Fn() -> Result<F, O>,
) -> Result<(F, bool), ShmError> {
    let owner = owner_node_name(station);
    let attributes = AttributeSpecifier::new()
        .define(
            &AttributeKey::new(OWNER_KEY.as_bytes())
                .map_err(|e| iceoryx("naming", OWNER_KEY, e))?,
            &AttributeValue::new(owner.as_bytes())
                .map_err(|e| iceoryx("naming", "the owner", e))?,
        )
        .map_err(|e| iceoryx("naming", "the owner", e))?;
    // Twice at most: once more after the dead are cleaned up.
    for attempt in 0..2 {
        match create(&attributes) {
            Ok(f) => return Ok((f, false)),
            Err(e) if !e.exists() => return Err(iceoryx("creating", name.as_str(), e)),
            Err(_) => {}
        }
        let Some((owner, holders)) = inspect(name, pattern)? else {
            continue; // (gone meanwhile)
        };
        match verdict(station, owner.as_deref(), &holders) {
            Verdict::Reuse => {
                return open()
                    .map(|f| (f, true))
                    .map_err(|e| iceoryx("opening", name.as_str(), e));
            }
            Verdict::Recreate if attempt == 0 => {
                node.try_cleanup_dead_nodes();
            }
            Verdict::Recreate => {
                return Err(ShmError::Taken {
                    service: name.as_str().to_string(),
                    detail: "it exists with nothing alive holding it, and cleaning up after dead processes did not remove it (remove the station's files under /tmp/iceoryx2 and /dev/shm/iox2_*)".into(),
                });
            }
            Verdict::Refuse(detail) => {
                return Err(ShmError::Taken {
                    service: name.as_str().to_string(),
                    detail,
                });
            }
        }
    }
    Err(iceoryx(
        "creating",
        name.as_str(),
        "it kept appearing and vanishing",
    ))
}

/// The station's services, made by its server and held for its run (their factories keep
/// them alive while viewers and devices come and go).
pub struct StationServices {
    /// `device/pose`.
    pub pose: PubSubFactory<ipc::Service, DevicePose, ()>,
    /// `device/force`.
    pub force: PubSubFactory<ipc::Service, DeviceForce, ()>,
    /// `render/frames`.
    pub frames: PubSubFactory<ipc::Service, [u8], FrameHeader>,
    /// `render/events`.
    pub events: EventFactory<ipc::Service>,
    /// `device/connect`.
    pub connect: RequestResponseFactory<ipc::Service, DeviceHello, (), DeviceWelcome, ()>,
    /// Services a previous server of this station left and this one took over.
    pub reused: Vec<String>,
}

/// Makes (or takes over) every service of `station`, on `node` — the server's owner node,
/// named [`owner_node_name`]. Fails, naming who holds it, when another process made one.
pub fn claim(node: &Node<ipc::Service>, station: &str) -> Result<StationServices, ShmError> {
    let mut reused = Vec::new();
    let mut note = |name: &ServiceName, again: bool| {
        if again {
            reused.push(name.as_str().to_string());
        }
    };
    let name = service_name(station, "device/pose")?;
    let (pose, again) = claim_one(
        node,
        station,
        &name,
        MessagingPattern::PublishSubscribe,
        |a| pose_builder(node, &name).create_with_attributes(a),
        || pose_builder(node, &name).open(),
    )?;
    note(&name, again);
    let name = service_name(station, "device/force")?;
    let (force, again) = claim_one(
        node,
        station,
        &name,
        MessagingPattern::PublishSubscribe,
        |a| force_builder(node, &name).create_with_attributes(a),
        || force_builder(node, &name).open(),
    )?;
    note(&name, again);
    let name = service_name(station, "render/frames")?;
    let (frames, again) = claim_one(
        node,
        station,
        &name,
        MessagingPattern::PublishSubscribe,
        |a| frame_builder(node, &name).create_with_attributes(a),
        || frame_builder(node, &name).open(),
    )?;
    note(&name, again);
    let name = service_name(station, "render/events")?;
    let (events, again) = claim_one(
        node,
        station,
        &name,
        MessagingPattern::Event,
        |a| event_builder(node, &name).create_with_attributes(a),
        || event_builder(node, &name).open(),
    )?;
    note(&name, again);
    let name = service_name(station, "device/connect")?;
    let (connect, again) = claim_one(
        node,
        station,
        &name,
        MessagingPattern::RequestResponse,
        |a| connect_builder(node, &name).create_with_attributes(a),
        || connect_builder(node, &name).open(),
    )?;
    note(&name, again);
    Ok(StationServices {
        pose,
        force,
        frames,
        events,
        connect,
        reused,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn holder(name: &str, alive: Option<bool>) -> Holder {
        Holder {
            name: Some(name.into()),
            alive,
            pid: Some(42),
        }
    }

    #[test]
    fn a_previous_servers_service_is_reused_and_a_live_ones_refused() {
        let ours = owner_node_name("lab1");
        // Killed server, a viewer still attached.
        let holders = [
            holder(&ours, Some(false)),
            holder("scalpel-viewer.lab1", Some(true)),
        ];
        assert_eq!(verdict("lab1", Some(&ours), &holders), Verdict::Reuse);
        let holders = [holder(&ours, Some(true))];
        assert!(matches!(
            verdict("lab1", Some(&ours), &holders),
            Verdict::Refuse(r) if r.contains("another server of station lab1") && r.contains("pid 42")
        ));
    }

    #[test]
    fn a_squatters_service_is_refused_while_it_lives_and_made_again_after() {
        let holders = [holder("squatter.lab1", Some(true))];
        for owner in [None, Some("someone"), Some("scalpel-server.owner.lab2")] {
            assert!(matches!(
                verdict("lab1", owner, &holders),
                Verdict::Refuse(r) if r.contains("squatter.lab1 (pid 42)") && r.contains("another process made it")
            ));
        }
        let dead = [holder("squatter.lab1", Some(false))];
        assert_eq!(verdict("lab1", None, &dead), Verdict::Recreate);
        assert_eq!(verdict("lab1", None, &[]), Verdict::Recreate);
        // Another user's node cannot be told alive or dead: it is not taken for dead.
        let hidden = [Holder {
            name: None,
            alive: None,
            pid: None,
        }];
        assert!(
            matches!(verdict("lab1", None, &hidden), Verdict::Refuse(r) if r.contains("another user"))
        );
    }
}
