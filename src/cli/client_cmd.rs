//! `rig queue`, `rig run`, `rig events`: the CLI as a client of a running `rig serve`.
//! The server's address comes from --server or RIG_SERVER, its token from RIG_TOKEN (never a
//! flag, so that it does not show in the process list).

use anyhow::{bail, Context};
use clap::{Args, Subcommand};
use serde_json::{json, Value};
use std::io::BufRead;
use std::path::PathBuf;
use std::time::Duration;

/// Where the service is.
#[derive(Debug, Args)]
pub struct Server {
    /// The service's URL. Without the flag: RIG_SERVER, then http://127.0.0.1:7878. The token
    /// (if the service has tokens) is read from RIG_TOKEN.
    #[arg(long, value_name = "URL", global = true)]
    pub server: Option<String>,
    /// Print the service's answer as JSON.
    #[arg(long, global = true)]
    pub json: bool,
}

#[derive(Debug, Args)]
pub struct QueueArgs {
    #[command(flatten)]
    pub server: Server,
    #[command(subcommand)]
    pub action: QueueAction,
}

/// Where a new or moved item goes (default: the back).
#[derive(Debug, Args, Clone)]
pub struct Place {
    /// At the front.
    #[arg(long, conflicts_with_all = ["before", "after", "index"])]
    pub front: bool,
    /// Before item ID.
    #[arg(long, value_name = "ID")]
    pub before: Option<u64>,
    /// After item ID.
    #[arg(long, value_name = "ID", conflicts_with = "before")]
    pub after: Option<u64>,
    /// At this index (0: the front).
    #[arg(long = "at", id = "index", value_name = "N", conflicts_with_all = ["before", "after"])]
    pub index: Option<usize>,
}

impl Place {
    fn json(&self) -> Value {
        match (self.front, self.before, self.after, self.index) {
            (true, ..) => json!("front"),
            (_, Some(id), ..) => json!({"before": id}),
            (_, _, Some(id), _) => json!({"after": id}),
            (.., Some(i)) => json!({"index": i}),
            _ => json!("back"),
        }
    }
}

#[derive(Debug, Subcommand)]
pub enum QueueAction {
    /// Add an item: `home`, `move X Y` (mm), or `scan SCRIPT.toml`.
    Add {
        #[command(subcommand)]
        task: NewTask,
    },
    /// The queue, the running item and the queue's options.
    List,
    /// One item wherever it is (queue, running, history): its attempts, folder, result.
    Show {
        id: u64,
    },
    /// Move a waiting item.
    Move {
        id: u64,
        #[command(flatten)]
        place: Place,
    },
    /// Remove a waiting item.
    Remove {
        id: u64,
    },
    /// Remove every waiting item.
    Clear,
    /// Start the queue.
    Start,
    /// Stop the queue after the running item.
    Stop,
    /// Ended items.
    /// Lock the queue and run control to admins, saying why (an admin's token); pause, abort
    /// and halt stay open to operators.
    Lock {
        note: String,
    },
    /// Lift the lock (an admin's token).
    Unlock,
    History,
}

