//! `rig serve` end to end on the simulator: who may do what, a server open to the network
//! without tokens, hostile requests, and events that no client loses.

mod common;

use common::serve::{call, wait_for, Server};
use serde_json::{json, Value};
use std::io::{BufRead, BufReader, Read, Write};
use std::time::{Duration, Instant};

fn tokens(dir: &std::path::Path) -> (std::path::PathBuf, [String; 3]) {
    let path = dir.join("tokens.toml");
    let mut out = Vec::new();
    for (name, role) in [("o", "observer"), ("p", "operator"), ("a", "admin")] {
        let o = common::rig()
            .args(["serve", "token", "add", name, "--role", role, "--tokens"])
            .arg(&path)
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        out.push(String::from_utf8(o.stdout).unwrap().trim().to_string());
    }
    let text = std::fs::read_to_string(&path).unwrap();
    for t in &out {
        assert!(!text.contains(t.as_str()), "a token in clear in the file");
    }
    (path, [out[0].clone(), out[1].clone(), out[2].clone()])
}

/// The routes as the service lists them: (method, path, role).
fn routes(s: &Server, token: &str) -> Vec<(String, String, Option<String>)> {
    let (st, doc) = s.call("GET", "/api/v1/openapi.json", Some(token), None);
    assert_eq!(st, 200);
    let mut v = Vec::new();
    for (path, ops) in doc["paths"].as_object().unwrap() {
        for (m, op) in ops.as_object().unwrap() {
            v.push((
                m.to_uppercase(),
                path.replace("{id}", "0")
                    .replace("{kind}", "pixel")
                    .replace("{session}", "20261129T000000Z-pixel")
                    .replace("{file}", "residuals-affine.png"),
                op["x-role"].as_str().map(String::from),
            ));
        }
    }
    v
}

#[test]
fn every_route_answers_each_role_as_the_roles_say() {
    let d = tempfile::tempdir().unwrap();
    let (file, [obs, op, admin]) = tokens(d.path());
    let s = Server::start(
        &d.path().join("data"),
        &["--sim", "--tokens", file.to_str().unwrap()],
    );
    let rank = |r: &str| {
        ["observer", "operator", "admin"]
            .iter()
            .position(|x| *x == r)
            .unwrap()
    };
    let all = routes(&s, &obs);
    assert!(all.len() >= 20, "{all:?}");
    let mut checked = 0;
    for (m, path, role) in &all {
        if path.ends_with("/shutdown") {
            continue;
        }
        for (who, tok) in [
            (None, None),
            (Some(0), Some(obs.as_str())),
            (Some(1), Some(op.as_str())),
            (Some(2), Some(admin.as_str())),
        ] {
            let body = (m != "GET" && m != "DELETE").then_some("{\"wrong\": 1}");
            let (st, v) = if path.ends_with("/events") {
                (events_status(&s.url, tok), Value::Null)
            } else {
                s.call(m, path, tok, body)
            };
            let want = match (role, who) {
                (None, _) => None,
                (Some(_), None) => Some(401),
                (Some(r), Some(w)) if w < rank(r) => Some(403),
                _ => None,
            };
            match want {
                Some(code) => assert_eq!(st, code, "{m} {path} as {who:?}: {v}"),
                None => assert!(
                    st != 401 && st != 403,
                    "{m} {path} as {who:?} gave {st}: {v}"
                ),
            }
            checked += 1;
        }
    }
    // An unknown token is refused; shutdown is the admin's alone, and ends the service.
    assert_eq!(s.call("GET", "/api/v1/status", Some("nope"), None).0, 401);
    assert_eq!(s.call("POST", "/api/v1/shutdown", Some(&op), None).0, 403);
    assert_eq!(
        s.call("POST", "/api/v1/shutdown", Some(&admin), None).0,
        200
    );
    let mut s = s;
    let t0 = Instant::now();
    while s.child.try_wait().unwrap().is_none() {
        assert!(
            t0.elapsed() < Duration::from_secs(30),
            "shutdown did not end the service"
        );
        std::thread::sleep(Duration::from_millis(20));
    }
    eprintln!("{checked} route × role requests checked");
}

