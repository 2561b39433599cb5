//! A stop that leaves a GRBL board usable, end to end: the real `rig` binary against `rig sim
//! --dialect grbl` on its pseudo-terminal, a separate process that outlives each `rig` run as a
//! board does. The emulator blocks as GRBL 1.1 does (a pending `G4` holds the parser; a complete
//! feed hold suspends it until `~` or a reset; a homing cycle ignores `!`), so a stop that only
//! holds would leave a board that the next command cannot talk to. Every property is read from
//! the simulator's truth (where the carriage is, whether the controller kept its reference,
//! its state), never from what the rig said; durations are only generous caps, so that a hang
//! fails instead of blocking.

use crate::common::*;
use serde_json::Value;
use std::io::{Read, Write};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

/// Longest a `rig` may take to end after Ctrl-C before the test calls it a hang.
const AFTER_CTRL_C: Duration = Duration::from_secs(20);

/// `rig stage --stage PORT --dialect grbl --json ARGS`.
fn rig_stage(sim: &SimProcess, args: &[&str]) -> Command {
    let mut c = rig();
    c.arg("stage")
        .arg("--stage")
        .arg(&sim.port)
        .args(["--dialect", "grbl", "--json"])
        .args(args);
    c
}

/// Starts `cmd`, sends it SIGINT once `ready` holds (or after `at_least`, whichever is later),
/// and waits for it within [`AFTER_CTRL_C`]: exit code, JSON and standard error, and how long
/// it took to end after the signal.
fn interrupt(
    mut cmd: Command,
    sim: &SimProcess,
    ready: impl Fn(&Value) -> bool,
    at_least: Duration,
) -> (i32, Value, String, Duration) {
    let mut child = cmd
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let t0 = Instant::now();
    let give_up = t0 + Duration::from_secs(30);
    while !(t0.elapsed() >= at_least && ready(&sim.truth())) {
        assert!(Instant::now() < give_up, "the motion never started");
        assert!(child.try_wait().unwrap().is_none(), "ended before Ctrl-C");
        std::thread::sleep(Duration::from_millis(50));
    }
    // SAFETY: a signal to our own child.
    unsafe { libc::kill(child.id() as i32, libc::SIGINT) };
    let signalled = Instant::now();
    let status = loop {
        if let Some(s) = child.try_wait().unwrap() {
            break s;
        }
        if signalled.elapsed() > AFTER_CTRL_C {
            let _ = child.kill();
            panic!("rig still running {AFTER_CTRL_C:?} after Ctrl-C");
        }
        std::thread::sleep(Duration::from_millis(10));
    };
    let took = signalled.elapsed();
    let (mut out, mut err) = (String::new(), String::new());
    child
        .stdout
        .take()
        .unwrap()
        .read_to_string(&mut out)
        .unwrap();
    child
        .stderr
        .take()
        .unwrap()
        .read_to_string(&mut err)
        .unwrap();
    eprintln!("ended {took:?} after Ctrl-C: {}", err.trim());
    let json = serde_json::from_str(out.trim()).unwrap_or(Value::Null);
    (status.code().unwrap_or(-1), json, err, took)
}

/// The truth once the simulated stage has come to rest.
fn rest(sim: &SimProcess) -> Value {
    let deadline = Instant::now() + Duration::from_secs(10);
    loop {
        let t = sim.truth();
        if t["busy"] == false {
            return t;
        }
        assert!(
            Instant::now() < deadline,
            "the stage never came to rest: {t}"
        );
        std::thread::sleep(Duration::from_millis(50));
    }
}

fn xy(v: &Value) -> (f64, f64) {
    (v["x_mm"].as_f64().unwrap(), v["y_mm"].as_f64().unwrap())
}

/// The next `rig stage status` reads the board, and what GRBL reports is where the carriage
/// really is (within the 3 µm backlash; a lost or shifted reference would be millimetres off),
/// in the controller's own frame of the truth.
fn status_matches_truth(sim: &SimProcess, truth: &Value, what: &str) -> Value {
    let (code, st, err) = sim.stage("grbl", &["status"]);
    assert_eq!(code, 0, "{what}: the next status failed: {err}");
    let (tx, ty) = carriage_um(truth);
    let (x, y) = xy(&st);
    assert!(
        (x * 1000.0 - tx).abs() < 5.0 && (y * 1000.0 - ty).abs() < 5.0,
        "{what}: status says {x}, {y} mm, the carriage is at {tx}, {ty} µm"
    );
    st
}

