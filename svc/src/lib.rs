//! `hilbench-svc` owns what the services (`plant`, `netem`, `controller`) do the same way: in
//! their libraries' `serve`, the gRPC server with health and reflection ([`GrpcServer`]); in
//! their `main`s, structured logs with `tracing` and the shutdown signal passed to `serve`, and
//! the core's enums as flags ([`args`]); server streams that cannot exhaust a service
//! ([`streams`]: a cap on open streams, and a bounded drop-oldest buffer per subscriber); mutual
//! TLS for servers and clients ([`tls`]: the flags, the checked files, the server's config and
//! the client's endpoint); waking at a deadline to tens of microseconds ([`realtime`]:
//! netem's release thread, the plant's step loop); and a service served in process on a
//! loopback port ([`loopback`]: `hilbench`'s services of a run, the tests'). The scenario file
//! format is a crate of its own, `hilbench-scenario-file`.

pub mod args;
pub mod connections;
pub mod loopback;
pub mod realtime;
pub mod streams;
pub mod tls;

use std::future::Future;
use std::net::SocketAddr;

use tonic::transport::Server;
use tonic::transport::server::Router;
use tonic_health::ServingStatus;
use tonic_health::server::HealthReporter;

/// Why a service's gRPC server could not serve (each service's error wraps it).
/// The services every server has beside its own: health and reflection (both versions).
pub const REFLECTION_AND_HEALTH: [&str; 3] = [
    "grpc.health.v1.Health",
    "grpc.reflection.v1.ServerReflection",
    "grpc.reflection.v1alpha.ServerReflection",
];

