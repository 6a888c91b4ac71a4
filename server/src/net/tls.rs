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

/// Most bytes a certificate or key file may have: a PEM chain is a few kilobytes, and a
/// wrong path (a device, a log) must not be read whole.
pub const PEM_MAX_BYTES: u64 = 1 << 20;

fn read_pem(path: &Path) -> anyhow::Result<Vec<u8>> {
    crate::input_file::read_capped(path, PEM_MAX_BYTES)
        .with_context(|| format!("cannot read {}", path.display()))
}

/// Certificates of a PEM file.
pub fn read_certs(path: &Path) -> anyhow::Result<Vec<CertificateDer<'static>>> {
    let certs: Vec<CertificateDer<'static>> = CertificateDer::pem_slice_iter(&read_pem(path)?)
        .collect::<Result<_, _>>()
        .with_context(|| format!("{}: not a PEM certificate file", path.display()))?;
    if certs.is_empty() {
        bail!("{}: no certificate in it", path.display());
    }
    Ok(certs)
}

/// The private key of a PEM file.
pub fn read_key(path: &Path) -> anyhow::Result<PrivateKeyDer<'static>> {
    PrivateKeyDer::from_pem_slice(&read_pem(path)?)
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

/// Longest identity a certificate may name (`scalpel certs issue` makes at most 64).
pub const MAX_IDENTITY: usize = 64;

/// Whether `name` is an identity as `scalpel certs issue` makes them (and the station
/// accepts): 1 to [`MAX_IDENTITY`] ASCII letters, digits, `-`, `_` or `.`.
pub fn is_identity(name: &str) -> bool {
    let plain = |b: u8| b.is_ascii_alphanumeric() || b"-_.".contains(&b);
    !name.is_empty() && name.len() <= MAX_IDENTITY && name.bytes().all(plain)
}

/// Who a verified client certificate names: its role and common name, or why it is refused:
/// no known role, or a name that is not what `scalpel certs issue` makes — 1 to
/// [`MAX_IDENTITY`] ASCII letters, digits, `-`, `_` or `.`. The name is printed in logs,
/// events, journals and observers' terminals and keys the fault book; a lab CA could sign
/// anything, and an escape sequence, a newline or a bidirectional override would reach every
/// terminal that shows it, a look-alike letter (Cyrillic "а" in "аnn") would pass for
/// another instructor in the record.
pub fn identity(cert: &CertificateDer<'_>) -> Result<(Role, String), String> {
    let (_, parsed) = x509_parser::parse_x509_certificate(cert.as_ref())
        .map_err(|_| "the client certificate cannot be read".to_string())?;
    let subject = parsed.subject();
    let role = match subject
        .iter_organizational_unit()
        .next()
        .and_then(|u| u.as_str().ok())
    {
        Some("observer") => Role::Observer,
        Some("instructor") => Role::Instructor,
        _ => return Err("the client certificate names no role (observer or instructor)".into()),
    };
    let name = subject
        .iter_common_name()
        .next()
        .ok_or("the client certificate has no common name")?
        .as_str()
        .map_err(|_| "the client certificate's common name is not UTF-8 text".to_string())?
        .to_string();
    if !is_identity(&name) {
        // Debug formatting escapes what must not reach a terminal raw.
        let shown: String = format!("{name:?}").chars().take(4 * MAX_IDENTITY).collect();
        return Err(format!(
            "the client certificate's name {shown} is not 1 to {MAX_IDENTITY} ASCII letters, \
             digits, '-', '_' or '.' (issue it with `scalpel certs issue`)"
        ));
    }
    Ok((role, name))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn certificate(name: &str, unit: &str) -> CertificateDer<'static> {
        let mut params = rcgen::CertificateParams::new(Vec::<String>::new()).unwrap();
        params
            .distinguished_name
            .push(rcgen::DnType::CommonName, name);
        params
            .distinguished_name
            .push(rcgen::DnType::OrganizationalUnitName, unit);
        let key = rcgen::KeyPair::generate().unwrap();
        params.self_signed(&key).unwrap().der().clone()
    }

    #[test]
    fn an_identity_is_a_role_and_a_printable_name() {
        assert_eq!(
            identity(&certificate("ann", "instructor")),
            Ok((Role::Instructor, "ann".into()))
        );
        assert_eq!(
            identity(&certificate("obs-2_b.lab", "observer")),
            Ok((Role::Observer, "obs-2_b.lab".into()))
        );
        let refused = |name: &str, unit: &str| identity(&certificate(name, unit)).unwrap_err();
        assert!(refused("ann", "admin").contains("names no role"));
        // An escape sequence that would turn a terminal red, a newline that would forge a
        // log line: refused, and shown escaped.
        let red = refused("eve\u{1b}[31m", "instructor");
        assert!(
            red.contains(r#""eve\u{1b}[31m""#) && !red.contains('\u{1b}'),
            "{red}"
        );
        let forged = refused("eve\n 12.0 s  fault 1 cleared", "observer");
        assert!(!forged.contains('\n'), "{forged}");
        // A right-to-left override, which turns what follows it round on screen.
        let turned = refused("eve\u{202e}nna", "instructor");
        assert!(
            !turned.contains('\u{202e}') && turned.contains(r"\u{202e}"),
            "{turned}"
        );
        assert!(refused("", "observer").contains("not 1 to 64"));
        assert!(refused("a\"b", "observer").contains("not 1 to 64"));
        // A Cyrillic "а" that would pass for ann in the record.
        assert!(refused("\u{430}nn", "instructor").contains(r#""аnn""#));
        assert!(refused(&"x".repeat(65), "observer").contains("not 1 to 64"));
        assert!(identity(&CertificateDer::from(vec![1, 2, 3])).is_err());
    }

    #[test]
    fn certificate_files_are_read_within_a_cap() {
        let huge = std::env::temp_dir().join(format!("scalpel-huge-{}.pem", std::process::id()));
        std::fs::write(&huge, vec![b'A'; 2 << 20]).unwrap();
        let err = format!("{:#}", read_certs(&huge).unwrap_err());
        std::fs::remove_file(&huge).ok();
        assert!(err.contains("over the limit of 1048576 bytes"), "{err}");
        let err = format!("{:#}", read_key(Path::new("/dev/zero")).unwrap_err());
        assert!(err.contains("not a regular file"), "{err}");
    }
}
