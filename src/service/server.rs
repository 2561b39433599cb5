//! Starting and ending the service: the bind policy (loopback unless tokens are configured),
//! the journal, the hardware thread, the runner and the HTTP server on one tokio runtime; and
//! an orderly end on SIGINT, SIGTERM or `POST /api/v1/shutdown` (a running item is paused at
//! once, stages stopped, and found interrupted at the next start).

use super::auth::Tokens;
use super::devices::{Interrupt, Opener, Settings};
use super::http::{router, App};
use super::ledger::{Ledger, LedgerError};
use super::runner::Lab;
use std::net::SocketAddr;
use std::path::PathBuf;
use std::sync::Arc;
use std::time::Duration;

#[derive(Debug, Clone)]
pub struct ServeOptions {
    pub bind: SocketAddr,
    /// The journal and the items' folders.
    pub data: PathBuf,
    pub tokens: Option<Tokens>,
    pub settings: Settings,
    pub listen: super::listen::Limits,
}

#[derive(Debug, thiserror::Error)]
pub enum ServeError {
    #[error("refusing to listen on {0}, which other machines can reach, without tokens: give --tokens FILE (`rig serve token add NAME --role operator --tokens FILE` makes one), or listen on 127.0.0.1")]
    OpenToNetwork(SocketAddr),
    #[error("cannot create the data folder {path}: {source}")]
    Data {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error(transparent)]
    Ledger(#[from] LedgerError),
    #[error("opening the hardware: {0}")]
    Hardware(String),
    #[error("cannot listen on {addr}: {source}")]
    Bind {
        addr: SocketAddr,
        source: std::io::Error,
    },
    #[error("{0}")]
    Runtime(std::io::Error),
}

/// What the server says once it listens (for a test or a script to read its address).
pub struct Started {
    pub addr: SocketAddr,
    pub recovered_bytes: u64,
    pub queued: usize,
}

/// Runs the service until it is told to end. `started` is called once it listens.
pub fn serve(
    opt: ServeOptions,
    open: Opener,
    started: impl FnOnce(&Started),
) -> Result<(), ServeError> {
    if !opt.bind.ip().is_loopback() && opt.tokens.as_ref().is_none_or(|t| t.is_empty()) {
        return Err(ServeError::OpenToNetwork(opt.bind));
    }
    std::fs::create_dir_all(&opt.data).map_err(|source| ServeError::Data {
        path: opt.data.clone(),
        source,
    })?;
    let (ledger, recovery) = Ledger::open(&opt.data)?;
    let ledger = Arc::new(ledger);
    let hw = Arc::new(
        super::hardware::spawn(open, ledger.bus.clone(), opt.settings.clone())
            .map_err(ServeError::Hardware)?,
    );
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .thread_name("rig-serve")
        .enable_all()
        .build()
        .map_err(ServeError::Runtime)?;
    let shutdown = Arc::new(tokio::sync::Notify::new());
    let served = rt.block_on(async {
        let (lab, runner) = Lab::new(ledger.clone(), hw.clone(), opt.data.clone());
        tokio::spawn(runner);
        let app = App {
            lab: lab.clone(),
            tokens: opt.tokens.clone().filter(|t| !t.is_empty()).map(Arc::new),
            limits: hw.limits,
            settings: opt.settings.clone(),
            shutdown: shutdown.clone(),
            max_event_clients: super::http::MAX_EVENT_CLIENTS
                .min(opt.listen.max_connections - opt.listen.max_connections.div_ceil(4)),
        };
        let listener = tokio::net::TcpListener::bind(opt.bind)
            .await
            .map_err(|source| ServeError::Bind {
                addr: opt.bind,
                source,
            })?;
        let addr = listener.local_addr().map_err(ServeError::Runtime)?;
        started(&Started {
            addr,
            recovered_bytes: recovery.dropped_bytes,
            queued: ledger.read(|s| s.queue.len()),
        });
        lab.kick();
        let end = {
            let shutdown = shutdown.clone();
            async move {
                let mut term =
                    tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate())
                        .ok();
                tokio::select! {
                    _ = tokio::signal::ctrl_c() => {},
                    _ = async { match term.as_mut() { Some(t) => { t.recv().await; } None => std::future::pending().await } } => {},
                    _ = shutdown.notified() => {},
                }
                tracing::info!("ending: the running item (if any) is paused now");
            }
        };
        super::listen::serve(listener, router(app), opt.listen, end).await;
        Ok::<(), ServeError>(())
    });
    // Stop the stages under a running item; it is found interrupted at the next start.
    if hw.busy_with().is_some() {
        hw.control.interrupt(Interrupt::PauseNow);
        let t0 = std::time::Instant::now();
        while hw.busy_with().is_some() && t0.elapsed() < Duration::from_secs(30) {
            std::thread::sleep(Duration::from_millis(20));
        }
    }
    rt.shutdown_timeout(Duration::from_secs(2));
    let closed = hw.close().map_err(ServeError::Hardware);
    served?;
    closed
}