fn events_status(url: &str, token: Option<&str>) -> u16 {
    let mut q = common::serve::agent().get(format!("{url}/api/v1/events"));
    if let Some(t) = token {
        q = q.header("Authorization", format!("Bearer {t}"));
    }
    q.call().unwrap().status().as_u16()
}

#[test]
fn a_server_open_to_the_network_needs_tokens() {
    let d = tempfile::tempdir().unwrap();
    let o = common::rig()
        .args(["serve", "--sim", "--bind", "0.0.0.0:0", "--data"])
        .arg(d.path())
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(1));
    let e = String::from_utf8_lossy(&o.stderr);
    assert!(
        e.contains("without tokens") && e.contains("--tokens"),
        "{e}"
    );
}

/// Reads events from an SSE stream (sending `last` as Last-Event-ID) until `n` of them are
/// of kind `queue` or `resync`: (kind, seq) of every event read.
fn read_events(url: &str, last: Option<u64>, n: usize) -> Vec<(String, u64)> {
    let mut q = common::serve::agent().get(format!("{url}/api/v1/events"));
    if let Some(l) = last {
        q = q.header("Last-Event-ID", l.to_string());
    }
    let r = q.call().unwrap();
    let mut lines = BufReader::new(r.into_body().into_reader()).lines();
    let mut kind = String::new();
    let mut out: Vec<(String, u64)> = Vec::new();
    while out
        .iter()
        .filter(|e| e.0 == "queue" || e.0 == "resync")
        .count()
        < n
    {
        let l = lines.next().unwrap().unwrap();
        if let Some(k) = l.strip_prefix("event:") {
            kind = k.trim().into();
        } else if let Some(d) = l.strip_prefix("data:") {
            let v: Value = serde_json::from_str(d.trim()).unwrap();
            out.push((kind.clone(), v["seq"].as_u64().unwrap_or(0)));
        }
    }
    out
}

/// Twenty clients follow the events while ten edit the queue: every client sees every event
/// in the same gapless order; a client reconnecting with its last number gets what it missed.
#[test]
fn no_client_loses_or_reorders_an_event() {
    let d = tempfile::tempdir().unwrap();
    let s = Server::start(&d.path().join("data"), &["--sim"]);
    let url = s.url.clone();
    let (_, st) = s.call("GET", "/api/v1/status", None, None);
    let first = st["next_event"].as_u64().unwrap();
    const EDITS: usize = 10 * 20;
    let readers: Vec<_> = (0..20)
        .map(|_| {
            let u = url.clone();
            std::thread::spawn(move || read_events(&u, Some(first - 1), EDITS))
        })
        .collect();
    let writers: Vec<_> = (0..10)
        .map(|w| {
            let u = url.clone();
            std::thread::spawn(move || {
                for i in 0..20 {
                    let b = json!({"items": [{"task": {"kind": "move", "x_mm": w as f64, "y_mm": i as f64}}]});
                    let (st, v) = call(&u, "POST", "/api/v1/queue/items", None, Some(&b.to_string()));
                    assert_eq!(st, 200, "{v}");
                }
            })
        })
        .collect();
    for w in writers {
        w.join().unwrap();
    }
    let seen: Vec<Vec<(String, u64)>> = readers.into_iter().map(|r| r.join().unwrap()).collect();
    // Every client saw the same numbers, gapless from the first; the stage's position events
    // are among them.
    for c in &seen {
        let seqs: Vec<u64> = c.iter().map(|e| e.1).collect();
        let want: Vec<u64> = (first..first + seqs.len() as u64).collect();
        assert_eq!(seqs, want, "a client saw a gap or another order");
        assert_eq!(c[..EDITS.min(c.len())].len(), EDITS.min(c.len()));
        assert_eq!(c.iter().filter(|e| e.0 == "queue").count(), EDITS);
    }
    let shortest = seen.iter().map(|c| c.len()).min().unwrap();
    for c in &seen {
        assert_eq!(
            c[..shortest],
            seen[0][..shortest],
            "two clients saw different events"
        );
    }
    // Reconnecting after event first+99: from first+100 on, replayed.
    let again = read_events(&url, Some(first + 99), 50);
    assert_eq!(again.first().unwrap().1, first + 100);
    let seqs: Vec<u64> = again.iter().map(|e| e.1).collect();
    assert_eq!(
        seqs,
        (first + 100..first + 100 + seqs.len() as u64).collect::<Vec<_>>()
    );
    // A number from before the backlog or from another run: told to resync first.
    assert_eq!(read_events(&url, Some(3), 1)[0].0, "resync");
    let (_, q) = s.call("GET", "/api/v1/queue", None, None);
    assert_eq!(q["queue"].as_array().unwrap().len(), EDITS);
}

