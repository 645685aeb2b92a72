//! Mutual TLS for every hilbench server and client, in one place: the flags
//! ([`IdentityArgs`], [`ServeTlsArgs`], [`TrustArgs`]), the files they name read and checked
//! once at start-up ([`Tls::load`], errors naming the flag), the server's config
//! ([`Tls::server_config`], used by [`crate::GrpcServer`]) and the client's endpoint
//! ([`Tls::endpoint`]).
//!
//! One identity per process: the certificate a service serves with is also the one it
//! presents as a client (the controller to its plant, netem to its upstream), as in a service
//! mesh. A deployment then has one certificate per service, made for both uses (`hilbench
//! certs` marks each for server and client authentication); ARCHITECTURE.md says why.
//!
//! Plaintext is the default: no flag, no TLS. `--tls-ca` switches a client to `https`;
//! `--tls-cert`/`--tls-key` make a server serve TLS; `--tls-client-ca` makes it refuse clients
//! without a certificate signed by that CA.

use std::path::{Path, PathBuf};

use rustls_pki_types::pem::PemObject;
use rustls_pki_types::{CertificateDer, PrivateKeyDer};
use tokio_rustls::rustls::server::WebPkiClientVerifier;
use tokio_rustls::rustls::{RootCertStore, ServerConfig};
use tonic::transport::{Certificate, ClientTlsConfig, Endpoint, Identity};

use crate::error_chain;

/// This process's identity: served by a server, presented by a client to servers that ask for
/// a certificate (`--tls-client-ca`).
#[derive(Debug, Clone, Default, clap::Args)]
pub struct IdentityArgs {
    /// This process's certificate (chain), PEM: a server serves TLS with it, a client presents
    /// it to servers that require client certificates. Needs --tls-key.
    #[arg(long, value_name = "PEM")]
    pub tls_cert: Option<PathBuf>,
    /// The private key of --tls-cert, PEM (PKCS#8, PKCS#1 or SEC1).
    #[arg(long, value_name = "PEM")]
    pub tls_key: Option<PathBuf>,
}

/// A server's TLS flags: its identity, and the CA its clients' certificates must chain to.
#[derive(Debug, Clone, Default, clap::Args)]
pub struct ServeTlsArgs {
    #[command(flatten)]
    pub identity: IdentityArgs,
    /// Require every client to present a certificate signed by this CA (PEM); clients without
    /// one, or with one from another CA, are refused at the handshake. Needs --tls-cert.
    #[arg(long, value_name = "PEM")]
    pub tls_client_ca: Option<PathBuf>,
}

/// A client's trust: the CA the servers' certificates must chain to.
#[derive(Debug, Clone, Default, clap::Args)]
pub struct TrustArgs {
    /// Connect with TLS (https), trusting servers whose certificate this CA (PEM) signed; the
    /// certificate must name the host or IP address connected to. Without it: plaintext.
    #[arg(long, value_name = "PEM")]
    pub tls_ca: Option<PathBuf>,
}

/// The files of a process's TLS set-up (what the flags name; `None`: not given).
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct TlsFiles {
    /// `--tls-cert`.
    pub cert: Option<PathBuf>,
    /// `--tls-key`.
    pub key: Option<PathBuf>,
    /// `--tls-client-ca`.
    pub client_ca: Option<PathBuf>,
    /// `--tls-ca`.
    pub ca: Option<PathBuf>,
}

impl TlsFiles {
    /// The files of a server that is not a client (plant, gateway).
    pub fn server(args: &ServeTlsArgs) -> Self {
        Self {
            cert: args.identity.tls_cert.clone(),
            key: args.identity.tls_key.clone(),
            client_ca: args.tls_client_ca.clone(),
            ca: None,
        }
    }

    /// The files of a server that is a client too (controller, netem).
    pub fn server_and_client(serve: &ServeTlsArgs, trust: &TrustArgs) -> Self {
        Self { ca: trust.tls_ca.clone(), ..Self::server(serve) }
    }

    /// The files of a client that serves nothing (hilbench, vehiclectl).
    pub fn client(identity: &IdentityArgs, trust: &TrustArgs) -> Self {
        Self {
            cert: identity.tls_cert.clone(),
            key: identity.tls_key.clone(),
            client_ca: None,
            ca: trust.tls_ca.clone(),
        }
    }