#[derive(Debug, thiserror::Error)]
pub enum ServeError {
    #[error("reflection service: {0}")]
    Reflection(#[from] tonic_reflection::server::Error),
    #[error("listener: {0}")]
    Io(#[from] std::io::Error),
    #[error("gRPC server: {0}")]
    Transport(#[from] tonic::transport::Error),
    #[error("TLS: {0}")]
    Tls(#[from] tls::TlsError),
}

/// A service's gRPC server before it serves: the health service with the service's own
/// services SERVING, and reflection over hilbench's and health's descriptors, on a listener.
pub struct GrpcServer {
    /// The listener's address (for the service's start-up log).
    pub addr: SocketAddr,
    /// The health service's reporter (a service that reports NOT_SERVING at shutdown awaits
    /// [`GrpcServer::not_serving`] in its shutdown signal instead).
    pub health: HealthReporter,
    /// What its connections met (refusals by reason), for tests and status.
    pub connections: std::sync::Arc<connections::ConnectionStats>,
    /// The names reported SERVING by [`GrpcServer::new`].
    services: Vec<String>,
    router: Router,
    incoming: Incoming,
}

/// The server's connections, plaintext or TLS ([`connections::Incoming`]).
enum Incoming {
    Plaintext(connections::Incoming<tokio::net::TcpStream>),
    Tls(connections::Incoming<tokio_rustls::server::TlsStream<tokio::net::TcpStream>>),
}

impl GrpcServer {
    /// Takes `listener` (with `TCP_NODELAY` on accepted connections when `nodelay`) under
    /// `limits` ([`connections`]), serves TLS when `tls` has an identity (and requires client
    /// certificates when it has a client CA), and reports every one of `services` (their
    /// `NamedService::NAME`s) SERVING. `name` (the binary's) begins its connection log lines.
    /// Plaintext on an address other than loopback is served, with a warning.
    pub async fn new(
        name: &'static str,
        listener: tokio::net::TcpListener,
        nodelay: bool,
        tls: &tls::Tls,
        limits: &connections::ConnectionLimits,
        services: &[&str],
    ) -> Result<Self, ServeError> {
        let addr = listener.local_addr()?;
        if !tls.serves_tls() && !addr.ip().is_loopback() {
            tracing::warn!(
                %addr,
                "serving plaintext gRPC on an address other than loopback: anyone who reaches it can \
                 drive the bench; give --tls-cert, --tls-key and --tls-client-ca (docs/tls.md)"
            );
        }
        // A peer that answers nothing for `idle_timeout` is closed: a ping every half of it,
        // unanswered for the other half.
        let half_idle = limits.idle_timeout / 2;
        let mut server = Server::builder()
            .http2_keepalive_interval(Some(half_idle))
            .http2_keepalive_timeout(Some(half_idle));
        let (health, health_service) = tonic_health::server::health_reporter();
        for name in services {
            health.set_service_status(*name, ServingStatus::Serving).await;
        }
        // Reflection lists what this server serves and nothing else (the descriptor set holds
        // every hilbench service), in both protocol versions: grpcurl and grpcio-reflection
        // still speak v1alpha.
        let advertised =
            services.iter().copied().chain(REFLECTION_AND_HEALTH).map(str::to_string).collect::<Vec<_>>();
        let builder = || {
            advertised.iter().fold(
                tonic_reflection::server::Builder::configure()
                    .register_encoded_file_descriptor_set(hilbench_proto::FILE_DESCRIPTOR_SET)
                    .register_encoded_file_descriptor_set(tonic_health::pb::FILE_DESCRIPTOR_SET),
                |b, name| b.with_service_name(name.clone()),
            )
        };
        let router = server
            .add_service(health_service)
            .add_service(builder().build_v1()?)
            .add_service(builder().build_v1alpha()?);
        let stats = std::sync::Arc::new(connections::ConnectionStats::default());
        let incoming = match tls.server_config() {
            Some(config) => Incoming::Tls(connections::Incoming::tls(
                listener,
                nodelay,
                *limits,
                name,
                stats.clone(),
                config?,
            )),
            None => Incoming::Plaintext(connections::Incoming::plaintext(
                listener,
                nodelay,
                *limits,
                name,
                stats.clone(),
            )),
        };
        let services = services.iter().map(|name| name.to_string()).collect();
        Ok(Self { addr, health, connections: stats, services, router, incoming })
    }

    /// A future that reports every one of the services given to [`GrpcServer::new`]
    /// NOT_SERVING. Opt-in: a service that reports NOT_SERVING at shutdown takes it before
    /// `serve` and awaits it in its shutdown signal.
    pub fn not_serving(&self) -> impl Future<Output = ()> + Send + use<> {
        let (health, services) = (self.health.clone(), self.services.clone());
        async move {
            for name in &services {
                health.set_service_status(name, ServingStatus::NotServing).await;
            }
        }
    }

    /// Serves health, reflection and what `add` adds to the router until `shutdown` resolves,
    /// then waits for the open calls (graceful shutdown).
    pub async fn serve(
        self,
        add: impl FnOnce(Router) -> Router,
        shutdown: impl Future<Output = ()>,
    ) -> Result<(), ServeError> {
        let router = add(self.router);
        match self.incoming {
            Incoming::Plaintext(incoming) => router.serve_with_incoming_shutdown(incoming, shutdown).await?,
            Incoming::Tls(incoming) => router.serve_with_incoming_shutdown(incoming, shutdown).await?,
        }
        Ok(())
    }
}

/// A server's address and TLS flags, flattened into each service's `main` (its default
/// address and help set there with `mut_arg("listen", ..)`).
#[derive(Debug, Clone, Default, clap::Args)]
pub struct ServerArgs {
    /// Address to listen on, HOST:PORT.
    #[arg(long)]
    pub listen: String,
    #[command(flatten)]
    pub tls: tls::ServeTlsArgs,
    #[command(flatten)]
    pub connections: connections::ConnectionArgs,
}

impl ServerArgs {
    /// Binds `--listen` ([`bind`]).
    pub async fn bind(&self) -> Result<tokio::net::TcpListener, BindError> {
        bind(&self.listen).await
    }
}

/// Why a service's `--listen` address could not be bound.
#[derive(Debug, thiserror::Error)]
#[error("--listen {address}: cannot listen: {source}")]
pub struct BindError {
    address: String,
    source: std::io::Error,
}

/// Binds a service's `--listen` address (`HOST:PORT`); the error names the flag.
pub async fn bind(address: &str) -> Result<tokio::net::TcpListener, BindError> {
    tokio::net::TcpListener::bind(address)
        .await
        .map_err(|source| BindError { address: address.to_string(), source })
}

/// `e: its source: its source's source ...` (tonic's transport errors say "transport error"
/// and keep the reason in their sources).
pub fn error_chain(e: &dyn std::error::Error) -> String {
    let mut text = e.to_string();
    let mut source = e.source();
    while let Some(s) = source {
        text.push_str(": ");
        text.push_str(&s.to_string());
        source = s.source();
    }
    text
}

/// What a panic said (its `&str` or `String` payload).
pub fn panic_text(payload: &(dyn std::any::Any + Send)) -> String {
    payload
        .downcast_ref::<&str>()
        .map(|s| s.to_string())
        .or_else(|| payload.downcast_ref::<String>().cloned())
        .unwrap_or_else(|| "a panic without a message".into())
}

/// Why a task did not finish: `panicked: <its message>`, or cancelled.
pub fn task_failure(e: tokio::task::JoinError) -> String {
    match e.try_into_panic() {
        Ok(payload) => format!("panicked: {}", panic_text(payload.as_ref())),
        Err(e) => format!("did not finish: {e}"),
    }
}

/// The environment variable that names the point where [`inject_panic`] panics.
pub const INJECT_PANIC_VAR: &str = "HILBENCH_INJECT_PANIC";

/// A test hook: panics when the environment variable [`INJECT_PANIC_VAR`] names `point`
/// (`plant-command`, `netem-command`, `controller-cycle`, `hilbench-run`), so that tests can
/// check that a panic anywhere ends a run with an error naming it. Read once per process; one
/// comparison per call otherwise.
pub fn inject_panic(point: &str) {
    static WANTED: std::sync::OnceLock<Option<String>> = std::sync::OnceLock::new();
    if WANTED.get_or_init(|| std::env::var(INJECT_PANIC_VAR).ok()).as_deref() == Some(point) {
        panic!("injected panic at {point} ({INJECT_PANIC_VAR})");
    }
}

/// For a service's `main`: a panic in any thread or task ends the process with exit code 1
/// after it is logged (the default hook's message, then an error line), rather than leaving a
/// service that serves on without the task that panicked. Its clients see the link drop and
/// report it.
pub fn exit_on_panic() {
    let default_hook = std::panic::take_hook();
    std::panic::set_hook(Box::new(move |info| {
        default_hook(info);
        let location = info.location().map(|l| format!(" at {}:{}", l.file(), l.line())).unwrap_or_default();
        tracing::error!("panic{location}: {}; the service exits", panic_text(info.payload()));
        std::process::exit(1);
    }));
}

/// Logs to stderr, filtered by `RUST_LOG` (default `info`).
pub fn init_tracing() {
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env()
                .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("info")),
        )
        // Colour only on a terminal: logs redirected to a file or a pipe stay plain text.
        .with_ansi(std::io::IsTerminal::is_terminal(&std::io::stdout()))
        .init();
}

/// Resolves on SIGINT (Ctrl-C) or SIGTERM. A signal that cannot be listened for is logged and
/// then never fires, so the other one still works.
pub async fn shutdown_signal() {
    let ctrl_c = async {
        if let Err(e) = tokio::signal::ctrl_c().await {
            tracing::error!("cannot listen for Ctrl-C: {e}");
            std::future::pending::<()>().await;
        }
    };
    #[cfg(unix)]
    let term = async {
        match tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate()) {
            Ok(mut s) => {
                s.recv().await;
            }
            Err(e) => {
                tracing::error!("cannot listen for SIGTERM: {e}");
                std::future::pending::<()>().await;
            }
        }
    };
    #[cfg(not(unix))]
    let term = std::future::pending::<()>();
    tokio::select! {
        () = ctrl_c => {}
        () = term => {}
    }
    tracing::info!("shutdown requested");
}

#[cfg(test)]
mod tests {
    use super::*;
    use tonic_health::pb::HealthCheckRequest;
    use tonic_health::pb::health_check_response::ServingStatus as Status;
    use tonic_health::pb::health_client::HealthClient;

