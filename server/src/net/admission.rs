//! Who gets into the endpoint, in two budgets: handshakes in flight and connections.
//!
//! Issue 45: a QUIC handshake started and never finished used to take one of
//! `max_connections` until the idle timeout, and nothing checked the client's address first;
//! 24 Initial packets a second from three addresses kept every observer out. Now:
//!
//! 1. an Initial from an address not yet validated gets a QUIC Retry (stateless: the
//!    server keeps nothing, and a spoofed address never sees the token);
//! 2. a validated one takes a place in the **handshake** budget (`max_handshakes`, and
//!    `max_handshakes_per_address` from one address) until its TLS handshake ends or
//!    times out ([`HANDSHAKE_TIMEOUT`]);
//! 3. only a finished handshake — a client certificate the lab's CA signed — takes a
//!    **connection** place (`max_connections`, `max_per_address`).
//!
//! An attacker without a certificate can therefore hold at most the handshake budget, for
//! at most the timeout each, and only from addresses it really has; the connection places
//! are the lab's. Sans-IO: the counts are plain data, the guards give their place back
//! however a task ends.

use std::collections::HashMap;
use std::net::IpAddr;
use std::sync::{Arc, Mutex};
use std::time::Duration;

/// Time a validated client has to finish its TLS handshake (a lab on the other side of
/// the world needs a few round trips: well under a second).
pub const HANDSHAKE_TIMEOUT: Duration = Duration::from_secs(2);

/// The budgets.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Budgets {
    /// Handshakes in flight at once.
    pub handshakes: usize,
    /// Handshakes in flight from one address.
    pub handshakes_per_address: usize,
    /// Connections at once (finished handshakes).
    pub connections: usize,
    /// Connections from one address.
    pub connections_per_address: usize,
}

/// Why a client was not let in.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum Refusal {
    /// The handshake budget is spent.
    Handshakes,
    /// This address has its share of handshakes in flight.
    HandshakesFromAddress,
    /// The connection budget is spent.
    Connections,
    /// This address has its share of connections.
    ConnectionsFromAddress,
    /// The TLS handshake failed (no certificate, a foreign CA, another protocol).
    Tls,
    /// The handshake did not finish in [`HANDSHAKE_TIMEOUT`].
    Timeout,
    /// The certificate carries no role, or a name that cannot be shown.
    Forbidden,
}

impl Refusal {
    /// How it reads in the log.
    pub fn describe(self, b: &Budgets) -> String {
        match self {
            Self::Handshakes => format!(
                "{} handshakes in flight already (network.max_handshakes)",
                b.handshakes
            ),
            Self::HandshakesFromAddress => format!(
                "{} handshakes in flight from this address already (network.max_handshakes_per_address)",
                b.handshakes_per_address
            ),
            Self::Connections => format!(
                "the station is at its limit of {} connections (network.max_connections)",
                b.connections
            ),
            Self::ConnectionsFromAddress => format!(
                "the station is at its limit of {} connections from one address (network.max_per_address)",
                b.connections_per_address
            ),
            Self::Tls => "TLS handshake failed".into(),
            Self::Timeout => format!(
                "the handshake did not finish within {} s",
                HANDSHAKE_TIMEOUT.as_secs_f64()
            ),
            Self::Forbidden => "certificate refused".into(),
        }
    }

    /// A short name for summaries.
    pub fn name(self) -> &'static str {
        match self {
            Self::Handshakes => "handshake budget",
            Self::HandshakesFromAddress => "handshakes per address",
            Self::Connections => "connection limit",
            Self::ConnectionsFromAddress => "connections per address",
            Self::Tls => "TLS failed",
            Self::Timeout => "handshake timed out",
            Self::Forbidden => "certificate refused",
        }
    }
}

#[derive(Debug, Default)]
struct Counts {
    total: usize,
    by_address: HashMap<IpAddr, usize>,
}

impl Counts {
    fn take(&mut self, ip: IpAddr, most: usize, most_per_address: usize) -> Result<(), bool> {
        if self.total >= most {
            return Err(false);
        }
        let n = self.by_address.entry(ip).or_default();
        if *n >= most_per_address {
            if *n == 0 {
                self.by_address.remove(&ip);
            }
            return Err(true);
        }
        *n += 1;
        self.total += 1;
        Ok(())
    }

    fn give_back(&mut self, ip: IpAddr) {
        if let Some(n) = self.by_address.get_mut(&ip) {
            *n -= 1;
            self.total -= 1;
            if *n == 0 {
                self.by_address.remove(&ip);
            }
        }
    }
}

#[derive(Debug, Default)]
struct State {
    handshakes: Counts,
    connections: Counts,
}

/// The two budgets' counts, shared by the accept loop and the connections' tasks.
#[derive(Clone)]
pub struct Admission {
    budgets: Budgets,
    state: Arc<Mutex<State>>,
}

