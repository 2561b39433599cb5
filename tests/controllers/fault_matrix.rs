//! The fault matrix: every injected fault kind × both dialects × several seeded trials. Each
//! operation must end within its timeout with either a position that the simulator's truth
//! confirms or a typed error; after an error the stages must be stopped; no motion command
//! outside the soft limits may ever leave the host (checked on the wire log), and the carriage
//! must never leave them (checked on the truth's excursion).
//!
//! Runs in-process (the same simulator and driver code as the binaries) over real
//! pseudo-terminals, several trials at a time. The matrix is printed with `--nocapture` and
//! written to `target/tmp/fault-matrix.md`.

use firmware_protocol::{Decoder, Message};
use rig::coords::CarriageUm;
use rig::stage::{self, Dialect, DriverOptions, LinkOptions, SoftLimits, StageError};
use rig_sim::{EmbeddedSim, FaultSpec, SimConfig};
use serde_json::Value;
use std::collections::BTreeMap;
use std::path::Path;
use std::sync::Mutex;
use std::time::{Duration, Instant};

const FAULTS: [(&str, &str); 9] = [
    ("drop", "drop=0.004"),
    ("corrupt", "corrupt=0.004"),
    ("dup", "dup=0.004"),
    ("delay", "delay=0.01:150"),
    ("stall", "stall=0.5"),
    ("limit", "limit=0.5"),
    ("reset", "reset=0.5"),
    ("estop", "estop=0.5"),
    ("disconnect", "disconnect=0.3"),
];
const TRIALS: u64 = 6;
const MOVES: usize = 4;
/// Largest accepted difference between an accepted position and the truth, µm.
const TRUTH_TOL_UM: f64 = 1.5;
/// No single operation may take longer than this (all timeouts are well inside it).
const OP_BOUND: Duration = Duration::from_secs(30);

#[derive(Default, Debug)]
struct Cell {
    trials: u64,
    ops: u64,
    verified: u64,
    errors: BTreeMap<&'static str, u64>,
    examples: BTreeMap<&'static str, String>,
    injected: u64,
    max_op: Duration,
    violations: Vec<String>,
}

fn read_truth(p: &Path) -> Value {
    let deadline = Instant::now() + Duration::from_secs(2);
    loop {
        if let Some(v) = std::fs::read_to_string(p)
            .ok()
            .and_then(|s| serde_json::from_str::<Value>(&s).ok())
        {
            if v["busy"] == false || Instant::now() > deadline {
                return v;
            }
        }
        std::thread::sleep(Duration::from_millis(5));
    }
}

fn truth_xy(v: &Value) -> CarriageUm {
    CarriageUm::new(
        v["carriage_um"][0].as_f64().unwrap(),
        v["carriage_um"][1].as_f64().unwrap(),
    )
}

/// Motion targets the host sent, from the wire log, in carriage µm.
fn sent_targets(
    log: &Path,
    dialect: Dialect,
    travel: CarriageUm,
) -> Vec<(String, Option<CarriageUm>)> {
    let Ok(text) = std::fs::read_to_string(log) else {
        return vec![];
    };
    let mut tx = Vec::new();
    for line in text.lines() {
        let v: Value = serde_json::from_str(line).unwrap();
        if v["dir"] == "tx" {
            let hex = v["hex"].as_str().unwrap();
            tx.extend(
                (0..hex.len())
                    .step_by(2)
                    .map(|i| u8::from_str_radix(&hex[i..i + 2], 16).unwrap()),
            );
        }
    }
    let mut out = Vec::new();
    match dialect {
        Dialect::Native => {
            let mut d = Decoder::new();
            for b in tx {
                if let Some(Ok(f)) = d.push(b) {
                    match f.msg {
                        Message::MoveAbs { x_nm, y_nm, .. } => out.push((
                            "MoveAbs".into(),
                            Some(CarriageUm::new(x_nm as f64 / 1000.0, y_nm as f64 / 1000.0)),
                        )),
                        Message::MoveRel { .. } => out.push(("MoveRel".into(), None)),
                        Message::Jog { .. } => out.push(("Jog".into(), None)),
                        _ => {}
                    }
                }
            }
        }
        Dialect::Grbl => {
            for line in String::from_utf8_lossy(&tx).split('\n') {
                let l = line.trim_matches(|c: char| {
                    c == '?' || c == '!' || c == '\u{18}' || c.is_whitespace()
                });
                if l.contains("G1") || l.contains("G0 ") || l.starts_with("$J") {
                    let word = |c: char| {
                        l.split_whitespace()
                            .find_map(|w| w.strip_prefix(c))
                            .and_then(|v| v.parse::<f64>().ok())
                    };
                    let p = match (word('X'), word('Y')) {
                        (Some(x), Some(y)) if l.contains("G90") => Some(CarriageUm::new(
                            x * 1000.0 + travel.x,
                            y * 1000.0 + travel.y,
                        )),
                        _ => None,
                    };
                    out.push((l.to_string(), p));
                }
            }
        }
    }
    out
}