/// Ctrl-C during `rig stage move`: the rig ends within seconds, the board is left Idle (not in
/// Hold, no sync pending) with its reference kept, and the next commands work.
fn ctrl_c_during_a_move_leaves_a_board_that_takes_the_next_command() {
    let sim = SimProcess::start_scaled("grbl", "1", &["--start-homed", "--seed", "5"]);
    let t0 = sim.truth();
    let (x0, y0) = carriage_um(&t0);
    // Far from where it powered up (0.2 to 0.8 of the travel): a move of over 110 mm, about
    // 6 s at 20 mm/s.
    let far = |v: f64| if v < 125_000.0 { "240" } else { "10" };
    let (fx, fy) = (far(x0), far(y0));
    let (code, j, err, took) = interrupt(
        rig_stage(&sim, &["move", fx, fy]),
        &sim,
        |t| t["busy"] == true,
        Duration::from_millis(1500),
    );
    assert_eq!(code, 130, "{err}");
    assert_eq!(j["error"]["kind"], "cancelled", "{j}");
    assert_eq!(j["stopped"]["action"], "decelerated", "{j}");
    let t = rest(&sim);
    assert_eq!(t["controller_state"], "Idle", "left in Hold or Alarm: {t}");
    assert_eq!(t["homed"], true, "the board lost its reference: {t}");
    let (x, y) = carriage_um(&t);
    assert!(
        (x - x0).abs() > 5_000.0 || (y - y0).abs() > 5_000.0,
        "it had moved: from {x0},{y0} to {x},{y} µm"
    );
    // The rig's report of where it stopped is where the carriage is.
    let (sx, sy) = xy(&j["stopped"]);
    assert!((sx * 1000.0 - x).abs() < 5.0 && (sy * 1000.0 - y).abs() < 5.0);
    let st = status_matches_truth(&sim, &t, "after Ctrl-C mid-move");
    assert_eq!(
        (st["state"].as_str(), st["homed"].as_bool()),
        (Some("idle"), Some(true))
    );
    // Usable: a move lands where the truth says.
    let (code, _, err) = sim.stage("grbl", &["move", "100", "120"]);
    assert_eq!(code, 0, "{err}");
    let (x, y) = carriage_um(&rest(&sim));
    assert!(
        (x - 100_000.0).abs() < 1.5 && (y - 120_000.0).abs() < 1.5,
        "{x} {y}"
    );
    eprintln!("move: ended {took:?} after Ctrl-C");
}

/// Ctrl-C during `rig stage home`: GRBL ignores a feed hold in a homing cycle, so the rig ends
/// it with a reset (ALARM:6: not homed) and ends within seconds; the next status reads the
/// board, in Alarm, and says it must be homed.
fn ctrl_c_during_homing_ends_the_cycle_and_leaves_a_board_that_answers() {
    let sim = SimProcess::start_scaled("grbl", "1", &["--seed", "5"]);
    let (code, j, err, took) = interrupt(
        rig_stage(&sim, &["home"]),
        &sim,
        |t| t["busy"] == true,
        Duration::from_millis(1500),
    );
    assert_eq!(code, 130, "{err}");
    assert_eq!(j["stopped"]["action"], "homing_aborted", "{j}");
    let t = rest(&sim);
    assert_eq!(t["controller_state"], "Alarm", "{t}");
    assert_eq!(
        t["homed"], false,
        "a reset during the cycle sets no reference"
    );
    let (code, st, err) = sim.stage("grbl", &["status"]);
    assert_eq!(code, 0, "the next status failed: {err}");
    assert_eq!(st["controller_state"], "Alarm", "{st}");
    assert_eq!(st["homed"], false, "{st}");
    let out = rig()
        .arg("stage")
        .arg("--stage")
        .arg(&sim.port)
        .args(["--dialect", "grbl", "status"])
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success() && text.contains("Alarm") && text.contains("rig stage home"),
        "{text}"
    );
    eprintln!("homing: ended {took:?} after Ctrl-C");
}

/// Another program streamed a move and its sync point (`G4 P0.01`) and left: the board either
/// in `Hold:0` (it sent `!`), its `G4` and a further line pending, or still running. A status
/// refuses it by name; `rig stage stop` sees the state, stops and resets it keeping the
/// position, and the board then takes commands.
fn rig_stage_stop_recovers_a_board_another_program_left_held_or_running() {
    // The two boards side by side, each its own simulator (a panic in either fails the test).
    std::thread::scope(|sc| {
        for held in [true, false] {
            sc.spawn(move || left_held_or_running(held));
        }
    });
}