#[derive(Debug, Subcommand)]
pub enum NewTask {
    /// Home both axes.
    Home {
        #[command(flatten)]
        place: Place,
        /// An idempotency key: adding again with the same key adds nothing.
        #[arg(long)]
        key: Option<String>,
    },
    /// Move to X Y, mm.
    Move {
        #[arg(allow_hyphen_values = true)]
        x_mm: f64,
        #[arg(allow_hyphen_values = true)]
        y_mm: f64,
        #[command(flatten)]
        place: Place,
        #[arg(long)]
        key: Option<String>,
    },
    /// A pixel calibration session into the service's store (as `rig calibrate pixel`; with
    /// the simulator, its own plate certificate).
    CalibratePixel {
        #[arg(long, default_value_t = 32)]
        frames: u32,
        #[arg(long, default_value_t = 5)]
        grid: usize,
        #[arg(long)]
        grid_only: bool,
        #[arg(long)]
        no_flat: bool,
        /// The plate certificate: its file name in the service's --certificates folder.
        #[arg(long, value_name = "FILE")]
        plate_cert: Option<PathBuf>,
        #[command(flatten)]
        place: Place,
        #[arg(long)]
        key: Option<String>,
    },
    /// An interior orientation session into the service's store (as `rig calibrate interior`;
    /// the newest pixel session when it runs, unless named).
    CalibrateInterior {
        #[arg(long, default_value_t = 32)]
        frames: u32,
        /// Where the film's centre lies on the carriage, roughly (mm).
        #[arg(long, value_name = "X,Y", default_value = "125,125")]
        film_centre: String,
        /// A pixel session: its folder's name in the service's store.
        #[arg(long, value_name = "DIR")]
        pixel_session: Option<PathBuf>,
        /// The film camera's certificate: its file name in the service's --certificates folder.
        #[arg(long, value_name = "FILE")]
        camera_cert: Option<PathBuf>,
        #[command(flatten)]
        place: Place,
        #[arg(long)]
        key: Option<String>,
    },
    /// Scan by a script (its text is sent; interior_session: absolute, or none for the
    /// service's newest).
    Scan {
        script: PathBuf,
        /// The item's name (default: the script's file name).
        #[arg(long)]
        name: Option<String>,
        #[command(flatten)]
        place: Place,
        #[arg(long)]
        key: Option<String>,
    },
}

#[derive(Debug, Args)]
pub struct RunArgs {
    #[command(flatten)]
    pub server: Server,
    #[command(subcommand)]
    pub action: RunAction,
}

#[derive(Debug, Subcommand)]
pub enum RunAction {
    /// Pause the running item at the next tile (--now: at once, the tile taken again).
    Pause {
        #[arg(long)]
        now: bool,
    },
    Resume,
    /// End the running item at the next tile, done.
    Stop,
    /// Stop the stages now; the item goes back to the front of the queue, the queue stops.
    Abort,
    /// Reset the controller now (also with nothing running).
    Halt,
    /// Simulator only: lay the film on the carriage (for a scan or an interior calibration).
    LayFilm,
    /// Simulator only: lift the film off the carriage, baring the plate's crosses (for a pixel
    /// calibration).
    LiftFilm,
}

#[derive(Debug, Args)]
pub struct EventsArgs {
    #[command(flatten)]
    pub server: Server,
    /// Replay from after this event number (what a reconnecting client sends as Last-Event-ID).
    #[arg(long, value_name = "N")]
    pub since: Option<u64>,
}

struct Client {
    base: String,
    token: Option<String>,
    agent: ureq::Agent,
}

fn client(s: &Server, timeout: Option<Duration>) -> Client {
    let base = s
        .server
        .clone()
        .or_else(|| std::env::var("RIG_SERVER").ok().filter(|v| !v.is_empty()))
        .unwrap_or_else(|| "http://127.0.0.1:7878".into());
    let agent: ureq::Agent = ureq::Agent::config_builder()
        .http_status_as_error(false)
        .timeout_global(timeout)
        .timeout_connect(Some(Duration::from_secs(5)))
        .build()
        .into();
    Client {
        base: base.trim_end_matches('/').to_string(),
        token: std::env::var("RIG_TOKEN").ok().filter(|v| !v.is_empty()),
        agent,
    }
}

