//! `hilbench certs`: a certificate authority and one certificate per service for a
//! deployment's mutual TLS (docs/tls.md), made with rcgen (pure Rust, ECDSA P-256).
//!
//! Each service's certificate is its one identity: it serves with it and presents it as a
//! client (the controller to netem, netem to the plant), so each is marked for both server and
//! client authentication. Its names: the service's own (`plant`, the Compose host name),
//! `localhost`, 127.0.0.1 and ::1 (hilbench's services on loopback), and whatever `--san` adds.

use std::path::{Path, PathBuf};

use anyhow::Context;
use rcgen::{
    BasicConstraints, CertificateParams, CertifiedIssuer, DnType, ExtendedKeyUsagePurpose, IsCa, KeyPair,
    KeyUsagePurpose,
};

/// What `hilbench certs` makes a certificate for: the servers, and hilbench as a client.
pub const IDENTITIES: [&str; 5] = ["plant", "netem", "controller", "gateway", "hilbench"];

/// `hilbench certs --out DIR [--san NAME]...`: writes the files and prints their paths.
pub fn certs(args: crate::cli::CertsArgs, opts: &super::Options) -> anyhow::Result<super::Exit> {
    for path in write_dir(&args.out, &args.san)? {
        if !opts.quiet {
            println!("{}", path.display());
        }
    }
    Ok(super::Exit::Success)
}

/// A certificate authority that signs the identities of one deployment.
pub struct Authority {
    issuer: CertifiedIssuer<'static, KeyPair>,
}

/// One identity: its certificate and private key, PEM.
pub struct IdentityPem {
    pub cert_pem: String,
    pub key_pem: String,
}

impl Authority {
    /// A new CA with a fresh key, named `name` (its subject's common name).
    pub fn new(name: &str) -> Result<Self, rcgen::Error> {
        let mut params = CertificateParams::new(Vec::<String>::new())?;
        params.is_ca = IsCa::Ca(BasicConstraints::Unconstrained);
        params.distinguished_name.push(DnType::CommonName, name);
        params.key_usages =
            vec![KeyUsagePurpose::KeyCertSign, KeyUsagePurpose::CrlSign, KeyUsagePurpose::DigitalSignature];
        Ok(Self { issuer: CertifiedIssuer::self_signed(params, KeyPair::generate()?)? })
    }

    /// The CA's certificate, PEM (what `--tls-ca` and `--tls-client-ca` name).
    pub fn cert_pem(&self) -> String {
        self.issuer.pem()
    }

    /// A certificate for `name` (its common name and first DNS name) with the other `names`
    /// as subject alternative names too (IP addresses become IP entries), for server and client
    /// authentication.
    pub fn issue(&self, name: &str, names: &[String]) -> Result<IdentityPem, rcgen::Error> {
        let mut sans = vec![name.to_string()];
        sans.extend(names.iter().filter(|n| n.as_str() != name).cloned());
        let mut params = CertificateParams::new(sans)?;
        params.distinguished_name.push(DnType::CommonName, name);
        params.key_usages = vec![KeyUsagePurpose::DigitalSignature];
        params.extended_key_usages =
            vec![ExtendedKeyUsagePurpose::ServerAuth, ExtendedKeyUsagePurpose::ClientAuth];
        let key = KeyPair::generate()?;
        let cert = params.signed_by(&key, &self.issuer)?;
        Ok(IdentityPem { cert_pem: cert.pem(), key_pem: key.serialize_pem() })
    }
}

/// The names every certificate of `hilbench certs` carries besides its service's: loopback,
/// and `extra` (`--san`).
pub fn default_names(extra: &[String]) -> Vec<String> {
    ["localhost", "127.0.0.1", "::1"].into_iter().map(String::from).chain(extra.iter().cloned()).collect()
}

/// Writes a new CA (`ca.pem`; its key `ca-key.pem`, to sign more later: keep it off the
/// machines) and `<name>.pem`/`<name>-key.pem` for each of [`IDENTITIES`] into `out` (created;
/// existing files are not overwritten). Keys are written readable by their owner only.
pub fn write_dir(out: &Path, extra_names: &[String]) -> anyhow::Result<Vec<PathBuf>> {
    std::fs::create_dir_all(out).with_context(|| format!("--out {}: cannot create it", out.display()))?;
    let ca = Authority::new("hilbench CA").context("cannot make the CA")?;
    let names = default_names(extra_names);
    let mut files = vec![(out.join("ca.pem"), ca.cert_pem(), false)];
    files.push((out.join("ca-key.pem"), ca.issuer.key().serialize_pem(), true));
    for name in IDENTITIES {
        let identity = ca.issue(name, &names).with_context(|| format!("cannot make {name}'s certificate"))?;
        files.push((out.join(format!("{name}.pem")), identity.cert_pem, false));
        files.push((out.join(format!("{name}-key.pem")), identity.key_pem, true));
    }
    if let Some((path, _, _)) = files.iter().find(|(path, _, _)| path.exists()) {
        anyhow::bail!(
            "--out {}: {} exists already (certificates are never overwritten)",
            out.display(),
            path.display()
        );
    }
    for (path, pem, secret) in &files {
        write_new(path, pem, *secret).with_context(|| format!("cannot write {}", path.display()))?;
    }
    Ok(files.into_iter().map(|(path, _, _)| path).collect())
}

fn write_new(path: &Path, text: &str, secret: bool) -> std::io::Result<()> {
    use std::io::Write;
    let mut options = std::fs::OpenOptions::new();
    options.write(true).create_new(true);
    #[cfg(unix)]
    if secret {
        use std::os::unix::fs::OpenOptionsExt;
        options.mode(0o600);
    }
    #[cfg(not(unix))]
    let _ = secret;
    options.open(path)?.write_all(text.as_bytes())
}
