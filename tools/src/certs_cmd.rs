//! `scalpel certs init --dir D [--host H]...` and `scalpel certs issue --dir D --role R --name N`:
//! a lab's certificate authority and the certificates of its server and clients (rcgen).
//!
//! The role of a client certificate is its subject's organizational unit (`observer` or
//! `instructor`); the server reads it from the verified certificate and allows nothing else
//! (docs/PROTOCOL.md, "Security"). Keys are written readable by their owner only.

use std::path::Path;

use anyhow::{Context, bail};
use rcgen::{
    BasicConstraints, CertificateParams, DistinguishedName, DnType, ExtendedKeyUsagePurpose, IsCa,
    Issuer, KeyPair, KeyUsagePurpose,
};

/// File names in a certificate folder.
pub const CA_CERT: &str = "ca.pem";
/// The CA's private key.
pub const CA_KEY: &str = "ca.key";
/// The server's certificate.
pub const SERVER_CERT: &str = "server.pem";
/// The server's private key.
pub const SERVER_KEY: &str = "server.key";

/// Days a certificate is valid.
const CA_DAYS: i64 = 3650;
/// Days a server or client certificate is valid.
const LEAF_DAYS: i64 = 825;

fn distinguished_name(common_name: &str, unit: &str) -> DistinguishedName {
    let mut dn = DistinguishedName::new();
    dn.push(DnType::OrganizationName, "scalpel lab");
    dn.push(DnType::OrganizationalUnitName, unit);
    dn.push(DnType::CommonName, common_name);
    dn
}

fn validity(params: &mut CertificateParams, days: i64) {
    let now = time_now();
    params.not_before = now - std::time::Duration::from_secs(3600);
    params.not_after = now + std::time::Duration::from_secs(days as u64 * 86_400);
}

fn time_now() -> time::OffsetDateTime {
    time::OffsetDateTime::now_utc()
}

/// Writes `text` to `path`, readable by the owner only when `secret`.
fn write(path: &Path, text: &str, secret: bool) -> anyhow::Result<()> {
    use std::io::Write as _;
    use std::os::unix::fs::OpenOptionsExt as _;
    let mut options = std::fs::OpenOptions::new();
    options
        .write(true)
        .create_new(true)
        .mode(if secret { 0o600 } else { 0o644 });
    let mut file = options.open(path).with_context(|| {
        format!(
            "cannot create {} (it must not exist already)",
            path.display()
        )
    })?;
    file.write_all(text.as_bytes())?;
    Ok(())
}

fn check_name(name: &str) -> anyhow::Result<()> {
    // The station's own rule for identities, and no leading '.' (a hidden file).
    if !scalpel_server::net::tls::is_identity(name) || name.starts_with('.') {
        bail!(
            "name {name:?}: use 1 to 64 letters, digits, '-', '_' or '.' (it names the certificate's files)"
        );
    }
    if ["ca", "server"].contains(&name) {
        bail!("name {name:?} is taken by the lab's own certificates");
    }
    Ok(())
}

/// Makes a CA and a server certificate (for localhost and `hosts`) in `dir`; returns what
/// it made, for people.
pub fn init(dir: &Path, hosts: &[String]) -> anyhow::Result<String> {
    std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    if dir.join(CA_CERT).exists() {
        bail!(
            "{} already has a CA ({CA_CERT}); issue certificates with `scalpel certs issue`, or use another folder",
            dir.display()
        );
    }
    let mut ca = CertificateParams::new(Vec::<String>::new())?;
    ca.distinguished_name = distinguished_name("scalpel lab CA", "ca");
    ca.is_ca = IsCa::Ca(BasicConstraints::Constrained(0));
    ca.key_usages = vec![KeyUsagePurpose::KeyCertSign, KeyUsagePurpose::CrlSign];
    validity(&mut ca, CA_DAYS);
    let ca_key = KeyPair::generate()?;
    let ca_cert = ca.self_signed(&ca_key)?;

    let mut names = vec!["localhost".to_string(), "127.0.0.1".into(), "::1".into()];
    names.extend(hosts.iter().cloned());
    let mut server = CertificateParams::new(names.clone())?;
    server.distinguished_name = distinguished_name("scalpel-server", "server");
    server.extended_key_usages = vec![ExtendedKeyUsagePurpose::ServerAuth];
    validity(&mut server, LEAF_DAYS);
    let server_key = KeyPair::generate()?;
    let issuer = Issuer::new(ca, ca_key);
    let server_cert = server.signed_by(&server_key, &issuer)?;

    write(&dir.join(CA_CERT), &ca_cert.pem(), false)?;
    write(&dir.join(CA_KEY), &issuer_key_pem(&issuer), true)?;
    write(&dir.join(SERVER_CERT), &server_cert.pem(), false)?;
    write(&dir.join(SERVER_KEY), &server_key.serialize_pem(), true)?;
    Ok(format!(
        "lab CA and server certificate ({}) in {}; keep {CA_KEY} private",
        names.join(", "),
        dir.display()
    ))
}

fn issuer_key_pem(issuer: &Issuer<'_, KeyPair>) -> String {
    issuer.key().serialize_pem()
}

/// Issues a client certificate for `name` with `role` (observer or instructor), signed by
/// the CA in `dir`; returns what it made, for people.
pub fn issue(dir: &Path, role: &str, name: &str) -> anyhow::Result<String> {
    check_name(name)?;
    if !["observer", "instructor"].contains(&role) {
        bail!("role {role:?}: observer or instructor");
    }
    let read = |file: &str| {
        let path = dir.join(file);
        // Capped (a PEM file is kilobytes; a wrong path must not be read whole).
        scalpel_server::input_file::read_text_capped(&path, scalpel_server::net::tls::PEM_MAX_BYTES)
            .with_context(|| {
                format!(
                    "cannot read {} (make a lab CA with `scalpel certs init --dir {}`)",
                    path.display(),
                    dir.display()
                )
            })
    };
    let ca_key = KeyPair::from_pem(&read(CA_KEY)?).context("the CA key")?;
    let issuer = Issuer::from_ca_cert_pem(&read(CA_CERT)?, ca_key).context("the CA certificate")?;
    let mut params = CertificateParams::new(Vec::<String>::new())?;
    params.distinguished_name = distinguished_name(name, role);
    params.extended_key_usages = vec![ExtendedKeyUsagePurpose::ClientAuth];
    validity(&mut params, LEAF_DAYS);
    let key = KeyPair::generate()?;
    let cert = params.signed_by(&key, &issuer)?;
    let cert_path = dir.join(format!("{name}.pem"));
    write(&cert_path, &cert.pem(), false)?;
    write(&dir.join(format!("{name}.key")), &key.serialize_pem(), true)?;
    Ok(format!(
        "{role} certificate for {name}: {} and {name}.key",
        cert_path.display()
    ))
}