    #[tokio::test]
    async fn not_serving_reports_every_listed_service_and_only_when_awaited()
    -> Result<(), Box<dyn std::error::Error>> {
        let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await?;
        let server = GrpcServer::new(
            "test",
            listener,
            false,
            &tls::Tls::plaintext(),
            &Default::default(),
            &["a.A", "b.B"],
        )
        .await?;
        let addr = server.addr;
        let not_serving = server.not_serving();
        let (stop, stopped) = tokio::sync::oneshot::channel::<()>();
        let task = tokio::spawn(server.serve(|router| router, async {
            let _ = stopped.await;
        }));
        let channel = tonic::transport::Channel::from_shared(format!("http://{addr}"))?.connect().await?;
        let mut client = HealthClient::new(channel);
        let mut status = async |name: &str| -> Result<i32, tonic::Status> {
            let r = client.check(HealthCheckRequest { service: name.into() }).await?;
            Ok(r.into_inner().status)
        };
        assert_eq!(status("a.A").await?, Status::Serving as i32);
        assert_eq!(status("b.B").await?, Status::Serving as i32);
        not_serving.await;
        assert_eq!(status("a.A").await?, Status::NotServing as i32);
        assert_eq!(status("b.B").await?, Status::NotServing as i32);
        let _ = stop.send(());
        task.await??;
        Ok(())
    }