    /// The layout of `hilbench certs --out DIR` for `name` (a service, or `hilbench`):
    /// `DIR/ca.pem` trusted both ways, `DIR/<name>.pem` and `DIR/<name>-key.pem` its identity.
    pub fn in_dir(dir: &Path, name: &str) -> Self {
        Self {
            cert: Some(dir.join(format!("{name}.pem"))),
            key: Some(dir.join(format!("{name}-key.pem"))),
            client_ca: Some(dir.join("ca.pem")),
            ca: Some(dir.join("ca.pem")),
        }
    }

    /// Reads and checks the files (see [`Tls::load`]).
    pub fn load(&self) -> Result<Tls, TlsError> {
        Tls::load(self)
    }
}

/// Why a TLS set-up was refused at start-up (each names the flag at fault).
#[derive(Debug, thiserror::Error)]
pub enum TlsError {
    #[error("{flag} {}: {reason}", path.display())]
    Read { flag: &'static str, path: PathBuf, reason: String },
    #[error("{flag} {}: {what}", path.display())]
    Pem { flag: &'static str, path: PathBuf, what: String },
    #[error("{given} needs {missing}")]
    Missing { given: &'static str, missing: &'static str },
    #[error("--tls-cert {} with --tls-key {}: {why}", cert.display(), key.display())]
    Identity { cert: PathBuf, key: PathBuf, why: String },
    #[error("--tls-ca {}: {why}", path.display())]
    Trust { path: PathBuf, why: String },
    #[error("address {address}: {why}")]
    Address { address: String, why: String },
}

/// A process's TLS material, read and checked: what it serves with, whom it accepts as
/// clients, whom it trusts as servers. [`Default`] is plaintext both ways. Kept as PEM, so
/// that a service's config stays comparable; its `Debug` never shows the key.
#[derive(Clone, Default, PartialEq, Eq)]
pub struct Tls {
    /// This process's certificate chain and private key.
    identity: Option<(Vec<u8>, Vec<u8>)>,
    client_ca: Option<Vec<u8>>,
    ca: Option<Vec<u8>>,
}

impl std::fmt::Debug for Tls {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Tls")
            .field("serves_tls", &self.serves_tls())
            .field("requires_client_certificates", &self.requires_client_certificates())
            .field("connects_with_tls", &self.connects_with_tls())
            .finish()
    }
}

impl Tls {
    /// Plaintext both ways (the default on loopback).
    pub fn plaintext() -> Self {
        Self::default()
    }

    /// Reads `files` and checks them: each file exists and holds PEM of the right kind (one or
    /// more certificates; one private key), the key belongs to the certificate, a key comes
    /// with a certificate and the other way round, and `--tls-client-ca` comes with an
    /// identity (a server that asks clients for certificates must serve TLS itself).
    pub fn load(files: &TlsFiles) -> Result<Self, TlsError> {
        let identity = match (&files.cert, &files.key) {
            (None, None) => None,
            (Some(_), None) => return Err(TlsError::Missing { given: "--tls-cert", missing: "--tls-key" }),
            (None, Some(_)) => return Err(TlsError::Missing { given: "--tls-key", missing: "--tls-cert" }),
            (Some(cert), Some(key)) => {
                let pems = (certificates_pem("--tls-cert", cert)?, key_pem("--tls-key", key)?);
                // rustls checks that the key is the certificate's when it builds a config:
                // build one now, so that a mismatch stops the start-up rather than every
                // handshake.
                server_config(&pems.0, &pems.1, None).map_err(|e| match e {
                    TlsError::Identity { why, .. } => {
                        TlsError::Identity { cert: cert.clone(), key: key.clone(), why }
                    }
                    other => other,
                })?;
                Some(pems)
            }
        };
        let client_ca = match &files.client_ca {
            None => None,
            Some(_) if identity.is_none() => {
                return Err(TlsError::Missing {
                    given: "--tls-client-ca",
                    missing: "--tls-cert and --tls-key",
                });
            }
            Some(path) => {
                let pem = certificates_pem("--tls-client-ca", path)?;
                if let Some((cert, key)) = &identity {
                    // The roots are checked when the server's config is built: build it now.
                    server_config(cert, key, Some(&pem)).map_err(|e| match e {
                        TlsError::Pem { flag, what, .. } => TlsError::Pem { flag, path: path.clone(), what },
                        other => other,
                    })?;
                }
                Some(pem)
            }
        };
        let ca = match &files.ca {
            None => None,
            Some(path) => Some(certificates_pem("--tls-ca", path)?),
        };
        let tls = Self { identity, client_ca, ca };
        if let (Some(path), Some(config)) = (&files.ca, tls.client_config()) {
            // The client's config is built per endpoint; build one now for the same reason.
            Endpoint::from_static("https://localhost")
                .tls_config(config)
                .map_err(|e| TlsError::Trust { path: path.clone(), why: error_chain(&e) })?;
        }
        Ok(tls)
    }