fn run_trial(kind: &str, spec: &str, dialect: Dialect, seed: u64, cell: &mut Cell) {
    let dir = tempfile::tempdir().unwrap();
    let truth = dir.path().join("truth.json");
    let wire = dir.path().join("wire.jsonl");
    let sim = EmbeddedSim::start(SimConfig {
        dialect: match dialect {
            Dialect::Native => rig_sim::Dialect::Native,
            Dialect::Grbl => rig_sim::Dialect::Grbl,
        },
        time_scale: 0.0,
        seed,
        faults: FaultSpec::parse(spec).unwrap(),
        truth: Some(truth.clone()),
        stage_link: None,
        ..Default::default()
    })
    .unwrap();
    cell.trials += 1;
    let tag = format!("{kind}/{dialect:?}/seed {seed}");
    let mut rng = seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1;
    let mut next = move || {
        rng ^= rng << 13;
        rng ^= rng >> 7;
        rng ^= rng << 17;
        (rng >> 11) as f64 / (1u64 << 53) as f64
    };

    let record = |cell: &mut Cell, t0: Instant, r: &Result<(), StageError>| {
        let dt = t0.elapsed();
        cell.ops += 1;
        cell.max_op = cell.max_op.max(dt);
        if dt > OP_BOUND {
            cell.violations
                .push(format!("{tag}: an operation took {dt:?}"));
        }
        match r {
            Ok(()) => cell.verified += 1,
            Err(e) => {
                *cell.errors.entry(e.kind()).or_default() += 1;
                cell.examples
                    .entry(e.kind())
                    .or_insert_with(|| e.to_string());
            }
        }
    };

    // Opening may itself fail on a noisy line: a typed error is a valid outcome.
    let t0 = Instant::now();
    let opened = (0..3).find_map(|_| {
        stage::open(
            &sim.port,
            dialect,
            DriverOptions::default(),
            &LinkOptions {
                wire_log: Some(wire.clone()),
                ..Default::default()
            },
        )
        .ok()
    });
    let Some(mut st) = opened else {
        record(
            cell,
            t0,
            &Err(StageError::Timeout {
                what: "open".into(),
                after: t0.elapsed(),
            }),
        );
        finish(sim, &truth, &wire, dialect, None, &tag, cell);
        return;
    };
    let limits = st.limits();
    let travel = st.info().travel;
    let mut homed = false;
    let mut dead = false;
    for i in 0..MOVES + 1 {
        if dead {
            break;
        }
        if !homed {
            let t0 = Instant::now();
            let r = st.home().map(|_| ());
            record(cell, t0, &r);
            match r {
                Ok(()) => homed = true,
                Err(StageError::Disconnected(_)) => dead = true,
                Err(_) => {}
            }
            continue;
        }
        let target = CarriageUm::new(
            limits.min.x + (limits.max.x - limits.min.x) * next(),
            limits.min.y + (limits.max.y - limits.min.y) * next(),
        );
        let t0 = Instant::now();
        let r = st.move_to(target);
        match &r {
            Ok(p) => {
                let t = truth_xy(&read_truth(&truth));
                let err = (*p - t).norm();
                if err > TRUTH_TOL_UM || (*p - target).norm() > 3.0 {
                    cell.violations.push(format!(
                        "{tag}: move {i} accepted {p} but truth is {t} ({err:.2} µm)"
                    ));
                }
            }
            Err(StageError::Disconnected(_)) => dead = true,
            Err(e) => {
                homed = false;
                let tv = read_truth(&truth);
                if tv["busy"] != false && tv["disconnected"] != true {
                    cell.violations
                        .push(format!("{tag}: after `{e}` the stage is still moving"));
                }
            }
        }
        record(cell, t0, &r.map(|_| ()));
    }
    drop(st);
    finish(
        sim,
        &truth,
        &wire,
        dialect,
        Some((limits, travel)),
        &tag,
        cell,
    );
}

