//! A status round trip through the stage driver (encode, write, the simulated controller's
//! turn, read, decode, match by sequence number) against a raw echo round trip of the same
//! sizes over the same kind of pseudo-terminal, in one run. Reported as a ratio: what the
//! protocol and driver cost on top of the line itself.

mod common;

use criterion::{criterion_group, Criterion};
use rig::stage::{self, Dialect, DriverOptions, Port};
use rig_sim::pty::Pty;
use rig_sim::{EmbeddedSim, SimConfig};
use std::hint::black_box;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

/// A native `Status` request is 7 bytes on the wire and its reply 17: the echo peer answers
/// every 7 bytes with 17.
const REQ: usize = 7;
const REPLY: usize = 17;

fn echo_peer(stop: Arc<AtomicBool>) -> (std::thread::JoinHandle<()>, std::path::PathBuf) {
    let pty = Pty::open(None).unwrap();
    let path = pty.slave_path.clone();
    let h = std::thread::spawn(move || {
        let mut buf = [0u8; 256];
        let mut pending = 0usize;
        while !stop.load(Ordering::Relaxed) {
            if pty.wait_readable(1) {
                pending += pty.read(&mut buf).unwrap();
                while pending >= REQ {
                    pending -= REQ;
                    let mut off = 0;
                    while off < REPLY {
                        off += pty.write(&[0x55; REPLY][off..]).unwrap();
                    }
                }
            }
        }
    });
    (h, path)
}

fn roundtrips(c: &mut Criterion) {
    let mut g = c.benchmark_group("status_roundtrip");
    g.measurement_time(Duration::from_secs(4));

    let stop = Arc::new(AtomicBool::new(false));
    let (h, path) = echo_peer(stop.clone());
    let mut port = Port::open(&path, 115_200, &Default::default()).unwrap();
    let mut buf = Vec::with_capacity(64);
    g.bench_function("raw_echo_pty", |b| {
        b.iter(|| {
            port.write_all(&[0x11; REQ]).unwrap();
            buf.clear();
            let deadline = Instant::now() + Duration::from_secs(1);
            while buf.len() < REPLY {
                port.read_until(deadline, &mut buf).unwrap();
            }
            black_box(&buf);
        })
    });
    drop(port);
    stop.store(true, Ordering::Relaxed);
    h.join().unwrap();

    for (name, dialect, sim_dialect) in [
        ("native_driver", Dialect::Native, rig_sim::Dialect::Native),
        ("grbl_driver", Dialect::Grbl, rig_sim::Dialect::Grbl),
    ] {
        let sim = EmbeddedSim::start(SimConfig {
            dialect: sim_dialect,
            time_scale: 0.0,
            start_homed: true,
            ..Default::default()
        })
        .unwrap();
        let mut st = stage::open(
            &sim.port,
            dialect,
            DriverOptions::default(),
            &Default::default(),
        )
        .unwrap();
        g.bench_function(name, |b| b.iter(|| black_box(st.status().unwrap())));
        drop(st);
        sim.shutdown().unwrap();
    }
    g.finish();
}

criterion_group!(benches, roundtrips);

fn main() {
    benches();
    Criterion::default().configure_from_args().final_summary();
    if let Some(base) = common::mean_ns("status_roundtrip", "raw_echo_pty") {
        println!("\nstatus round trip, ratio to a raw echo of the same sizes over a pty:");
        println!("  (a GRBL status is two reports that must agree: its reports carry no checksum)");
        for b in ["native_driver", "grbl_driver"] {
            if let Some(t) = common::mean_ns("status_roundtrip", b) {
                println!(
                    "  {b:<14} {:>9.1} µs  = {:>5.2} × raw echo ({:.1} µs)",
                    t / 1000.0,
                    t / base,
                    base / 1000.0
                );
            }
        }
    }
}