/// A place in the handshake budget, given back when dropped.
pub struct HandshakePlace {
    admission: Admission,
    ip: IpAddr,
}

/// A place in the connection budget, given back when dropped.
pub struct ConnectionPlace {
    admission: Admission,
    ip: IpAddr,
}

impl Admission {
    /// Empty budgets.
    pub fn new(budgets: Budgets) -> Self {
        Self {
            budgets,
            state: Arc::default(),
        }
    }

    /// The budgets.
    pub fn budgets(&self) -> &Budgets {
        &self.budgets
    }

    fn state(&self) -> std::sync::MutexGuard<'_, State> {
        self.state.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// A handshake from `ip` starts, if the handshake budget has room.
    pub fn handshake(&self, ip: IpAddr) -> Result<HandshakePlace, Refusal> {
        let b = self.budgets;
        match self
            .state()
            .handshakes
            .take(ip, b.handshakes, b.handshakes_per_address)
        {
            Ok(()) => Ok(HandshakePlace {
                admission: self.clone(),
                ip,
            }),
            Err(false) => Err(Refusal::Handshakes),
            Err(true) => Err(Refusal::HandshakesFromAddress),
        }
    }

    /// A finished handshake becomes a connection, if the connection budget has room; the
    /// handshake's place is given back either way.
    pub fn connect(&self, handshake: HandshakePlace) -> Result<ConnectionPlace, Refusal> {
        let ip = handshake.ip;
        drop(handshake);
        let b = self.budgets;
        match self
            .state()
            .connections
            .take(ip, b.connections, b.connections_per_address)
        {
            Ok(()) => Ok(ConnectionPlace {
                admission: self.clone(),
                ip,
            }),
            Err(false) => Err(Refusal::Connections),
            Err(true) => Err(Refusal::ConnectionsFromAddress),
        }
    }

    /// Handshakes in flight and connections now.
    pub fn in_use(&self) -> (usize, usize) {
        let s = self.state();
        (s.handshakes.total, s.connections.total)
    }
}

impl Drop for HandshakePlace {
    fn drop(&mut self) {
        self.admission.state().handshakes.give_back(self.ip);
    }
}

impl Drop for ConnectionPlace {
    fn drop(&mut self) {
        self.admission.state().connections.give_back(self.ip);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ip(last: u8) -> IpAddr {
        IpAddr::from([127, 0, 0, last])
    }

    fn admission() -> Admission {
        Admission::new(Budgets {
            handshakes: 4,
            handshakes_per_address: 2,
            connections: 3,
            connections_per_address: 2,
        })
    }

    #[test]
    fn handshakes_are_bounded_in_all_and_per_address_and_given_back() {
        let a = admission();
        let h1 = a.handshake(ip(2)).unwrap();
        let _h2 = a.handshake(ip(2)).unwrap();
        assert_eq!(
            a.handshake(ip(2)).err(),
            Some(Refusal::HandshakesFromAddress)
        );
        let _h3 = a.handshake(ip(3)).unwrap();
        let _h4 = a.handshake(ip(4)).unwrap();
        assert_eq!(a.handshake(ip(5)).err(), Some(Refusal::Handshakes));
        drop(h1);
        let _h5 = a.handshake(ip(5)).unwrap();
        assert_eq!(a.in_use(), (4, 0));
    }

    #[test]
    fn a_finished_handshake_moves_to_the_connection_budget() {
        let a = admission();
        let c1 = a.connect(a.handshake(ip(2)).unwrap()).unwrap();
        assert_eq!(a.in_use(), (0, 1));
        let _c2 = a.connect(a.handshake(ip(2)).unwrap()).unwrap();
        // The handshake's place comes back even when the connection is refused.
        assert_eq!(
            a.connect(a.handshake(ip(2)).unwrap()).err(),
            Some(Refusal::ConnectionsFromAddress)
        );
        assert_eq!(a.in_use(), (0, 2));
        let _c3 = a.connect(a.handshake(ip(3)).unwrap()).unwrap();
        assert_eq!(
            a.connect(a.handshake(ip(4)).unwrap()).err(),
            Some(Refusal::Connections)
        );
        drop(c1);
        let _c4 = a.connect(a.handshake(ip(4)).unwrap()).unwrap();
        assert_eq!(a.in_use(), (0, 3));
    }

    #[test]
    fn handshakes_in_flight_do_not_use_connection_places() {
        let a = admission();
        let _held: Vec<_> = [2, 3]
            .iter()
            .map(|&k| a.handshake(ip(k)).unwrap())
            .collect();
        let _c: Vec<_> = (0..3)
            .map(|k| a.connect(a.handshake(ip(10 + k)).unwrap()).unwrap())
            .collect();
        assert_eq!(a.in_use(), (2, 3));
    }
}