    /// Whether this process serves TLS.
    pub fn serves_tls(&self) -> bool {
        self.identity.is_some()
    }

    /// Whether this process's servers require client certificates.
    pub fn requires_client_certificates(&self) -> bool {
        self.client_ca.is_some()
    }

    /// Whether this process connects with TLS.
    pub fn connects_with_tls(&self) -> bool {
        self.ca.is_some()
    }

    /// The server's TLS config (`None`: plaintext): its identity, and the client CA when
    /// client certificates are required.
    pub fn server_config(&self) -> Option<Result<ServerConfig, TlsError>> {
        let (cert, key) = self.identity.as_ref()?;
        Some(server_config(cert, key, self.client_ca.as_deref()))
    }

    /// The client's TLS config (`None`: plaintext): the trusted CA, and this process's identity
    /// as client certificate when it has one.
    pub fn client_config(&self) -> Option<ClientTlsConfig> {
        let config = ClientTlsConfig::new().ca_certificate(Certificate::from_pem(self.ca.as_ref()?));
        Some(match &self.identity {
            Some((cert, key)) => config.identity(Identity::from_pem(cert, key)),
            None => config,
        })
    }

    /// The URI of `address` (`HOST:PORT`, or a URI with its scheme): `https://` with TLS,
    /// `http://` without. A scheme that contradicts the set-up is refused.
    pub fn uri(&self, address: &str) -> Result<String, TlsError> {
        let refuse = |why: &str| TlsError::Address { address: address.to_string(), why: why.to_string() };
        match (address.split_once("://"), self.connects_with_tls()) {
            (None, true) => Ok(format!("https://{address}")),
            (None, false) => Ok(format!("http://{address}")),
            (Some(("https", _)), true) | (Some(("http", _)), false) => Ok(address.to_string()),
            (Some(("http", _)), true) => Err(refuse("http:// with --tls-ca (give HOST:PORT or https://)")),
            (Some(("https", _)), false) => Err(refuse("https:// needs --tls-ca (the CA to trust)")),
            (Some((scheme, _)), _) => Err(refuse(&format!("unknown scheme {scheme}:// (http or https)"))),
        }
    }

    /// An endpoint for `address` ([`Tls::uri`]) with this process's client TLS config.
    pub fn endpoint(&self, address: &str) -> Result<Endpoint, TlsError> {
        let uri = self.uri(address)?;
        let refuse = |e: tonic::transport::Error| TlsError::Address {
            address: address.to_string(),
            why: error_chain(&e),
        };
        let endpoint = Endpoint::from_shared(uri).map_err(refuse)?;
        match self.client_config() {
            Some(config) => endpoint.tls_config(config).map_err(refuse),
            None => Ok(endpoint),
        }
    }
}

/// The common name of the certificate the client of `request` presented, or why there is
/// none (a plaintext connection, a server that asks for no client certificate, a certificate
/// without a common name).
pub fn client_common_name<T>(request: &tonic::Request<T>) -> Result<String, &'static str> {
    let certs = request.peer_certs().ok_or("no client certificate")?;
    let leaf = certs.first().ok_or("no client certificate")?;
    let (_, cert) = x509_parser::parse_x509_certificate(leaf.as_ref())
        .map_err(|_| "a certificate that does not parse")?;
    let name = cert.subject().iter_common_name().next().ok_or("a certificate without a common name")?;
    name.as_str().map(str::to_owned).map_err(|_| "a certificate whose common name is not text")
}