impl Client {
    fn call(&self, method: &str, path: &str, body: Option<Value>) -> anyhow::Result<Value> {
        let url = format!("{}{path}", self.base);
        let auth = self.token.as_ref().map(|t| format!("Bearer {t}"));
        let r = match (method, body) {
            ("GET", _) => {
                let mut q = self.agent.get(&url);
                if let Some(a) = &auth {
                    q = q.header("Authorization", a);
                }
                q.call()
            }
            (m, b) => {
                let mut q = match m {
                    "DELETE" => {
                        let mut q = self.agent.delete(&url);
                        if let Some(a) = &auth {
                            q = q.header("Authorization", a);
                        }
                        return self.answer(q.call(), &url);
                    }
                    "PATCH" => self.agent.patch(&url),
                    "PUT" => self.agent.put(&url),
                    _ => self.agent.post(&url),
                };
                if let Some(a) = &auth {
                    q = q.header("Authorization", a);
                }
                match b {
                    Some(b) => q.send_json(&b),
                    None => q.send_empty(),
                }
            }
        };
        self.answer(r, &url)
    }

    fn answer(
        &self,
        r: Result<ureq::http::Response<ureq::Body>, ureq::Error>,
        url: &str,
    ) -> anyhow::Result<Value> {
        let mut r = r.with_context(|| {
            format!("no answer from the service at {url}: is `rig serve` running there? (--server URL or RIG_SERVER)")
        })?;
        let status = r.status();
        let v: Value = r
            .body_mut()
            .read_json()
            .with_context(|| format!("{url} answered {status} with a body that is not JSON"))?;
        if !status.is_success() {
            bail!(
                "the service refused ({status}, {}): {}",
                v["error"].as_str().unwrap_or("?"),
                v["message"].as_str().unwrap_or("")
            );
        }
        Ok(v)
    }
}

fn print(v: &Value, json: bool, text: impl FnOnce(&Value) -> String) {
    if json {
        println!("{v}");
    } else {
        println!("{}", text(v));
    }
}

fn describe(task: &Value) -> String {
    match task["kind"].as_str() {
        Some("move") => format!("move to {} {} mm", task["x_mm"], task["y_mm"]),
        Some("scan") => format!("scan {}", task["name"].as_str().unwrap_or("?")),
        Some(k) => k.to_string(),
        None => task.to_string(),
    }
}

fn item_line(i: &Value) -> String {
    format!(
        "{:>6}  {:<8}  {}  ({} attempt{})",
        i["id"],
        i["state"].as_str().unwrap_or("?"),
        describe(&i["task"]),
        i["attempts"].as_array().map_or(0, |a| a.len()),
        if i["attempts"].as_array().map_or(0, |a| a.len()) == 1 {
            ""
        } else {
            "s"
        }
    )
}

