//! TLS for the QUIC endpoint: TLS 1.3 only, the ring provider, mutual TLS against the lab's
//! CA (`scalpel certs init`), ALPN `scalpel/1`, 0-RTT off. A client's role comes from its
//! verified certificate (subject organizational unit `observer` or `instructor`); anything
//! else is refused (default deny).

use std::path::Path;
use std::sync::Arc;

use anyhow::{Context, bail};
use rustls::pki_types::pem::PemObject;
use rustls::pki_types::{CertificateDer, PrivateKeyDer};
use rustls::server::WebPkiClientVerifier;
use scalpel_proto::wire::{ALPN, Role};

/// The files of a lab certificate folder.
pub const CA_FILE: &str = "ca.pem";
/// The server's certificate.
pub const SERVER_CERT_FILE: &str = "server.pem";
/// The server's key.
pub const SERVER_KEY_FILE: &str = "server.key";

/// The crypto provider everything uses (dependencies.md §5: name it, or rustls refuses
/// when more than one is compiled in).
pub fn provider() -> Arc<rustls::crypto::CryptoProvider> {
    Arc::new(rustls::crypto::ring::default_provider())
}

/// Certificates of a PEM file.
pub fn read_certs(path: &Path) -> anyhow::Result<Vec<CertificateDer<'static>>> {
    let certs: Vec<CertificateDer<'static>> = CertificateDer::pem_file_iter(path)
        .with_context(|| format!("cannot read {}", path.display()))?
        .collect::<Result<_, _>>()
        .with_context(|| format!("{}: not a PEM certificate file", path.display()))?;
    if certs.is_empty() {
        bail!("{}: no certificate in it", path.display());
    }
    Ok(certs)
}

/// The private key of a PEM file.
pub fn read_key(path: &Path) -> anyhow::Result<PrivateKeyDer<'static>> {
    PrivateKeyDer::from_pem_file(path)
        .with_context(|| format!("{}: not a PEM private key", path.display()))
}

/// The lab's CA as a root store.
pub fn roots(ca: &Path) -> anyhow::Result<rustls::RootCertStore> {
    let mut roots = rustls::RootCertStore::empty();
    for cert in read_certs(ca)? {
        roots
            .add(cert)
            .with_context(|| format!("{}: not a usable CA certificate", ca.display()))?;
    }
    Ok(roots)
}

/// The server's TLS configuration from a certificate folder.
pub fn server_config(certs: &Path) -> anyhow::Result<rustls::ServerConfig> {
    let verifier = WebPkiClientVerifier::builder_with_provider(
        Arc::new(roots(&certs.join(CA_FILE))?),
        provider(),
    )
    .build()
    .context("client certificate verifier")?;
    let mut chain = read_certs(&certs.join(SERVER_CERT_FILE))?;
    chain.extend(read_certs(&certs.join(CA_FILE))?);
    let mut tls = rustls::ServerConfig::builder_with_provider(provider())
        .with_protocol_versions(&[&rustls::version::TLS13])
        .context("TLS 1.3")?
        .with_client_cert_verifier(verifier)
        .with_single_cert(chain, read_key(&certs.join(SERVER_KEY_FILE))?)
        .context("the server certificate and key do not match")?;
    tls.alpn_protocols = vec![ALPN.to_vec()];
    // No 0-RTT: early data can be replayed.
    tls.max_early_data_size = 0;
    Ok(tls)
}

/// Who a verified client certificate names: its role and common name. `None` for a
/// certificate without a known role (refused).
pub fn identity(cert: &CertificateDer<'_>) -> Option<(Role, String)> {
    let (_, parsed) = x509_parser::parse_x509_certificate(cert.as_ref()).ok()?;
    let subject = parsed.subject();
    let unit = subject
        .iter_organizational_unit()
        .next()?
        .as_str()
        .ok()?
        .to_string();
    let name = subject
        .iter_common_name()
        .next()?
        .as_str()
        .ok()?
        .to_string();
    let role = match unit.as_str() {
        "observer" => Role::Observer,
        "instructor" => Role::Instructor,
        _ => return None,
    };
    Some((role, name))
}