/// Whether `e` is a TLS refusal (a certificate not trusted or for another name, a handshake
/// the peer refused) rather than a server not listening yet: retrying the connection does not
/// help. tokio-rustls reports these as `InvalidData` I/O errors, somewhere in tonic's chain.
pub fn is_tls_refusal(e: &(dyn std::error::Error + 'static)) -> bool {
    let mut source = Some(e);
    while let Some(s) = source {
        if s.downcast_ref::<std::io::Error>().is_some_and(|io| io.kind() == std::io::ErrorKind::InvalidData) {
            return true;
        }
        source = s.source();
    }
    false
}

/// A server's rustls config, as tonic's `ServerTlsConfig` builds it (the process's crypto
/// provider, ring): the identity, and client certificates required and checked against
/// `client_ca` when given. [`crate::connections::Incoming`] adds ALPN `h2`.
fn server_config(cert: &[u8], key: &[u8], client_ca: Option<&[u8]>) -> Result<ServerConfig, TlsError> {
    let identity_error = |why: String| TlsError::Identity { cert: PathBuf::new(), key: PathBuf::new(), why };
    let chain = CertificateDer::pem_slice_iter(cert)
        .collect::<Result<Vec<_>, _>>()
        .map_err(|e| identity_error(format!("not PEM: {e}")))?;
    let key =
        PrivateKeyDer::from_pem_slice(key).map_err(|e| identity_error(format!("no private key: {e}")))?;
    let builder = ServerConfig::builder();
    let builder = match client_ca {
        None => builder.with_no_client_auth(),
        Some(ca) => {
            let trust_error =
                |what: String| TlsError::Pem { flag: "--tls-client-ca", path: PathBuf::new(), what };
            let mut roots = RootCertStore::empty();
            for certificate in CertificateDer::pem_slice_iter(ca) {
                let certificate = certificate.map_err(|e| trust_error(format!("not PEM: {e}")))?;
                roots.add(certificate).map_err(|e| trust_error(e.to_string()))?;
            }
            let verifier = WebPkiClientVerifier::builder(roots.into())
                .build()
                .map_err(|e| trust_error(e.to_string()))?;
            builder.with_client_cert_verifier(verifier)
        }
    };
    builder.with_single_cert(chain, key).map_err(|e| identity_error(e.to_string()))
}

/// A certificate or key file: a regular file of at most `user_file::MAX_PEM_FILE_BYTES`
/// (`--tls-cert /dev/zero` read until memory ran out).
fn read(flag: &'static str, path: &Path) -> Result<Vec<u8>, TlsError> {
    use hilbench_scenario_file::user_file::{MAX_PEM_FILE_BYTES, read_bytes};
    read_bytes(path, MAX_PEM_FILE_BYTES, "PEM").map_err(|e| TlsError::Read {
        flag,
        path: e.path,
        reason: e.reason,
    })
}

/// The file's bytes, when it holds one or more PEM certificates and nothing unreadable.
fn certificates_pem(flag: &'static str, path: &Path) -> Result<Vec<u8>, TlsError> {
    let bytes = read(flag, path)?;
    let pem_error = |what: String| TlsError::Pem { flag, path: path.to_path_buf(), what };
    let certificates = CertificateDer::pem_slice_iter(&bytes)
        .collect::<Result<Vec<_>, _>>()
        .map_err(|e| pem_error(format!("not PEM: {e}")))?;
    if certificates.is_empty() {
        return Err(pem_error("no PEM certificate (-----BEGIN CERTIFICATE-----) in it".into()));
    }
    Ok(bytes)
}

/// The file's bytes, when it holds a PEM private key.
fn key_pem(flag: &'static str, path: &Path) -> Result<Vec<u8>, TlsError> {
    let bytes = read(flag, path)?;
    PrivateKeyDer::from_pem_slice(&bytes).map_err(|e| TlsError::Pem {
        flag,
        path: path.to_path_buf(),
        what: format!("no PEM private key (PKCS#8, PKCS#1 or SEC1) in it: {e}"),
    })?;
    Ok(bytes)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A temporary directory with two unrelated self-signed identities (`a`, `b`) and a file
    /// that is not PEM.
    fn files(name: &str) -> PathBuf {
        let dir = std::env::temp_dir().join(format!("svc-tls-{name}-{}", std::process::id()));
        std::fs::create_dir_all(&dir).expect("temp dir");
        for id in ["a", "b"] {
            let made = rcgen::generate_simple_self_signed(vec!["localhost".to_string()]).expect("rcgen");
            std::fs::write(dir.join(format!("{id}.pem")), made.cert.pem()).expect("write");
            std::fs::write(dir.join(format!("{id}-key.pem")), made.signing_key.serialize_pem())
                .expect("write");
        }
        std::fs::write(dir.join("garbage.pem"), "not a certificate\n").expect("write");
        dir
    }

    fn error(files: TlsFiles) -> String {
        Tls::load(&files).map(|_| ()).expect_err("refused").to_string()
    }

    #[test]
    fn load_refuses_bad_files_naming_the_flag_at_fault() {
        let dir = files("load");
        let at = |name: &str| Some(dir.join(name));
        let identity = TlsFiles { cert: at("a.pem"), key: at("a-key.pem"), ..TlsFiles::default() };
        assert!(Tls::load(&identity).is_ok_and(|tls| tls.serves_tls() && !tls.connects_with_tls()));
        let cases = [
            (TlsFiles { cert: at("a.pem"), ..TlsFiles::default() }, "--tls-cert needs --tls-key"),
            (TlsFiles { key: at("a-key.pem"), ..TlsFiles::default() }, "--tls-key needs --tls-cert"),
            (TlsFiles { client_ca: at("a.pem"), ..TlsFiles::default() }, "--tls-client-ca needs --tls-cert"),
            (TlsFiles { cert: at("missing.pem"), ..identity.clone() }, "--tls-cert"),
            (TlsFiles { cert: at("garbage.pem"), ..identity.clone() }, "no PEM certificate"),
            (TlsFiles { key: at("a.pem"), ..identity.clone() }, "--tls-key"),
            (TlsFiles { key: at("b-key.pem"), ..identity.clone() }, "with --tls-key"),
            (TlsFiles { client_ca: at("garbage.pem"), ..identity.clone() }, "--tls-client-ca"),
            (TlsFiles { ca: at("a-key.pem"), ..TlsFiles::default() }, "--tls-ca"),
            // A device is refused before it is read (it used to be read until memory ran out).
            (
                TlsFiles { ca: Some(PathBuf::from("/dev/zero")), ..TlsFiles::default() },
                "--tls-ca /dev/zero: not a regular file",
            ),
        ];
        for (files, expected) in cases {
            let why = error(files.clone());
            assert!(why.contains(expected), "{files:?}: {why}");
        }
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn the_uri_follows_the_set_up_and_a_contradicting_scheme_is_refused() {
        let dir = files("uri");
        let tls = TlsFiles { ca: Some(dir.join("a.pem")), ..TlsFiles::default() }.load().expect("loads");
        let plain = Tls::plaintext();
        assert_eq!(plain.uri("127.0.0.1:1").ok(), Some("http://127.0.0.1:1".into()));
        assert_eq!(tls.uri("plant:1").ok(), Some("https://plant:1".into()));
        assert_eq!(tls.uri("https://plant:1").ok(), Some("https://plant:1".into()));
        assert!(tls.uri("http://plant:1").is_err_and(|e| e.to_string().contains("--tls-ca")));
        assert!(plain.uri("https://plant:1").is_err_and(|e| e.to_string().contains("--tls-ca")));
        assert!(plain.uri("ftp://plant:1").is_err());
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn server_args_take_the_services_default_address_and_the_tls_flags() {
        use clap::Parser;
        // As each service's main sets it: the default and `required(false)` (a `String` field
        // is otherwise required, default or not).
        #[derive(Debug, clap::Parser)]
        #[command(mut_arg("listen", |a| a.default_value("127.0.0.1:50051").required(false)))]
        struct Cli {
            #[command(flatten)]
            server: crate::ServerArgs,
        }
        let plain = Cli::try_parse_from(["plant"]).expect("parses");
        assert_eq!(plain.server.listen, "127.0.0.1:50051");
        assert_eq!(TlsFiles::server(&plain.server.tls), TlsFiles::default());
        let args =
            ["plant", "--listen", "0.0.0.0:1", "--tls-cert", "c", "--tls-key", "k", "--tls-client-ca", "ca"];
        let tls = Cli::try_parse_from(args).expect("parses");
        assert_eq!(tls.server.listen, "0.0.0.0:1");
        let files = TlsFiles::server(&tls.server.tls);
        assert_eq!(files.cert.as_deref(), Some(Path::new("c")));
        assert_eq!(files.key.as_deref(), Some(Path::new("k")));
        assert_eq!(files.client_ca.as_deref(), Some(Path::new("ca")));
    }

    #[test]
    fn debug_never_shows_the_key() {
        let dir = files("debug");
        let tls = TlsFiles {
            cert: Some(dir.join("a.pem")),
            key: Some(dir.join("a-key.pem")),
            ..TlsFiles::default()
        }
        .load()
        .expect("loads");
        let key = std::fs::read_to_string(dir.join("a-key.pem")).expect("key");
        let shown = format!("{tls:?}");
        assert!(!shown.contains("PRIVATE") && !key.lines().skip(1).any(|l| shown.contains(l)), "{shown}");
        let _ = std::fs::remove_dir_all(&dir);
    }
}