/// An admin's lock closes the queue and the run's control to operators (423, saying who and
/// why) but never pause, abort or halt; it is journaled (a restart keeps it); an admin lifts it.
#[test]
fn an_admins_lock_keeps_operators_off_the_queue_but_not_off_the_brakes() {
    let d = tempfile::tempdir().unwrap();
    let (file, [_obs, op, admin]) = tokens(d.path());
    let data = d.path().join("data");
    let args = ["--sim", "--tokens", file.to_str().unwrap()];
    let s = Server::start(&data, &args);
    let add = json!({"items": [{"task": {"kind": "home"}}]}).to_string();
    assert_eq!(
        s.call("POST", "/api/v1/lock", Some(&op), Some("{\"note\": \"x\"}"))
            .0,
        403
    );
    let (st, v) = s.call(
        "POST",
        "/api/v1/lock",
        Some(&admin),
        Some("{\"note\": \"\"}"),
    );
    assert_eq!((st, v["error"].as_str()), (422, Some("bad_note")), "{v}");
    let (st, v) = s.call(
        "POST",
        "/api/v1/lock",
        Some(&admin),
        Some("{\"note\": \"aligning the lamp\"}"),
    );
    assert_eq!(st, 200, "{v}");
    let (st, v) = s.call("POST", "/api/v1/queue/items", Some(&op), Some(&add));
    assert_eq!(st, 423, "{v}");
    assert_eq!(v["error"], "locked");
    assert!(
        v["message"].as_str().unwrap().contains("aligning the lamp"),
        "{v}"
    );
    for path in [
        "/api/v1/queue/start",
        "/api/v1/run/resume",
        "/api/v1/queue/clear",
    ] {
        assert_eq!(s.call("POST", path, Some(&op), None).0, 423, "{path}");
    }
    // Jogging an unhomed stage (the admin may): the remedy named is an item, not a command.
    let (st, v) = s.call(
        "POST",
        "/api/v1/stage/jog",
        Some(&admin),
        Some("{\"dx_mm\": 1, \"dy_mm\": 0}"),
    );
    assert_eq!((st, v["error"].as_str()), (409, Some("not_homed")), "{v}");
    assert!(
        v["message"].as_str().unwrap().contains("queue a home item"),
        "{v}"
    );
    // The brakes stay open: nothing runs, so pause and abort say so (409), halt resets.
    assert_eq!(s.call("POST", "/api/v1/run/pause", Some(&op), None).0, 409);
    assert_eq!(s.call("POST", "/api/v1/run/abort", Some(&op), None).0, 409);
    assert_eq!(s.call("POST", "/api/v1/run/halt", Some(&op), None).0, 200);
    // The admin still may.
    assert_eq!(
        s.call("POST", "/api/v1/queue/items", Some(&admin), Some(&add))
            .0,
        200
    );
    // Kept across a crash.
    s.kill();
    let s = Server::start(&data, &args);
    let (_, st) = s.call("GET", "/api/v1/status", Some(&op), None);
    assert_eq!(st["lock"]["note"], "aligning the lamp", "{st}");
    assert_eq!(
        s.call("POST", "/api/v1/queue/items", Some(&op), Some(&add))
            .0,
        423
    );
    assert_eq!(s.call("DELETE", "/api/v1/lock", Some(&admin), None).0, 200);
    assert_eq!(
        s.call("POST", "/api/v1/queue/items", Some(&op), Some(&add))
            .0,
        200
    );
    let (_, q) = s.call("GET", "/api/v1/queue", Some(&op), None);
    assert_eq!(q["queue"].as_array().unwrap().len(), 2);
}

