//! The command-line arguments every remote client (`observe`, `instruct`) takes: the
//! server's address, the lab's certificate folder and this client's certificate name.

use std::net::SocketAddr;
use std::path::PathBuf;

use anyhow::Context;
use clap::Args;
use scalpel_client::remote::Credentials;

/// Where a remote client connects, and as whom.
#[derive(Debug, Clone, Args)]
pub struct RemoteTarget {
    /// The server's address (HOST:PORT).
    pub addr: String,
    /// The lab's certificate folder (`scalpel certs`).
    #[arg(long)]
    pub certs: PathBuf,
    /// This client's certificate name (NAME.pem, NAME.key in the folder).
    #[arg(long)]
    pub name: String,
    /// The name in the server's certificate.
    #[arg(long, default_value = "localhost")]
    pub server_name: String,
}

impl RemoteTarget {
    /// The address, resolved; an error names what was given.
    pub fn socket_addr(&self) -> anyhow::Result<SocketAddr> {
        std::net::ToSocketAddrs::to_socket_addrs(&self.addr)
            .with_context(|| format!("{}: not an address (HOST:PORT)", self.addr))?
            .next()
            .with_context(|| format!("{}: no address", self.addr))
    }

    /// This client's certificate and key, and the lab's CA.
    pub fn credentials(&self) -> Credentials {
        Credentials::from_dir(&self.certs, &self.name)
    }

    /// A current-thread runtime for the client (one connection needs no more).
    pub fn runtime() -> anyhow::Result<tokio::runtime::Runtime> {
        Ok(tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()?)
    }
}
