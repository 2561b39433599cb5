//! `rig serve`: the lab service (rig::service), and `rig serve token add`.

use super::connect::{connect, ConnectArgs};
use super::usage::usage_bail;
use anyhow::Context;
use clap::{Args, Subcommand};
use rig::service::auth::{Role, Tokens};
use rig::service::devices::{Devices, Settings, SimCertificates};
use rig::service::server::{serve, ServeOptions};
use rig::stage::LinkOptions;
use std::net::SocketAddr;
use std::path::PathBuf;

#[derive(Debug, Args)]
pub struct ServeArgs {
    #[command(flatten)]
    pub conn: ConnectArgs,
    #[command(flatten)]
    pub sessions: super::shared_args::SessionStore,
    /// Address to listen on. Another than loopback (127.0.0.1, ::1) needs --tokens.
    #[arg(long, default_value = "127.0.0.1:7878", value_name = "ADDR:PORT")]
    pub bind: SocketAddr,
    /// The service's folder: its journal (the queue, the history, the running item) and every
    /// item's files (items/ID/).
    #[arg(long, default_value = "rig-service", value_name = "DIR")]
    pub data: PathBuf,
    /// Tokens file (SHA-256 digests and roles; `rig serve token add` writes it). Without it,
    /// only this machine can connect, with every right.
    #[arg(long, value_name = "FILE", global = true)]
    pub tokens: Option<PathBuf>,
    /// The folder of the certificates that calibration items name (by file name only).
    #[arg(long, value_name = "DIR")]
    pub certificates: Option<PathBuf>,
    /// Memory a scan's plan may take, MiB.
    #[arg(long, default_value_t = rig::scan::plan::DEFAULT_MAX_MEMORY_MIB, value_name = "MIB")]
    pub max_memory: u64,
    /// Frames averaged for a live-view frame.
    #[arg(long, default_value_t = 4, value_parser = clap::value_parser!(u32).range(1..=64))]
    pub look_frames: u32,
    /// The most connections served at once (one more is closed at once).
    #[arg(long, default_value_t = rig::service::listen::MAX_CONNECTIONS, value_parser = clap::builder::RangedU64ValueParser::<usize>::new().range(1..=65536), value_name = "N")]
    pub max_connections: usize,
    /// Seconds a client has to send a request's headers (a half-open connection is closed then).
    #[arg(long, default_value_t = rig::service::listen::HEADER_TIMEOUT.as_secs_f64(), value_name = "S")]
    pub header_timeout: f64,
    /// Print the address and state as one JSON line once listening.
    #[arg(long)]
    pub json: bool,
    #[command(subcommand)]
    pub action: Option<ServeAction>,
}

#[derive(Debug, Subcommand)]
pub enum ServeAction {
    /// Tokens: `add NAME --role ROLE --tokens FILE` makes one and prints it once.
    Token {
        #[command(subcommand)]
        action: TokenAction,
    },
}

#[derive(Debug, Subcommand)]
pub enum TokenAction {
    /// Make a token for NAME (replacing NAME's earlier one); prints it once, stores its digest.
    Add {
        name: String,
        #[arg(long, value_enum)]
        role: Role,
    },
}

pub fn run(a: ServeArgs) -> anyhow::Result<i32> {
    if let Some(ServeAction::Token {
        action: TokenAction::Add { name, role },
    }) = &a.action
    {
        let Some(path) = &a.tokens else {
            usage_bail!("name the tokens file: rig serve token add NAME --role ROLE --tokens FILE");
        };
        let mut t = match path.exists() {
            true => Tokens::load(path)?,
            false => Tokens::default(),
        };
        let token = t.add(name, *role).context("drawing a random token")?;
        rig::atomic::write_with(path, |w| {
            std::io::Write::write_all(w, t.to_toml().as_bytes())
        })?;
        println!("{token}");
        eprintln!(
            "rig: token for {name:?} ({}) stored as a digest in {}; it is shown only now",
            role.name(),
            path.display()
        );
        return Ok(0);
    }
    if !(0.05..=600.0).contains(&a.header_timeout) {
        usage_bail!(
            "--header-timeout {}: use 0.05 to 600 seconds",
            a.header_timeout
        );
    }
    let listen = rig::service::listen::Limits {
        max_connections: a.max_connections,
        header_timeout: std::time::Duration::try_from_secs_f64(a.header_timeout)
            .context("--header-timeout")?,
    };
    let tokens = a.tokens.as_ref().map(|p| Tokens::load(p)).transpose()?;
    let limits = a.conn.port.limits;
    let settings = Settings {
        store: a.sessions.store.clone(),
        limits,
        max_memory_mib: a.max_memory,
        look_frames: a.look_frames,
        sim: a.conn.sim.on,
        certificates: a.certificates.clone(),
    };
    let data = a.data.clone();
    let json = a.json;
    let conn = a.conn;
    let truth = data.join("sim-truth.json");
    let open = Box::new(move |cancel, position| {
        let hw = connect(
            &conn,
            Some(truth),
            true,
            &LinkOptions {
                wire_log: None,
                cancel: Some(cancel),
                position: Some(position),
            },
        )
        .map_err(|e| format!("{e:#}"))?;
        let certificates = match &hw.sim {
            Some(s) => SimCertificates {
                plate: Some(rig_sim::certificates::plate_certificate(
                    &s.world.plate,
                    s.world.seed,
                )),
                camera: s
                    .world
                    .film
                    .as_ref()
                    .map(|f| rig_sim::certificates::camera_certificate(f, s.world.seed)),
            },
            None => SimCertificates::default(),
        };
        let sim_film = hw
            .sim
            .as_ref()
            .filter(|s| s.world.film.is_some())
            .map(|s| s.world.film_laid.clone());
        let (stage, camera, rest) = hw.split();
        Ok(Devices {
            stage,
            camera,
            certificates,
            sim_film,
            close: Box::new(move || rest.close().map_err(|e| format!("{e:#}"))),
        })
    });
    serve(
        ServeOptions {
            bind: a.bind,
            data: data.clone(),
            tokens,
            settings,
            listen,
        },
        open,
        |s| {
            if json {
                println!(
                    "{}",
                    serde_json::json!({"listening": format!("http://{}", s.addr), "data": data, "queued": s.queued, "journal_bytes_set_aside": s.recovered_bytes})
                );
            } else {
                println!(
                    "rig serve: listening on http://{}  (data in {}, {} items queued; Ctrl-C ends)",
                    s.addr,
                    data.display(),
                    s.queued
                );
                if s.recovered_bytes > 0 {
                    println!("  the journal's torn last record ({} bytes) was set aside: the service ended while writing it", s.recovered_bytes);
                }
            }
            use std::io::Write;
            let _ = std::io::stdout().flush();
        },
    )?;
    Ok(0)
}