/// A port scan's half-open connections (headers never finished) neither pile up nor lock
/// others out: beyond the cap they are closed at once, and each is closed when the header
/// time limit runs out; a real client then gets its answer.
#[test]
fn a_port_scan_cannot_exhaust_the_service() {
    let d = tempfile::tempdir().unwrap();
    let s = Server::start(
        &d.path().join("data"),
        &[
            "--sim",
            "--max-connections",
            "40",
            "--header-timeout",
            "0.3",
        ],
    );
    let host = s.url.trim_start_matches("http://").to_string();
    let pid = s.child.id();
    let fds = || std::fs::read_dir(format!("/proc/{pid}/fd")).map_or(0, |d| d.count());
    let before = fds();
    let mut scan: Vec<std::net::TcpStream> = (0..300)
        .map(|_| {
            let mut c = std::net::TcpStream::connect(&host).unwrap();
            let _ = c.write_all(b"GET /api/v1/status HTTP/1.1\r\nHost: x\r\n");
            c
        })
        .collect();
    std::thread::sleep(Duration::from_millis(100));
    let during = fds();
    assert!(
        during <= before + 45,
        "{during} descriptors open during the scan (from {before}; the cap is 40)"
    );
    // Every half-open connection is closed by the service within the header limit (or at once).
    let t0 = Instant::now();
    for c in &mut scan {
        c.set_read_timeout(Some(Duration::from_secs(5))).unwrap();
        let mut b = [0u8; 64];
        let n = c.read(&mut b).unwrap_or(0);
        assert!(n == 0 || b.starts_with(b"HTTP/1.1 408"), "{:?}", &b[..n]);
    }
    assert!(t0.elapsed() < Duration::from_secs(5));
    let (st, _) = s.call("GET", "/api/v1/status", None, None);
    assert_eq!(st, 200);
    // Event streams take at most three quarters of the connections (30 of 40): the rest stay
    // free for control, so a halt gets through with every stream taken.
    let streams: Vec<std::net::TcpStream> = (0..30)
        .map(|_| {
            let mut c = std::net::TcpStream::connect(&host).unwrap();
            c.write_all(b"GET /api/v1/events HTTP/1.1\r\nHost: x\r\n\r\n")
                .unwrap();
            let mut b = [0u8; 12];
            c.read_exact(&mut b).unwrap();
            assert_eq!(&b, b"HTTP/1.1 200");
            c
        })
        .collect();
    let one_more = common::serve::agent()
        .get(format!("{}/api/v1/events", s.url))
        .call()
        .unwrap();
    assert_eq!(one_more.status().as_u16(), 503);
    drop(one_more);
    assert_eq!(s.call("POST", "/api/v1/run/halt", None, None).0, 200);
    drop(streams);
    eprintln!("300 half-open connections: {during} descriptors at most (from {before}), all closed in {:.2} s", t0.elapsed().as_secs_f64());
}

/// Position events come during a motion, not only after it: a long move reports where the
/// carriage is on its way, at most ten times a second.
#[test]
fn position_events_follow_a_motion_at_most_ten_times_a_second() {
    let d = tempfile::tempdir().unwrap();
    let s = Server::start(
        &d.path().join("data"),
        // A twentieth of real time: a 250 mm move takes about half a second.
        &["--sim", "--sim-time-scale", "0.05"],
    );
    let (_, st) = s.call("GET", "/api/v1/status", None, None);
    let first = st["next_event"].as_u64().unwrap();
    let body = json!({"items": [{"task": {"kind": "home"}}, {"task": {"kind": "move", "x_mm": 200.0, "y_mm": 150.0}}]});
    let (code, v) = s.call("POST", "/api/v1/queue/items", None, Some(&body.to_string()));
    assert_eq!(code, 200, "{v}");
    let moving = v["ids"][1].as_u64().unwrap();
    let url = s.url.clone();
    let reader = std::thread::spawn(move || {
        let r = common::serve::agent()
            .get(format!("{url}/api/v1/events"))
            .header("Last-Event-ID", (first - 1).to_string())
            .call()
            .unwrap();
        let mut kind = String::new();
        let mut out: Vec<(u64, f64, f64, bool)> = Vec::new();
        let mut started = false;
        for l in BufReader::new(r.into_body().into_reader()).lines() {
            let l = l.unwrap();
            if let Some(k) = l.strip_prefix("event:") {
                kind = k.trim().into();
            } else if let Some(d) = l.strip_prefix("data:") {
                let v: Value = serde_json::from_str(d.trim()).unwrap();
                let data = &v["data"];
                if kind == "item" && data["id"] == moving {
                    if data["state"] == "running" {
                        started = true;
                    } else if data["ended"].is_string() {
                        return out;
                    }
                }
                if kind == "position" {
                    out.push((
                        v["at_ms"].as_u64().unwrap(),
                        data["x_mm"].as_f64().unwrap(),
                        data["y_mm"].as_f64().unwrap(),
                        started,
                    ));
                }
            }
        }
        out
    });
    assert_eq!(s.call("POST", "/api/v1/queue/start", None, None).0, 200);
    let seen = reader.join().unwrap();
    // On the way: strictly between the home position and the target.
    let on_way: Vec<_> = seen
        .iter()
        .filter(|e| e.3 && e.1 > 1.0 && e.1 < 199.0)
        .collect();
    eprintln!(
        "{} position events during the move, {} of them on the way",
        seen.iter().filter(|e| e.3).count(),
        on_way.len()
    );
    assert!(on_way.len() >= 3, "too few positions on the way: {seen:?}");
    // The carriage moves one way: x grows along the events.
    assert!(on_way.windows(2).all(|w| w[1].1 >= w[0].1), "{on_way:?}");
    // Rate-limited: on the way, never two within 100 ms (a few ms of clock granularity).
    for w in on_way.windows(2) {
        assert!(
            w[1].0 - w[0].0 >= 95,
            "two position events {} ms apart",
            w[1].0 - w[0].0
        );
    }
}

