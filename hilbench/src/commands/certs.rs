//! `hilbench certs`: a certificate authority and one certificate per service for a
//! deployment's mutual TLS (docs/tls.md), made with rcgen (pure Rust, ECDSA P-256).
//!
//! Each service's certificate is its one identity: it serves with it and presents it as a
//! client (the controller to netem, netem to the plant), so each is marked for both server and
//! client authentication. Its names: the service's own (`plant`, the Compose host name),
//! `localhost`, 127.0.0.1 and ::1 (hilbench's services on loopback), and whatever `--san` adds.
//!
//! Every certificate, the CA's too, is valid from an hour before it is made (clocks that lag a
//! little) for `--days` days ([`DEFAULT_DAYS`] by default, at most [`MAX_DAYS`]), not rcgen's
//! default of 1975 to 4096: a key that leaks stops being trusted on its own.

use std::path::{Path, PathBuf};
use std::time::{Duration, SystemTime};

use anyhow::Context;
use rcgen::{
    BasicConstraints, CertificateParams, CertifiedIssuer, DnType, ExtendedKeyUsagePurpose, IsCa, KeyPair,
    KeyUsagePurpose,
};

/// What `hilbench certs` makes a certificate for: the servers, and hilbench as a client.
pub const IDENTITIES: [&str; 5] = ["plant", "netem", "controller", "gateway", "hilbench"];

pub use crate::cli::{DEFAULT_DAYS, MAX_DAYS, san_name};
/// How long before it is made a certificate is already valid.
const BACKDATE: Duration = Duration::from_secs(3600);

/// `hilbench certs --out DIR [--san NAME]... [--days N]`: writes the files and prints their
/// paths.
pub fn certs(args: crate::cli::CertsArgs, opts: &super::Options) -> anyhow::Result<super::Exit> {
    for path in write_dir(&args.out, &args.san, args.days)? {
        if !opts.quiet {
            println!("{}", path.display());
        }
    }
    Ok(super::Exit::Success)
}

/// A certificate authority that signs the identities of one deployment.
pub struct Authority {
    issuer: CertifiedIssuer<'static, KeyPair>,
    validity: Validity,
}

/// When the certificates of one `hilbench certs` are valid: from an hour before now, for
/// `days` days.
#[derive(Debug, Clone, Copy)]
pub struct Validity {
    pub not_before: SystemTime,
    pub not_after: SystemTime,
}

impl Validity {
    /// From an hour ago to `days` days from now (`days` in `1..=MAX_DAYS`).
    pub fn days_from_now(days: u32) -> anyhow::Result<Self> {
        anyhow::ensure!((1..=MAX_DAYS).contains(&days), "--days {days}: must be in 1..={MAX_DAYS}");
        let now = SystemTime::now();
        let not_before = now.checked_sub(BACKDATE).context("the clock is before 1970")?;
        let not_after = now + Duration::from_secs(u64::from(days) * 86_400);
        Ok(Self { not_before, not_after })
    }

    fn apply(&self, params: &mut CertificateParams) -> Result<(), rcgen::Error> {
        let at = |t: SystemTime| {
            let since = t.duration_since(SystemTime::UNIX_EPOCH).map_err(|_| rcgen::Error::Time)?;
            Ok::<_, rcgen::Error>(rcgen::date_time_ymd(1970, 1, 1) + since)
        };
        params.not_before = at(self.not_before)?;
        params.not_after = at(self.not_after)?;
        Ok(())
    }
}

/// One identity: its certificate and private key, PEM.
pub struct IdentityPem {
    pub cert_pem: String,
    pub key_pem: String,
}

impl Authority {
    /// A new CA with a fresh key, named `name` (its subject's common name), valid for
    /// `validity`, as is every certificate it issues.
    pub fn new(name: &str, validity: Validity) -> Result<Self, rcgen::Error> {
        let mut params = CertificateParams::new(Vec::<String>::new())?;
        validity.apply(&mut params)?;
        params.is_ca = IsCa::Ca(BasicConstraints::Unconstrained);
        params.distinguished_name.push(DnType::CommonName, name);
        params.key_usages =
            vec![KeyUsagePurpose::KeyCertSign, KeyUsagePurpose::CrlSign, KeyUsagePurpose::DigitalSignature];
        Ok(Self { issuer: CertifiedIssuer::self_signed(params, KeyPair::generate()?)?, validity })
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
        self.validity.apply(&mut params)?;
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
/// existing files are not overwritten), all valid for `days` days. Keys are written readable by
/// their owner only. Every extra name is checked ([`san_name`]) before anything is written.
pub fn write_dir(out: &Path, extra_names: &[String], days: u32) -> anyhow::Result<Vec<PathBuf>> {
    let validity = Validity::days_from_now(days)?;
    for name in extra_names {
        san_name(name).map_err(|e| anyhow::anyhow!("--san: {e}"))?;
    }
    std::fs::create_dir_all(out).with_context(|| format!("--out {}: cannot create it", out.display()))?;
    let ca = Authority::new("hilbench CA", validity).context("cannot make the CA")?;
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn san_names_must_be_ip_addresses_or_dns_names() {
        for good in ["plant", "bench.example.org", "*.example.org", "10.0.0.7", "fe80::1", "a-1.b"] {
            assert_eq!(san_name(good), Ok(good.to_string()), "{good}");
        }
        for bad in [
            "",
            " ",
            "my host",
            "a..b",
            "-a",
            "a-",
            "host/x",
            "*.",
            "caf\u{e9}",
            &"a".repeat(64),
            "1.2.3.4.5",
            "10.0.0.256",
        ] {
            assert!(san_name(bad).is_err(), "{bad:?} accepted");
        }
    }

    #[test]
    fn validity_is_bounded_by_days_and_refused_outside_its_range() {
        let v = Validity::days_from_now(30).expect("30 days");
        let span = v.not_after.duration_since(v.not_before).expect("ordered");
        assert_eq!(span, Duration::from_secs(30 * 86_400) + BACKDATE);
        assert!(Validity::days_from_now(0).is_err());
        assert!(Validity::days_from_now(MAX_DAYS + 1).is_err());
    }
}
