//! The service under load for a minute (`cargo test --release --test service_soak -- --ignored`;
//! not yet in `.ci/run`: it fails today, see issue 39): scans run back to back on the simulator in real time while 100 clients
//! follow the events and 10 edit the queue. No client loses or reorders an event (numbers
//! gapless), and the scan's tile rate stays within 5 % of its rate with no clients.

mod common;

use common::serve::{call, Server};
use serde_json::{json, Value};
use std::io::{BufRead, BufReader};
use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

const WINDOW: Duration = Duration::from_secs(60);
/// Each editor adds and removes an item this often (at 50 ms, 370 edits a second in all, the
/// tile rate fell by a quarter: the journal's syncs and the clients' own threads share the two
/// cores with the scan).
const EDIT_EVERY: Duration = Duration::from_millis(500);

fn tiles_written(data: &Path) -> usize {
    let mut n = 0;
    if let Ok(items) = std::fs::read_dir(data.join("items")) {
        for i in items.flatten() {
            if let Ok(files) = std::fs::read_dir(i.path().join("scan/tiles")) {
                n += files
                    .flatten()
                    .filter(|f| f.path().extension().is_some_and(|e| e == "tiff"))
                    .count();
            }
        }
    }
    n
}

/// Tiles per second over `window`.
fn tile_rate(data: &Path, window: Duration) -> f64 {
    let (n0, t0) = (tiles_written(data), Instant::now());
    std::thread::sleep(window);
    (tiles_written(data) - n0) as f64 / t0.elapsed().as_secs_f64()
}

#[test]
#[ignore = "three minutes of load; fails today (the tile rate falls 30 % under the clients): issue 39"]
fn a_minute_of_100_event_clients_and_10_editors_costs_no_event_and_no_tile_rate() {
    let d = tempfile::tempdir().unwrap();
    let store = d.path().join("store");
    common::quick_pixel_session(&store);
    common::run_ok(
        common::rig()
            .args([
                "calibrate",
                "interior",
                "--sim",
                "--frames",
                "8",
                "--json",
                "--store",
            ])
            .arg(&store),
    );
    let script = "[film]\nname = \"soak\"\n\n[output]\ndir = \"unused\"\nresolution_um = 25.0\n\n[capture]\nframes = 8\noverlap = 0.2\nsettle_ms = 0\n\n[[region]]\nname = \"a\"\nphoto_mm = [-110.0, -110.0, 110.0, 110.0]\n";
    let data = d.path().join("data");
    let s = Server::start(
        &data,
        &[
            "--sim",
            "--sim-time-scale",
            "1",
            "--store",
            store.to_str().unwrap(),
        ],
    );
    // One scan of the whole photo for the whole run (scans back to back would each home
    // first, and the windows would hold different numbers of homings).
    let items: Vec<Value> = (0..3)
        .map(|k| json!({"task": {"kind": "scan", "name": format!("s{k}"), "script": script}}))
        .collect();
    let (st, v) = s.call(
        "POST",
        "/api/v1/queue/items",
        None,
        Some(&json!({ "items": items }).to_string()),
    );
    assert_eq!(st, 200, "{v}");
    assert_eq!(s.call("POST", "/api/v1/queue/start", None, None).0, 200);
    while tiles_written(&data) < 3 {
        std::thread::sleep(Duration::from_millis(100));
    }
    let alone = tile_rate(&data, WINDOW);

    let (_, st) = s.call("GET", "/api/v1/status", None, None);
    let first = st["next_event"].as_u64().unwrap();
    let stop = Arc::new(AtomicBool::new(false));
    let followers: Vec<_> = (0..100)
        .map(|_| {
            let (u, stop) = (s.url.clone(), stop.clone());
            std::thread::spawn(move || {
                // A stream longer than the tests' usual 60 s limit.
                let agent: ureq::Agent = ureq::Agent::config_builder()
                    .timeout_global(Some(Duration::from_secs(600)))
                    .build()
                    .into();
                let r = agent
                    .get(format!("{u}/api/v1/events"))
                    .header("Last-Event-ID", (first - 1).to_string())
                    .call()
                    .unwrap();
                let mut seqs = Vec::new();
                for l in BufReader::new(r.into_body().into_reader()).lines() {
                    let l = l.unwrap();
                    if l.starts_with("event: resync") || l.starts_with("event:resync") {
                        panic!("a client was told to resync");
                    }
                    if let Some(id) = l.strip_prefix("id:") {
                        seqs.push(id.trim().parse::<u64>().unwrap());
                        if stop.load(Ordering::Relaxed) {
                            break;
                        }
                    }
                }
                seqs
            })
        })
        .collect();
    let editors: Vec<_> = (0..10)
        .map(|w| {
            let (u, stop) = (s.url.clone(), stop.clone());
            std::thread::spawn(move || {
                let mut n = 0;
                while !stop.load(Ordering::Relaxed) {
                    let b = json!({"items": [{"task": {"kind": "move", "x_mm": w as f64, "y_mm": 1.0}}], "at": "back"});
                    let (st, v) = call(&u, "POST", "/api/v1/queue/items", None, Some(&b.to_string()));
                    assert_eq!(st, 200, "{v}");
                    let id = v["ids"][0].as_u64().unwrap();
                    let (st, v) = call(&u, "DELETE", &format!("/api/v1/queue/items/{id}"), None, None);
                    assert_eq!(st, 200, "{v}");
                    n += 2;
                    // An operator's pace, quickened: an add and a remove every half second.
                    std::thread::sleep(EDIT_EVERY);
                }
                n
            })
        })
        .collect();
    let loaded = tile_rate(&data, WINDOW);
    stop.store(true, Ordering::Relaxed);
    let edits: usize = editors.into_iter().map(|e| e.join().unwrap()).sum();
    // One more event wakes every follower to see the stop.
    s.call(
        "POST",
        "/api/v1/queue/items",
        None,
        Some(&json!({"items": [{"task": {"kind": "home"}}]}).to_string()),
    );
    let seen: Vec<Vec<u64>> = followers.into_iter().map(|f| f.join().unwrap()).collect();
    for c in &seen {
        assert_eq!(c.first(), Some(&first));
        assert!(
            c.windows(2).all(|w| w[1] == w[0] + 1),
            "a client saw a gap or another order"
        );
    }
    let shortest = seen.iter().map(|c| c.len()).min().unwrap();
    eprintln!(
        "{} event clients, {edits} edits by 10 clients in {} s: every client saw {shortest}+ events, gapless; tiles {alone:.3}/s alone, {loaded:.3}/s under load ({:+.1} %)",
        seen.len(),
        WINDOW.as_secs(),
        (loaded / alone - 1.0) * 100.0
    );
    assert!(edits > 1000, "{edits} edits");
    // (Tiles are counted whole: over a minute at ~1.8 a second, one tile is 1 % of the rate.)
    assert!(
        loaded >= 0.95 * alone,
        "the tile rate fell from {alone:.3}/s to {loaded:.3}/s under the clients"
    );
}