/// Clients that vanish while events are written to them (a close, a reset, then another write:
/// EPIPE) leave the service answering: the process must not die of SIGPIPE, which the CLI's
/// other commands take by default.
#[test]
fn clients_vanishing_mid_write_never_end_the_service() {
    let d = tempfile::tempdir().unwrap();
    let mut s = Server::start(&d.path().join("data"), &["--sim"]);
    let host = s.url.trim_start_matches("http://").to_string();
    let done = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
    // Three writers keep events coming while the readers come and go.
    let writers: Vec<_> = (0..3)
        .map(|w| {
            let (u, done) = (s.url.clone(), done.clone());
            std::thread::spawn(move || {
                let mut n = 0;
                while !done.load(std::sync::atomic::Ordering::Relaxed) {
                    let b = json!({"items": [{"task": {"kind": "move", "x_mm": w as f64, "y_mm": 1.0}}]});
                    let (st, v) = call(&u, "POST", "/api/v1/queue/items", None, Some(&b.to_string()));
                    assert_eq!(st, 200, "{v}");
                    n += 1;
                }
                n
            })
        })
        .collect();
    for _ in 0..400 {
        let mut ev = std::net::TcpStream::connect(&host).unwrap();
        ev.write_all(b"GET /api/v1/events HTTP/1.1\r\nHost: x\r\n\r\n")
            .unwrap();
        let mut b = [0u8; 256];
        let _ = ev.read(&mut b).unwrap();
        // Dropped mid-stream, some of it unread.
    }
    done.store(true, std::sync::atomic::Ordering::Relaxed);
    let added: usize = writers.into_iter().map(|w| w.join().unwrap()).sum();
    assert!(s.child.try_wait().unwrap().is_none(), "the service ended");
    let (_, q) = s.call("GET", "/api/v1/queue", None, None);
    assert_eq!(q["queue"].as_array().unwrap().len(), added);
}