pub fn queue(a: QueueArgs) -> anyhow::Result<i32> {
    let c = client(&a.server, Some(Duration::from_secs(90)));
    let json = a.server.json;
    match a.action {
        QueueAction::Add { task } => {
            let (task, place, key) = match task {
                NewTask::Home { place, key } => (json!({"kind": "home"}), place, key),
                NewTask::Move {
                    x_mm,
                    y_mm,
                    place,
                    key,
                } => (
                    json!({"kind": "move", "x_mm": x_mm, "y_mm": y_mm}),
                    place,
                    key,
                ),
                NewTask::CalibratePixel {
                    frames,
                    grid,
                    grid_only,
                    no_flat,
                    plate_cert,
                    place,
                    key,
                } => (
                    json!({"kind": "calibrate_pixel", "frames": frames, "grid": grid,
                           "grid_only": grid_only, "no_flat": no_flat, "plate_cert": plate_cert}),
                    place,
                    key,
                ),
                NewTask::CalibrateInterior {
                    frames,
                    film_centre,
                    pixel_session,
                    camera_cert,
                    place,
                    key,
                } => {
                    let (x, y) = super::camera_cmd::parse_pair(&film_centre, "--film-centre")?;
                    (
                        json!({"kind": "calibrate_interior", "frames": frames,
                               "film_centre_mm": [x, y], "pixel_session": pixel_session,
                               "camera_cert": camera_cert}),
                        place,
                        key,
                    )
                }
                NewTask::Scan {
                    script,
                    name,
                    place,
                    key,
                } => {
                    let text = std::fs::read_to_string(&script).with_context(|| {
                        format!("cannot read the scan script {}", script.display())
                    })?;
                    let name = name.unwrap_or_else(|| {
                        script
                            .file_stem()
                            .map_or("scan".into(), |s| s.to_string_lossy().into_owned())
                    });
                    (
                        json!({"kind": "scan", "name": name, "script": text}),
                        place,
                        key,
                    )
                }
            };
            let v = c.call(
                "POST",
                "/api/v1/queue/items",
                Some(json!({"items": [{"task": task, "key": key}], "at": place.json()})),
            )?;
            print(&v, json, |v| match v["added"].as_bool() {
                Some(true) => format!("queued as item {}", v["ids"][0]),
                _ => format!("already queued (same key) as item {}", v["ids"][0]),
            });
        }
        QueueAction::List => {
            let v = c.call("GET", "/api/v1/queue", None)?;
            print(&v, json, |v| {
                let mut s = format!(
                    "queue {}{}\n",
                    if v["options"]["running"].as_bool() == Some(true) {
                        "running"
                    } else {
                        "stopped"
                    },
                    if v["options"]["autostart"].as_bool() == Some(true) {
                        " (autostart)"
                    } else {
                        ""
                    }
                );
                match &v["running"] {
                    Value::Null => s += "running: nothing\n",
                    r => s += &format!("running:\n{}\n", item_line(r)),
                }
                let q = v["queue"].as_array().cloned().unwrap_or_default();
                s += &format!("waiting: {}\n", q.len());
                for i in &q {
                    s += &item_line(i);
                    s.push('\n');
                }
                s.trim_end().to_string()
            });
        }
        QueueAction::Show { id } => {
            let v = c.call("GET", &format!("/api/v1/items/{id}"), None)?;
            print(&v, json, |v| {
                let mut s = format!(
                    "{}\n  where: {}\n  folder: {}\n  result: {}",
                    item_line(&v["item"]),
                    v["where"].as_str().unwrap_or("?"),
                    v["dir"].as_str().unwrap_or("none yet"),
                    v["item"]["result"]
                );
                for (n, a) in v["item"]["attempts"]
                    .as_array()
                    .into_iter()
                    .flatten()
                    .enumerate()
                {
                    s += &format!(
                        "\n  attempt {}: {}{}",
                        n + 1,
                        a["outcome"].as_str().unwrap_or("running"),
                        a["message"]
                            .as_str()
                            .map(|m| format!(": {m}"))
                            .unwrap_or_default()
                    );
                }
                s
            });
        }
        QueueAction::Move { id, place } => {
            let v = c.call(
                "POST",
                &format!("/api/v1/queue/items/{id}/move"),
                Some(json!({"to": place.json()})),
            )?;
            print(&v, json, |_| format!("moved item {id}"));
        }
        QueueAction::Remove { id } => {
            let v = c.call("DELETE", &format!("/api/v1/queue/items/{id}"), None)?;
            print(&v, json, |_| format!("removed item {id}"));
        }
        QueueAction::Clear => {
            let v = c.call("POST", "/api/v1/queue/clear", None)?;
            print(&v, json, |_| "queue cleared".into());
        }
        QueueAction::Start => {
            let v = c.call("POST", "/api/v1/queue/start", None)?;
            print(&v, json, |_| "queue started".into());
        }
        QueueAction::Stop => {
            let v = c.call("POST", "/api/v1/queue/stop", None)?;
            print(&v, json, |v| match v["stop_after_current"].as_bool() {
                Some(true) => "the queue stops when the running item ends".into(),
                _ => "queue stopped".into(),
            });
        }
        QueueAction::Lock { note } => {
            let v = c.call("POST", "/api/v1/lock", Some(json!({ "note": note })))?;
            print(&v, json, |v| {
                format!(
                    "queue locked by {}: {}",
                    v["lock"]["by"].as_str().unwrap_or("?"),
                    v["lock"]["note"].as_str().unwrap_or("")
                )
            });
        }
        QueueAction::Unlock => {
            let v = c.call("DELETE", "/api/v1/lock", None)?;
            print(&v, json, |_| "queue unlocked".into());
        }
        QueueAction::History => {
            let v = c.call("GET", "/api/v1/history", None)?;
            print(&v, json, |v| {
                v["history"]
                    .as_array()
                    .map(|h| h.iter().map(item_line).collect::<Vec<_>>().join("\n"))
                    .unwrap_or_default()
            });
        }
    }
    Ok(0)
}