fn finish(
    sim: EmbeddedSim,
    truth: &Path,
    wire: &Path,
    dialect: Dialect,
    lt: Option<(SoftLimits, CarriageUm)>,
    tag: &str,
    cell: &mut Cell,
) {
    sim.shutdown().unwrap();
    let t = read_truth(truth);
    cell.injected += t["injected_faults"]
        .as_array()
        .map_or(0, |a| a.len() as u64);
    let lf = &t["line_faults"];
    cell.injected += ["dropped", "corrupted", "duplicated", "delayed"]
        .iter()
        .map(|k| lf[k].as_u64().unwrap_or(0))
        .sum::<u64>();
    let Some((limits, travel)) = lt else { return };
    let margin = 10.0; // noise, backlash and drift around a limit
    for (cmd, p) in sent_targets(wire, dialect, travel) {
        if let Some(p) = p {
            if limits.check(p).is_err() {
                cell.violations.push(format!(
                    "{tag}: host sent {cmd} to {p}, outside the soft limits"
                ));
            }
        }
    }
    // Where the carriage went. GRBL has no checksum: a corrupted line can move it anywhere
    // GRBL's own limits allow (its full travel), which the position check then reports.
    let (lo, hi) = if dialect == Dialect::Grbl {
        (CarriageUm::default(), travel)
    } else {
        (limits.min, limits.max)
    };
    if let Some(ex) = t["excursion_um"].as_array() {
        for k in 0..2 {
            let (a, b) = (ex[k][0].as_f64().unwrap(), ex[k][1].as_f64().unwrap());
            if a < lo.axis(k) - margin || b > hi.axis(k) + margin {
                cell.violations.push(format!(
                    "{tag}: carriage axis {k} went to {a:.1}..{b:.1} µm"
                ));
            }
        }
    }
}

fn fault_matrix() {
    let cells: Mutex<BTreeMap<(usize, &str), Cell>> = Mutex::new(BTreeMap::new());
    let jobs: Vec<(usize, &str, &str, Dialect, u64)> = FAULTS
        .iter()
        .enumerate()
        .flat_map(|(i, (k, s))| {
            [Dialect::Native, Dialect::Grbl]
                .into_iter()
                .flat_map(move |d| (0..TRIALS).map(move |t| (i, *k, *s, d, 100 + t)))
        })
        .collect();
    let queue = Mutex::new(jobs.into_iter());
    std::thread::scope(|sc| {
        for _ in 0..54 {
            sc.spawn(|| loop {
                let Some((i, k, s, d, seed)) = queue.lock().unwrap().next() else {
                    break;
                };
                let mut c = Cell::default();
                run_trial(k, s, d, seed, &mut c);
                let mut all = cells.lock().unwrap();
                let e = all
                    .entry((
                        i * 2 + (d == Dialect::Grbl) as usize,
                        if d == Dialect::Grbl { "grbl" } else { "native" },
                    ))
                    .or_default();
                e.trials += c.trials;
                e.ops += c.ops;
                e.verified += c.verified;
                e.injected += c.injected;
                e.max_op = e.max_op.max(c.max_op);
                for (k, n) in c.errors {
                    *e.errors.entry(k).or_default() += n;
                }
                for (k, m) in c.examples {
                    e.examples.entry(k).or_insert(m);
                }
                e.violations.extend(c.violations);
            });
        }
    });
    let cells = cells.into_inner().unwrap();
    let mut table = String::from("| fault | dialect | trials | operations | verified | typed errors | faults injected | slowest op |\n|---|---|---|---|---|---|---|---|\n");
    let mut violations = Vec::new();
    let mut total_errors = 0;
    for ((i, d), c) in &cells {
        let errs: Vec<String> = c.errors.iter().map(|(k, n)| format!("{k} {n}")).collect();
        total_errors += c.errors.values().sum::<u64>();
        table += &format!(
            "| {} | {d} | {} | {} | {} | {} | {} | {:.2} s |\n",
            FAULTS[i / 2].0,
            c.trials,
            c.ops,
            c.verified,
            if errs.is_empty() {
                "none".into()
            } else {
                errs.join(", ")
            },
            c.injected,
            c.max_op.as_secs_f64()
        );
        violations.extend(c.violations.iter().cloned());
        // Every fault kind must actually have been injected, or the row proves nothing.
        assert!(
            c.injected > 0,
            "{} / {d}: no fault was injected",
            FAULTS[i / 2].0
        );
    }
    println!("{table}");
    for ((i, d), c) in &cells {
        for (k, m) in &c.examples {
            println!("{} / {d} / {k}: {m}", FAULTS[i / 2].0);
        }
    }
    let out = Path::new(env!("CARGO_TARGET_TMPDIR")).join("fault-matrix.md");
    std::fs::write(&out, &table).unwrap();
    assert!(
        total_errors > 0,
        "faults were injected but nothing ever failed: the checks are blind"
    );
    assert!(
        violations.is_empty(),
        "fault matrix violations:\n{}\n{table}",
        violations.join("\n")
    );
}

crate::waiting_tests!(fault_matrix,);