/// Hostile requests each end in a typed 4xx with a message, and leave the queue, the stage
/// and the service as they were.
#[test]
fn hostile_requests_are_refused_with_typed_errors() {
    let d = tempfile::tempdir().unwrap();
    let s = Server::start(&d.path().join("data"), &["--sim"]);
    // A half-open connection (a port scan's), and a client that leaves mid-stream: neither
    // holds the service up.
    let mut half = std::net::TcpStream::connect(s.url.trim_start_matches("http://")).unwrap();
    half.write_all(b"GET /api/v1/status HTTP/1.1\r\nHost: x\r\n")
        .unwrap();
    {
        let mut ev = std::net::TcpStream::connect(s.url.trim_start_matches("http://")).unwrap();
        ev.write_all(b"GET /api/v1/events HTTP/1.1\r\nHost: x\r\n\r\n")
            .unwrap();
        let mut b = [0u8; 64];
        let _ = ev.read(&mut b).unwrap();
    }
    let big = format!(
        "{{\"items\": [{{\"task\": {{\"kind\": \"home\"}}, \"key\": \"{}\"}}]}}",
        "x".repeat(5 << 20)
    );
    let scan = |name: &str, script: &str| {
        json!({"items": [{"task": {"kind": "scan", "name": name, "script": script}}]}).to_string()
    };
    let cert = |c: &str| {
        json!({"items": [{"task": {"kind": "calibrate_pixel", "plate_cert": c}}]}).to_string()
    };
    let cases: Vec<(&str, String, Option<String>, u16, &str)> =
        vec![
        // A client cannot make the service read a file of its choosing.
        ("POST", "/api/v1/queue/items".into(), Some(cert("/etc/passwd")), 422, "bad_task"),
        ("POST", "/api/v1/queue/items".into(), Some(cert("../tokens.toml")), 422, "bad_task"),
        (
            "POST",
            "/api/v1/queue/items".into(),
            Some("{\"items\": [".into()),
            400,
            "malformed_json",
        ),
        (
            "POST",
            "/api/v1/queue/items".into(),
            Some(
                "{\"items\": [{\"task\": {\"kind\": \"move\", \"x_mm\": \"ten\", \"y_mm\": 1}}]}"
                    .into(),
            ),
            422,
            "wrong_type",
        ),
        (
            "POST",
            "/api/v1/queue/items".into(),
            Some("{\"items\": [{\"task\": {\"kind\": \"fly\"}}]}".into()),
            422,
            "wrong_type",
        ),
        (
            "POST",
            "/api/v1/queue/items".into(),
            Some("{\"items\": [], \"extra\": 1}".into()),
            422,
            "wrong_type",
        ),
        (
            "POST",
            "/api/v1/queue/items".into(),
            Some("{\"items\": []}".into()),
            422,
            "bad_request",
        ),
        (
            "POST",
            "/api/v1/queue/items".into(),
            Some(
                "{\"items\": [{\"task\": {\"kind\": \"move\", \"x_mm\": 500, \"y_mm\": 1}}]}"
                    .into(),
            ),
            422,
            "out_of_limits",
        ),
        (
            "POST",
            "/api/v1/queue/items".into(),
            Some(
                "{\"items\": [{\"task\": {\"kind\": \"move\", \"x_mm\": 1e400, \"y_mm\": 1}}]}"
                    .into(),
            ),
            400,
            "malformed_json",
        ),
        (
            "POST",
            "/api/v1/queue/items".into(),
            Some(scan("../../etc", "x = 1")),
            422,
            "bad_task",
        ),
        (
            "POST",
            "/api/v1/queue/items".into(),
            Some(scan("ok", "[film]\nname = 3")),
            422,
            "bad_task",
        ),
        (
            "POST",
            "/api/v1/queue/items".into(),
            Some(
                "{\"items\": [{\"task\": {\"kind\": \"home\"}}], \"at\": {\"before\": 77}}".into(),
            ),
            404,
            "no_item",
        ),
        (
            "POST",
            "/api/v1/queue/items".into(),
            Some("{\"items\": [{\"task\": {\"kind\": \"home\"}}], \"at\": {\"index\": 9}}".into()),
            422,
            "bad_position",
        ),
        ("GET", "/api/v1/items/12345".into(), None, 404, "no_item"),
        (
            "GET",
            "/api/v1/items/..%2F..%2Fetc".into(),
            None,
            400,
            "bad_id",
        ),
        (
            "DELETE",
            "/api/v1/queue/items/-1".into(),
            None,
            400,
            "bad_id",
        ),
        (
            "POST",
            "/api/v1/queue/items/5/move".into(),
            Some("{\"to\": \"front\"}".into()),
            404,
            "no_item",
        ),
        ("POST", "/api/v1/run/resume".into(), None, 409, "state"),
        ("POST", "/api/v1/run/pause".into(), None, 409, "state"),
        ("POST", "/api/v1/run/abort".into(), None, 409, "state"),
        ("POST", "/api/v1/run/stop".into(), None, 409, "state"),
        (
            "POST",
            "/api/v1/run/pause".into(),
            Some("{\"immediate\": \"yes\"}".into()),
            422,
            "bad_body",
        ),
        (
            "POST",
            "/api/v1/stage/jog".into(),
            Some("{\"dx_mm\": 1e9, \"dy_mm\": 0}".into()),
            422,
            "bad_jog",
        ),
        ("GET", "/api/v1/nothing/here".into(), None, 404, "no_route"),
    ];
    let n = cases.len();
    for (m, path, body, code, kind) in cases {
        let (st, v) = s.call(m, &path, None, body.as_deref());
        assert_eq!(st, code, "{m} {path}: {v}");
        assert_eq!(v["error"], kind, "{m} {path}: {v}");
        assert!(v["message"].as_str().is_some_and(|m| !m.is_empty()), "{v}");
    }
    // A body over the limit, announced with `Expect: 100-continue` as curl does: refused
    // before it is sent (a client that sends it anyway races the server's close).
    {
        let mut c = std::net::TcpStream::connect(s.url.trim_start_matches("http://")).unwrap();
        write!(
            c,
            "POST /api/v1/queue/items HTTP/1.1\r\nHost: x\r\nContent-Type: application/json\r\nContent-Length: {}\r\nExpect: 100-continue\r\n\r\n",
            big.len()
        )
        .unwrap();
        let mut answer = String::new();
        let _ = c.read_to_string(&mut answer);
        assert!(answer.starts_with("HTTP/1.1 413"), "{answer}");
        assert!(answer.contains("\"error\":\"body\""), "{answer}");
    }
    // Another site's page cannot drive the service (a no-cors POST from the browser): the
    // service's own page can.
    {
        let host = s.url.trim_start_matches("http://");
        let post = |origin: &str| {
            let r = common::serve::agent()
                .post(format!("{}/api/v1/queue/start", s.url))
                .header("Origin", origin)
                .send_empty()
                .unwrap();
            r.status().as_u16()
        };
        assert_eq!(post("http://evil.example"), 403);
        assert_eq!(post("null"), 403);
        assert_eq!(post(&format!("http://{host}")), 200);
        assert_eq!(s.call("POST", "/api/v1/queue/stop", None, None).0, 200);
    }
    // Nothing of it was queued, and the service still answers.
    let (st, q) = s.call("GET", "/api/v1/queue", None, None);
    assert_eq!(st, 200);
    assert_eq!(q["queue"].as_array().unwrap().len(), 0, "{q}");
    // Ten thousand items in one batch are taken; one more is refused, typed.
    let batch = json!({"items": vec![json!({"task": {"kind": "home"}}); 10_000]}).to_string();
    let (st, v) = s.call("POST", "/api/v1/queue/items", None, Some(&batch));
    assert_eq!(st, 200, "{v}");
    let (st, v) = s.call(
        "POST",
        "/api/v1/queue/items",
        None,
        Some("{\"items\": [{\"task\": {\"kind\": \"home\"}}]}"),
    );
    assert_eq!((st, v["error"].as_str()), (507, Some("queue_full")), "{v}");
    let (st, _) = s.call("POST", "/api/v1/queue/clear", None, None);
    assert_eq!(st, 200);
    // A storm of pauses, resumes and aborts with nothing running: each refused, typed.
    for i in 0..60 {
        let p = [
            "/api/v1/run/pause",
            "/api/v1/run/resume",
            "/api/v1/run/abort",
        ][i % 3];
        let (st, v) = s.call("POST", p, None, None);
        assert_eq!((st, v["error"].as_str()), (409, Some("state")), "{p}: {v}");
    }
    // Halt from idle resets the controller; the stage then needs homing and says so.
    let (st, v) = s.call("POST", "/api/v1/run/halt", None, None);
    assert_eq!(st, 200, "{v}");
    let (_, v) = s.call("GET", "/api/v1/status", None, None);
    assert_eq!(v["stage"]["homed"], false, "{v}");
    drop(half);
    eprintln!(
        "{n} hostile requests, a 10 000-item batch, a full queue, 60 control requests: each typed"
    );
}

