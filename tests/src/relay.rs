//! A TCP relay on a loopback port that can *freeze*: it stops moving bytes, in both directions
//! and on every connection, without closing anything. That is how a link fails when a gateway
//! hangs or a route drops: no reset, no FIN, just silence. New connections accepted while
//! frozen are held open and never relayed; after `thaw` new connections relay again (the
//! frozen ones stay frozen, as a half-dead TCP connection would).

use std::net::SocketAddr;
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};

use tokio::net::TcpStream;
use tokio::sync::watch;
use tokio::task::JoinHandle;

/// A running relay; dropping it closes the listener and every connection.
pub struct Relay {
    pub addr: SocketAddr,
    frozen: watch::Sender<bool>,
    accepted: Arc<AtomicU64>,
    task: JoinHandle<()>,
}

impl Relay {
    /// Relays connections to `upstream` from a fresh loopback port.
    pub async fn start(upstream: SocketAddr) -> Relay {
        let (listener, addr) = crate::server::bind_loopback().await;
        let (frozen, watch_frozen) = watch::channel(false);
        let accepted = Arc::new(AtomicU64::new(0));
        let counter = accepted.clone();
        let task = tokio::spawn(async move {
            let mut connections = tokio::task::JoinSet::new();
            while let Ok((inbound, _)) = listener.accept().await {
                counter.fetch_add(1, Ordering::SeqCst);
                connections.spawn(relay_one(inbound, upstream, watch_frozen.clone()));
            }
        });
        Relay { addr, frozen, accepted, task }
    }

    /// Stops relaying on every connection, open or to come, until `thaw`.
    pub fn freeze(&self) {
        self.frozen.send_replace(true);
    }

    /// Relays new connections again.
    pub fn thaw(&self) {
        self.frozen.send_replace(false);
    }

    /// Connections accepted so far.
    pub fn accepted(&self) -> u64 {
        self.accepted.load(Ordering::SeqCst)
    }
}

impl Drop for Relay {
    fn drop(&mut self) {
        self.task.abort();
    }
}

async fn relay_one(mut inbound: TcpStream, upstream: SocketAddr, mut frozen: watch::Receiver<bool>) {
    if !*frozen.borrow_and_update() {
        if let Ok(mut outbound) = TcpStream::connect(upstream).await {
            tokio::select! {
                _ = tokio::io::copy_bidirectional(&mut inbound, &mut outbound) => return,
                _ = frozen.wait_for(|f| *f) => {}
            }
            // Frozen: hold both ends open and silent until the relay is dropped.
            let _hold = outbound;
            std::future::pending::<()>().await;
        }
        return;
    }
    let _hold = inbound;
    std::future::pending::<()>().await;
}