pub fn run(a: RunArgs) -> anyhow::Result<i32> {
    let c = client(&a.server, Some(Duration::from_secs(90)));
    // The run routes are POST /api/v1/run/NAME; the simulator's film is a PUT of its own.
    let run = |name: &str| ("POST", format!("/api/v1/run/{name}"));
    let film = || ("PUT", "/api/v1/sim/film".to_string());
    let ((method, path), body, what) = match a.action {
        RunAction::Pause { now } => (
            run("pause"),
            Some(json!({"immediate": now})),
            if now {
                "paused now"
            } else {
                "pausing at the next tile"
            },
        ),
        RunAction::Resume => (run("resume"), None, "resumed"),
        RunAction::Stop => (run("stop"), None, "stopping at the next tile"),
        RunAction::Abort => (
            run("abort"),
            None,
            "aborted: stages stopped, the item is back at the front",
        ),
        RunAction::Halt => (run("halt"), None, "halted: controller reset"),
        RunAction::LayFilm => (
            film(),
            Some(json!({"laid": true})),
            "the simulator's film is laid on the carriage",
        ),
        RunAction::LiftFilm => (
            film(),
            Some(json!({"laid": false})),
            "the simulator's film is lifted: the plate's crosses show",
        ),
    };
    let v = c.call(method, &path, body)?;
    print(&v, a.server.json, |v| match &v["id"] {
        Value::Null => what.to_string(),
        id => format!("item {id}: {what}"),
    });
    Ok(0)
}

/// Follows the event stream, one line per event (JSON with --json), until the service ends.
pub fn events(a: EventsArgs) -> anyhow::Result<i32> {
    let c = client(&a.server, None);
    let url = format!("{}/api/v1/events", c.base);
    let mut q = c.agent.get(&url);
    if let Some(t) = &c.token {
        q = q.header("Authorization", format!("Bearer {t}"));
    }
    if let Some(n) = a.since {
        q = q.header("Last-Event-ID", n.to_string());
    }
    let r = q
        .call()
        .with_context(|| format!("no answer from the service at {url}"))?;
    if !r.status().is_success() {
        let status = r.status();
        let v: Value = r.into_body().read_json().unwrap_or(Value::Null);
        bail!(
            "the service refused ({status}): {}",
            v["message"].as_str().unwrap_or("")
        );
    }
    let reader = std::io::BufReader::new(r.into_body().into_reader());
    let mut kind = String::new();
    for line in reader.lines() {
        let line = line.context("reading the event stream")?;
        if let Some(k) = line.strip_prefix("event:") {
            kind = k.trim().to_string();
        } else if let Some(d) = line.strip_prefix("data:") {
            let v: Value = serde_json::from_str(d.trim()).unwrap_or(Value::Null);
            if a.server.json {
                println!("{}", json!({"kind": kind, "event": v}));
            } else {
                match &v["seq"] {
                    Value::Null => println!(
                        "{:>20} {:<9} {}",
                        "",
                        kind,
                        v["message"].as_str().unwrap_or("")
                    ),
                    seq => println!("{:>20} {:<9} {}", seq, kind, v["data"]),
                }
            }
            use std::io::Write;
            let _ = std::io::stdout().flush();
        }
    }
    Ok(0)
}