/// A board another program left held (`held`) or running: `rig stage status` refuses it,
/// `rig stage stop` brings it to Idle, homed, where it was, ready for the next move.
fn left_held_or_running(held: bool) {
    let what = if held { "held" } else { "running" };
    let sim = SimProcess::start_scaled("grbl", "1", &["--start-homed", "--seed", "5"]);
    {
        let mut f = open_nonblocking(&sim.port);
        f.write_all(b"G90 G21 G53 G1 X-240 Y-240 F600\nG4 P0.01\n\n")
            .unwrap();
        std::thread::sleep(Duration::from_millis(700));
        if held {
            f.write_all(b"!").unwrap();
        }
        let deadline = Instant::now() + Duration::from_secs(5);
        let want = if held { "Hold:0" } else { "Run" };
        while sim.truth()["controller_state"] != want {
            assert!(Instant::now() < deadline, "{what}: {}", sim.truth());
            std::thread::sleep(Duration::from_millis(20));
        }
    } // the other program is gone
    let before = sim.truth();
    let (code, j, err) = sim.stage("grbl", &["status"]);
    assert_eq!(code, 5, "{what}: {err}");
    assert_eq!(j["error"]["kind"], "not_ready", "{what}: {j}");
    assert!(err.contains("rig stage stop"), "{what}: {err}");
    if held {
        assert_eq!(
            sim.truth()["controller_state"],
            "Hold:0",
            "status changed nothing"
        );
    }
    let t = Instant::now();
    let (code, j, err) = sim.stage("grbl", &["stop"]);
    let took = t.elapsed();
    assert_eq!(code, 0, "{what}: {err}");
    let want = if held { "released" } else { "decelerated" };
    assert_eq!(j["action"], want, "{what}: {j}");
    let after = rest(&sim);
    assert_eq!(after["controller_state"], "Idle", "{what}: {after}");
    assert_eq!(after["homed"], true, "{what}: reference lost: {after}");
    if held {
        // (The truth drifts by a few µm an hour.)
        let (a, b) = (carriage_um(&after), carriage_um(&before));
        assert!(
            (a.0 - b.0).abs() < 0.05 && (a.1 - b.1).abs() < 0.05,
            "{what}: a held board does not move: {b:?} → {a:?}"
        );
    }
    let (sx, sy) = xy(&j);
    let (tx, ty) = carriage_um(&after);
    assert!((sx * 1000.0 - tx).abs() < 5.0 && (sy * 1000.0 - ty).abs() < 5.0);
    status_matches_truth(&sim, &after, what);
    let (code, _, err) = sim.stage("grbl", &["move", "100", "120"]);
    assert_eq!(code, 0, "{what}: {err}");
    eprintln!("{what}: `rig stage stop` took {took:?}");
}

/// A fault mid-move (a limit switch: GRBL's hard-limit alarm, critical, which answers nothing
/// until a reset): the rig reports the fault, resets the board on its way out, and the next
/// status reads it, in Alarm and not homed (a hard limit loses the position).
fn a_fault_mid_move_leaves_a_board_the_next_status_reads() {
    let sim = SimProcess::start_scaled("grbl", "0", &["--start-homed", "--faults", "limit=1"]);
    let (code, j, err) = sim.stage("grbl", &["move", "60", "40"]);
    assert_eq!(code, 5, "{err}");
    assert_eq!(j["error"]["kind"], "fault", "{j}");
    assert!(err.contains("ALARM:1"), "{err}");
    let t = rest(&sim);
    assert_eq!(t["controller_state"], "Alarm", "{t}");
    let (code, st, err) = sim.stage("grbl", &["status"]);
    assert_eq!(code, 0, "the next status failed: {err}");
    assert_eq!(
        (st["controller_state"].as_str(), st["homed"].as_bool()),
        (Some("Alarm"), Some(false))
    );
}

/// Another program started a homing cycle and left: GRBL says nothing during the cycle (not
/// even to `?`), and ignores a feed hold. A status reports the silence and names `rig stage
/// stop`, sending no reset; `rig stage stop` ends the cycle with a reset (ALARM:6), and the board
/// then answers, in Alarm, not homed.
fn rig_stage_stop_ends_a_homing_cycle_another_program_left() {
    let sim = SimProcess::start_scaled("grbl", "1", &["--seed", "5"]);
    {
        let mut f = open_nonblocking(&sim.port);
        f.write_all(b"$H\n").unwrap();
        let deadline = Instant::now() + Duration::from_secs(5);
        while sim.truth()["controller_state"] != "Home" {
            assert!(Instant::now() < deadline, "{}", sim.truth());
            std::thread::sleep(Duration::from_millis(20));
        }
    }
    let (code, _, err) = sim.stage("grbl", &["status"]);
    assert_ne!(code, 0, "a homing board cannot answer");
    assert!(err.contains("rig stage stop"), "{err}");
    assert_eq!(
        sim.truth()["controller_state"],
        "Home",
        "status sent no reset"
    );
    let (code, j, err) = sim.stage("grbl", &["stop"]);
    assert_eq!(code, 0, "{err}");
    assert_eq!(j["action"], "homing_aborted", "{j}");
    let t = rest(&sim);
    assert_eq!(
        (t["controller_state"].as_str(), t["homed"].as_bool()),
        (Some("Alarm"), Some(false))
    );
    let (code, st, err) = sim.stage("grbl", &["status"]);
    assert_eq!(code, 0, "{err}");
    assert_eq!(st["controller_state"], "Alarm", "{st}");
}

crate::waiting_tests!(
    ctrl_c_during_a_move_leaves_a_board_that_takes_the_next_command,
    ctrl_c_during_homing_ends_the_cycle_and_leaves_a_board_that_answers,
    rig_stage_stop_recovers_a_board_another_program_left_held_or_running,
    a_fault_mid_move_leaves_a_board_the_next_status_reads,
    rig_stage_stop_ends_a_homing_cycle_another_program_left,
);
