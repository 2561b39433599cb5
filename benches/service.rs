//! The lab service measured against its floors, in one run (`cargo bench --bench service`):
//!
//! - event latency: from a jog's request to an event client seeing the new position (median,
//!   p99), beside one status round trip of the driver over the simulator's pseudo-terminal (the
//!   least a position change can cost to learn) and the jog's own HTTP answer;
//! - queue reads per second (100 items waiting) beside requests per second to a route that
//!   does nothing (the HTTP floor), two clients on two cores;
//! - the service's memory with 100 event clients following a burst of events, beside idle.

use serde_json::{json, Value};
use std::io::{BufRead, BufReader};
use std::process::{Child, Command, Stdio};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{mpsc, Arc};
use std::time::{Duration, Instant};

struct Server {
    child: Child,
    url: String,
    _data: tempfile::TempDir,
}

impl Drop for Server {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

fn start() -> Server {
    let data = tempfile::tempdir().unwrap();
    let mut child = Command::new(env!("CARGO_BIN_EXE_rig"))
        .args([
            "serve",
            "--sim",
            "--bind",
            "127.0.0.1:0",
            "--json",
            "--data",
        ])
        .arg(data.path())
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let mut line = String::new();
    BufReader::new(child.stdout.take().unwrap())
        .read_line(&mut line)
        .unwrap();
    let v: Value = serde_json::from_str(&line).unwrap();
    Server {
        url: v["listening"].as_str().unwrap().into(),
        child,
        _data: data,
    }
}

fn agent() -> ureq::Agent {
    ureq::Agent::config_builder()
        .http_status_as_error(false)
        .timeout_global(Some(Duration::from_secs(30)))
        .build()
        .into()
}

fn post(a: &ureq::Agent, url: &str, body: Value) -> Value {
    a.post(url)
        .header("Content-Type", "application/json")
        .send(body.to_string())
        .unwrap()
        .body_mut()
        .read_json()
        .unwrap_or(Value::Null)
}

fn percentile(v: &mut [f64], p: f64) -> f64 {
    v.sort_by(|a, b| a.total_cmp(b));
    v[((v.len() - 1) as f64 * p).round() as usize]
}

/// An event client: every position event's x and when it came.
fn follow_positions(url: &str) -> mpsc::Receiver<(f64, Instant)> {
    let (tx, rx) = mpsc::channel();
    let r = agent().get(format!("{url}/api/v1/events")).call().unwrap();
    std::thread::spawn(move || {
        let mut kind = String::new();
        for l in BufReader::new(r.into_body().into_reader()).lines() {
            let Ok(l) = l else { return };
            if let Some(k) = l.strip_prefix("event:") {
                kind = k.trim().into();
            } else if let Some(d) = l.strip_prefix("data:") {
                if kind == "position" {
                    let v: Value = serde_json::from_str(d.trim()).unwrap();
                    if tx
                        .send((v["data"]["x_mm"].as_f64().unwrap(), Instant::now()))
                        .is_err()
                    {
                        return;
                    }
                }
            }
        }
    });
    rx
}

fn rss_kib(pid: u32) -> u64 {
    let s = std::fs::read_to_string(format!("/proc/{pid}/status")).unwrap();
    s.lines()
        .find_map(|l| l.strip_prefix("VmRSS:"))
        .and_then(|v| v.trim().trim_end_matches("kB").trim().parse().ok())
        .unwrap()
}

fn status_round_trip_us(n: usize) -> Vec<f64> {
    let sim = rig_sim::EmbeddedSim::start(rig_sim::SimConfig {
        time_scale: 0.0,
        start_homed: true,
        ..Default::default()
    })
    .unwrap();
    let mut st = rig::stage::open(
        &sim.port,
        rig::stage::Dialect::Native,
        rig::stage::DriverOptions::default(),
        &Default::default(),
    )
    .unwrap();
    let v = (0..n)
        .map(|_| {
            let t = Instant::now();
            std::hint::black_box(st.status().unwrap());
            t.elapsed().as_secs_f64() * 1e6
        })
        .collect();
    drop(st);
    sim.shutdown().unwrap();
    v
}

fn main() {
    if std::env::args().any(|a| a == "--list") {
        return;
    }
    // The floor: one status round trip over the pty.
    let mut raw = status_round_trip_us(500);
    let raw_med = percentile(&mut raw, 0.5);
    let raw_p99 = percentile(&mut raw, 0.99);

    let s = start();
    let a = agent();
    post(
        &a,
        &format!("{}/api/v1/queue/items", s.url),
        json!({"items": [{"task": {"kind": "home"}}]}),
    );
    post(&a, &format!("{}/api/v1/queue/start", s.url), json!({}));
    std::thread::sleep(Duration::from_millis(500));
    post(&a, &format!("{}/api/v1/queue/stop", s.url), json!({}));

    // Event latency: jog ±10 µm, 200 times; each time, when the new x reaches the client.
    let rx = follow_positions(&s.url);
    std::thread::sleep(Duration::from_millis(200));
    while rx.try_recv().is_ok() {}
    let (mut to_event, mut to_reply) = (Vec::new(), Vec::new());
    for i in 0..200 {
        let dx = if i % 2 == 0 { 0.01 } else { -0.01 };
        let t0 = Instant::now();
        let v = post(
            &a,
            &format!("{}/api/v1/stage/jog", s.url),
            json!({"dx_mm": dx, "dy_mm": 0.0}),
        );
        to_reply.push(t0.elapsed().as_secs_f64() * 1e6);
        let x = v["position"]["x_mm"].as_f64().expect("a jog's answer");
        loop {
            let (ex, at) = rx
                .recv_timeout(Duration::from_secs(5))
                .expect("a position event");
            if (ex - x).abs() < 1e-9 {
                to_event.push((at - t0).as_secs_f64() * 1e6);
                break;
            }
        }
        // Past the 10 Hz thinning, so that every jog's position is sent.
        std::thread::sleep(Duration::from_millis(110));
    }
    // Per jog: the event's arrival less the jog's own answer (negative: the event came first).
    let mut lead: Vec<f64> = to_event.iter().zip(&to_reply).map(|(e, r)| e - r).collect();
    let lead_med = percentile(&mut lead, 0.5);
    let lead_p99 = percentile(&mut lead, 0.99);
    let ev_med = percentile(&mut to_event, 0.5);
    let ev_p99 = percentile(&mut to_event, 0.99);
    let re_med = percentile(&mut to_reply, 0.5);

    // Queue reads per second, 100 items waiting, beside the HTTP floor (an unknown route).
    let queue_100 = || {
        let items: Vec<Value> = (0..100)
            .map(|_| json!({"task": {"kind": "home"}}))
            .collect();
        post(
            &a,
            &format!("{}/api/v1/queue/items", s.url),
            json!({ "items": items }),
        );
    };
    queue_100();
    let rate = |path: &str| {
        let stop = Arc::new(AtomicBool::new(false));
        let workers: Vec<_> = (0..2)
            .map(|_| {
                let (u, stop) = (format!("{}{path}", s.url), stop.clone());
                std::thread::spawn(move || {
                    let a = agent();
                    let mut n = 0u64;
                    while !stop.load(Ordering::Relaxed) {
                        let mut r = a.get(&u).call().unwrap();
                        let _ = r.body_mut().read_to_vec().unwrap();
                        n += 1;
                    }
                    n
                })
            })
            .collect();
        let t0 = Instant::now();
        std::thread::sleep(Duration::from_secs(3));
        stop.store(true, Ordering::Relaxed);
        let n: u64 = workers.into_iter().map(|w| w.join().unwrap()).sum();
        n as f64 / t0.elapsed().as_secs_f64()
    };
    let floor = rate("/api/v1/nothing-here");
    let reads = rate("/api/v1/queue");

    // Memory: idle, then 100 event clients following 1000 events.
    drop(rx);
    std::thread::sleep(Duration::from_millis(300));
    let idle = rss_kib(s.child.id());
    let clients: Vec<_> = (0..100).map(|_| follow_positions(&s.url)).collect();
    for _ in 0..10 {
        queue_100();
        post(&a, &format!("{}/api/v1/queue/clear", s.url), json!({}));
    }
    std::thread::sleep(Duration::from_millis(500));
    let busy = rss_kib(s.child.id());
    drop(clients);

    println!("rig serve, measured in one run (the simulator, 2 cores):");
    println!(
        "  status round trip over the pty (the floor): median {raw_med:.0} µs, p99 {raw_p99:.0} µs"
    );
    println!(
        "  jog request -> its answer: median {re_med:.0} µs; -> an event client sees the new position: median {ev_med:.0} µs ({:.1} × the round trip), p99 {ev_p99:.0} µs ({:.1} ×)",
        ev_med / raw_med,
        ev_p99 / raw_med
    );
    println!(
        "  per jog, the event's arrival less the jog's HTTP answer: median {lead_med:+.0} µs, p99 {lead_p99:+.0} µs ({:+.1} × the round trip at p99): the event comes with the answer",
        lead_p99 / raw_med
    );
    println!(
        "  queue reads (100 waiting): {reads:.0}/s = {:.2} × the HTTP floor ({floor:.0}/s to an unknown route)",
        reads / floor
    );
    println!(
        "  memory: {idle} KiB idle, {busy} KiB with 100 event clients after 1000 events: {:.2} ×, {:.0} KiB a client",
        busy as f64 / idle as f64,
        (busy as f64 - idle as f64) / 100.0
    );
}
