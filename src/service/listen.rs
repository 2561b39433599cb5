//! The service's accept loop: at most [`MAX_CONNECTIONS`] connections at once (one more is
//! closed at once, so a port scan cannot exhaust memory or descriptors), a request's headers
//! within [`HEADER_TIMEOUT`] (a half-open connection is closed then), and an end that waits
//! at most [`DRAIN`] for open connections (an event stream never ends by itself).

use axum::Router;
use hyper_util::rt::{TokioIo, TokioTimer};
use hyper_util::service::TowerToHyperService;
use std::sync::Arc;
use std::time::Duration;
use tokio::net::TcpListener;
use tokio::sync::{watch, Semaphore};

/// The most connections served at once.
pub const MAX_CONNECTIONS: usize = 1024;
/// A request's headers must arrive within this.
pub const HEADER_TIMEOUT: Duration = Duration::from_secs(10);
/// How long the end waits for open connections to finish.
const DRAIN: Duration = Duration::from_secs(2);

/// Limits of the accept loop (the defaults above; tests may lower them).
#[derive(Debug, Clone, Copy)]
pub struct Limits {
    pub max_connections: usize,
    pub header_timeout: Duration,
}

impl Default for Limits {
    fn default() -> Self {
        Limits {
            max_connections: MAX_CONNECTIONS,
            header_timeout: HEADER_TIMEOUT,
        }
    }
}

/// Serves `app` on `listener` until `end` resolves.
pub async fn serve(
    listener: TcpListener,
    app: Router,
    limits: Limits,
    end: impl std::future::Future<Output = ()>,
) {
    let slots = Arc::new(Semaphore::new(limits.max_connections.max(1)));
    let (stop_tx, stop_rx) = watch::channel(false);
    tokio::pin!(end);
    loop {
        let (io, _) = tokio::select! {
            a = listener.accept() => match a {
                Ok(c) => c,
                // Out of descriptors and the like: wait a little rather than spin.
                Err(e) => {
                    tracing::warn!("accepting a connection: {e}");
                    tokio::time::sleep(Duration::from_millis(50)).await;
                    continue;
                }
            },
            _ = &mut end => break,
        };
        let Ok(slot) = slots.clone().try_acquire_owned() else {
            tracing::warn!(
                "{} connections open: one more closed at once",
                limits.max_connections
            );
            drop(io);
            continue;
        };
        let _ = io.set_nodelay(true);
        let service = TowerToHyperService::new(app.clone());
        let mut stop = stop_rx.clone();
        let header_timeout = limits.header_timeout;
        tokio::spawn(async move {
            let conn = hyper::server::conn::http1::Builder::new()
                .timer(TokioTimer::new())
                .header_read_timeout(header_timeout)
                .serve_connection(TokioIo::new(io), service)
                .with_upgrades();
            tokio::pin!(conn);
            tokio::select! {
                r = conn.as_mut() => {
                    if let Err(e) = r {
                        tracing::debug!("connection: {e}");
                    }
                }
                _ = async { let _ = stop.wait_for(|s| *s).await; } => {
                    conn.as_mut().graceful_shutdown();
                    let _ = tokio::time::timeout(DRAIN, conn).await;
                }
            }
            drop(slot);
        });
    }
    let _ = stop_tx.send(true);
    // Every connection finished, or the drain's time is up.
    let _ = tokio::time::timeout(
        DRAIN,
        slots.acquire_many(limits.max_connections.max(1) as u32),
    )
    .await;
}