    #[tokio::test]
    async fn reflection_lists_only_the_services_served_to_a_v1alpha_client_too()
    -> Result<(), Box<dyn std::error::Error>> {
        use tokio_stream::StreamExt;
        use tonic_reflection::pb::v1alpha::ServerReflectionRequest;
        use tonic_reflection::pb::v1alpha::server_reflection_client::ServerReflectionClient;
        use tonic_reflection::pb::v1alpha::server_reflection_request::MessageRequest;
        use tonic_reflection::pb::v1alpha::server_reflection_response::MessageResponse;

        let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await?;
        let server = GrpcServer::new(
            "test",
            listener,
            false,
            &tls::Tls::plaintext(),
            &Default::default(),
            &["hilbench.v1.Plant"],
        )
        .await?;
        let addr = server.addr;
        let (stop, stopped) = tokio::sync::oneshot::channel::<()>();
        let task = tokio::spawn(server.serve(|router| router, async {
            let _ = stopped.await;
        }));
        let channel = tonic::transport::Channel::from_shared(format!("http://{addr}"))?.connect().await?;
        let mut client = ServerReflectionClient::new(channel);
        let request = ServerReflectionRequest {
            host: String::new(),
            message_request: Some(MessageRequest::ListServices(String::new())),
        };
        let mut answers = client.server_reflection_info(tokio_stream::once(request)).await?.into_inner();
        let answer = answers.next().await.ok_or("no answer")??;
        let Some(MessageResponse::ListServicesResponse(list)) = answer.message_response else {
            return Err(format!("not a service list: {answer:?}").into());
        };
        let mut names: Vec<String> = list.service.into_iter().map(|s| s.name).collect();
        names.sort();
        let mut expected: Vec<String> =
            ["hilbench.v1.Plant"].into_iter().chain(REFLECTION_AND_HEALTH).map(String::from).collect();
        expected.sort();
        assert_eq!(names, expected, "the plant's server lists NetemControl or Controller too");
        let _ = stop.send(());
        task.await??;
        Ok(())
    }
}