/// The simulator's film is laid and lifted as an operator's hands do: with the film laid (as
/// `rig serve --sim` starts) a pixel calibration cannot see the plate's crosses and fails;
/// lifted, the same item ends done; while an item runs the film stays put (409 busy); laid
/// again, an interior calibration sees the fiducials and ends done. The status and the
/// command line say where the film is.
#[test]
fn the_simulators_film_is_lifted_for_a_pixel_calibration_and_laid_for_an_interior_one() {
    let d = tempfile::tempdir().unwrap();
    let store = d.path().join("store");
    // Motions at a hundredth of real time: an item (which homes first, 0.6 s) runs long
    // enough to be caught running.
    let s = Server::start(
        &d.path().join("data"),
        &[
            "--sim",
            "--sim-time-scale",
            "0.01",
            "--store",
            store.to_str().unwrap(),
        ],
    );
    assert_eq!(
        s.call("GET", "/api/v1/status", None, None).1["sim_film"],
        "laid"
    );
    let pixel = json!({"items": [{"task": {"kind": "calibrate_pixel", "frames": 4, "grid": 3, "grid_only": true}}]}).to_string();
    let ended = |id: u64| {
        wait_for(&s, "/api/v1/history", 120, |v| {
            v["history"]
                .as_array()
                .is_some_and(|h| h.iter().any(|i| i["id"] == id))
        })["history"]
            .as_array()
            .unwrap()
            .iter()
            .find(|i| i["id"] == id)
            .unwrap()
            .clone()
    };
    let (st, v) = s.call("POST", "/api/v1/queue/items", None, Some(&pixel));
    assert_eq!(st, 200, "{v}");
    let covered = v["ids"][0].as_u64().unwrap();
    assert_eq!(s.call("POST", "/api/v1/queue/start", None, None).0, 200);
    let it = ended(covered);
    assert_eq!(it["state"], "failed", "{it}");
    assert!(
        it["attempts"][0]["message"]
            .as_str()
            .is_some_and(|m| m.contains("film lying over the plate")),
        "{it}"
    );

    // Lifted from the command line, as an operator would.
    let out = common::run_ok(
        common::rig()
            .args(["run", "lift-film", "--server", &s.url])
            .env_remove("RIG_TOKEN"),
    );
    assert!(
        String::from_utf8_lossy(&out.stdout).contains("lifted"),
        "{out:?}"
    );
    assert_eq!(
        s.call("GET", "/api/v1/status", None, None).1["sim_film"],
        "lifted"
    );
    let (st, v) = s.call("POST", "/api/v1/queue/items", None, Some(&pixel));
    assert_eq!(st, 200, "{v}");
    let bare = v["ids"][0].as_u64().unwrap();
    // Started: the queue stopped after the failure (continue_on_failure is off).
    s.call("POST", "/api/v1/queue/start", None, None);
    wait_for(&s, "/api/v1/status", 60, |v| v["running"]["id"] == bare);
    let (st, v) = s.call("PUT", "/api/v1/sim/film", None, Some(r#"{"laid": true}"#));
    assert_eq!((st, v["error"].as_str()), (409, Some("busy")), "{v}");
    let it = ended(bare);
    assert_eq!(it["state"], "done", "{it}");

    let (st, v) = s.call("PUT", "/api/v1/sim/film", None, Some(r#"{"laid": true}"#));
    assert_eq!((st, &v["sim_film"]), (200, &json!("laid")), "{v}");
    let (st, v) = s.call("PUT", "/api/v1/sim/film", None, Some(r#"{"laid": "yes"}"#));
    assert_eq!(st, 422, "{v}");
    let interior = json!({"items": [{"task": {"kind": "calibrate_interior", "frames": 4}}]});
    let (st, v) = s.call(
        "POST",
        "/api/v1/queue/items",
        None,
        Some(&interior.to_string()),
    );
    assert_eq!(st, 200, "{v}");
    let id = v["ids"][0].as_u64().unwrap();
    s.call("POST", "/api/v1/queue/start", None, None);
    let it = ended(id);
    assert_eq!(it["state"], "done", "{it}");
    // Each calibration item's folder is its session in the store.
    for (id, kind) in [(bare, "pixel"), (id, "interior")] {
        let (st, v) = s.call("GET", &format!("/api/v1/items/{id}"), None, None);
        assert_eq!(st, 200, "{v}");
        let dir = std::path::Path::new(v["dir"].as_str().unwrap_or_else(|| panic!("{v}")));
        assert!(
            dir.starts_with(&store) && dir.is_dir() && dir.to_string_lossy().ends_with(kind),
            "{v}"
        );
    }
}
