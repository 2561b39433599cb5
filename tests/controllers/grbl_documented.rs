//! The rig against GRBL 1.1 as its interface documents describe it, not as an eager emulator
//! would: silent during homing, late reports, feed holds that do not act, WPos and inch
//! reports, homing toward either switch, alarms at connect, absurd settings. The emulator is
//! checked byte by byte against the documented behaviour first; the scripted fake
//! (`common/fake_grbl.rs`) plays the boards that misbehave. Truth comes from the simulated
//! stage itself (where the carriage really is), not from what the rig was told.

use crate::common;

use crate::fake_grbl::{FakeGrbl, Script};
use rig::coords::CarriageUm;
use rig::stage::grbl::GrblController;
use rig::stage::{
    Controller, Driver, DriverOptions, FaultKind, Stage, StageError, StageState, StopAction,
    TimeoutPolicy,
};
use rig_sim::{Dialect, EmbeddedSim, SimConfig};
use std::io::{Read, Write};
use std::time::{Duration, Instant};

fn grbl(time_scale: f64, start_homed: bool, settings: &[(u32, f64)]) -> EmbeddedSim {
    EmbeddedSim::start(SimConfig {
        dialect: Dialect::Grbl,
        time_scale,
        start_homed,
        grbl_settings: settings.to_vec(),
        ..Default::default()
    })
    .unwrap()
}

/// Where the simulated carriage really is, mm.
fn truth_mm(sim: &EmbeddedSim) -> (f64, f64) {
    let s = sim.world.stage();
    (s.carriage_true(0) / 1000.0, s.carriage_true(1) / 1000.0)
}

fn driver(sim_port: &std::path::Path) -> Driver<GrblController> {
    Driver::new(
        GrblController::open(sim_port, &Default::default()).unwrap(),
        DriverOptions::default(),
    )
}

/// Collects what the board prints for `dur` after sending `bytes`.
fn raw_exchange(f: &mut std::fs::File, bytes: &[u8], dur: Duration) -> String {
    f.write_all(bytes).unwrap();
    let end = Instant::now() + dur;
    let mut out = Vec::new();
    let mut buf = [0u8; 1024];
    while Instant::now() < end {
        match f.read(&mut buf) {
            Ok(n) if n > 0 => out.extend_from_slice(&buf[..n]),
            _ => std::thread::sleep(Duration::from_millis(2)),
        }
    }
    String::from_utf8_lossy(&out).to_string()
}

fn emulator_is_silent_while_homing_and_answers_once_before_its_ok() {
    // Half real time: seed 1's seek (168 mm at 10 mm/s) takes 8 s, so the questions below all
    // fall inside the cycle.
    let sim = grbl(0.5, false, &[]);
    let mut f = common::open_nonblocking(&sim.port);
    raw_exchange(&mut f, b"", Duration::from_millis(100));
    assert_eq!(
        raw_exchange(&mut f, b"$H\n", Duration::from_millis(100)),
        ""
    );
    let during = raw_exchange(&mut f, b"?", Duration::from_millis(300));
    assert_eq!(during, "", "GRBL says nothing during a homing cycle");
    let during = raw_exchange(&mut f, b"??", Duration::from_millis(300));
    assert_eq!(during, "");
    // The cycle ends: one late report for the three coalesced questions, then the `ok`.
    let deadline = Instant::now() + Duration::from_secs(30);
    let mut out = String::new();
    while !out.contains("ok\r\n") && Instant::now() < deadline {
        out += &raw_exchange(&mut f, b"", Duration::from_millis(100));
    }
    assert!(out.starts_with("<Home|MPos:"), "{out:?}");
    assert_eq!(out.matches('<').count(), 1, "{out:?}");
    assert!(out.ends_with(">\r\nok\r\n"), "{out:?}");
    // Afterwards `?` is answered at once again, as Idle at minus the pull-off.
    let now = raw_exchange(&mut f, b"?", Duration::from_millis(100));
    assert!(now.starts_with("<Idle|MPos:-1.0"), "{now:?}");
}

fn rig_homes_a_board_that_is_silent_while_homing() {
    // Fast enough for a test, slow enough that the cycle (1-3 s) outlasts the old 2 s give-up.
    let sim = grbl(0.2, false, &[]);
    let mut d = driver(&sim.port);
    let p = d.home().unwrap();
    // GRBL's frame: a 1 mm pull-off from the + switches at the 250 mm end.
    assert!(
        (p.x_mm() - 249.0).abs() < 0.01 && (p.y_mm() - 249.0).abs() < 0.01,
        "{p}"
    );
    let (tx, ty) = truth_mm(&sim);
    // The carriage itself, from the simulator: the backlash of the downward pull-off at most.
    assert!((tx - p.x_mm()).abs() < 0.005 && (ty - p.y_mm()).abs() < 0.005);
    let st = d.status().unwrap();
    assert_eq!((st.state, st.homed), (StageState::Idle, true));
    let to = d.move_to(CarriageUm::from_mm(120.0, 80.0)).unwrap();
    let (tx, ty) = truth_mm(&sim);
    assert!(
        (tx - 120.0).abs() < 0.003 && (ty - 80.0).abs() < 0.003,
        "{tx} {ty} vs {to}"
    );
}

fn homing_toward_the_minus_switches_moves_limits_and_frame_with_them() {
    let sim = grbl(0.0, false, &[(23, 3.0)]);
    let mut d = driver(&sim.port);
    let l = d.limits();
    assert_eq!(
        (l.min.x_mm(), l.min.y_mm()),
        (1.0, 1.0),
        "a pull-off from the − switches"
    );
    assert_eq!((l.max.x_mm(), l.max.y_mm()), (250.0, 250.0));
    let p = d.home().unwrap();
    assert!(
        (p.x_mm() - 1.0).abs() < 0.01 && (p.y_mm() - 1.0).abs() < 0.01,
        "{p}"
    );
    // Between the pull-off and the switch: refused before anything is sent.
    let e = d.move_to(CarriageUm::from_mm(0.5, 10.0)).unwrap_err();
    assert!(
        matches!(e, StageError::OutOfLimits { axis: 'X', .. }),
        "{e}"
    );
    d.move_to(CarriageUm::from_mm(200.0, 150.0)).unwrap();
    let (tx, ty) = truth_mm(&sim);
    assert!(
        (tx - 200.0).abs() < 0.003 && (ty - 150.0).abs() < 0.003,
        "{tx} {ty}"
    );
    // The far end is inside the travel and away from the (+) switches, which never closed.
    d.move_to(CarriageUm::from_mm(250.0, 250.0)).unwrap();
    assert_eq!(d.status().unwrap().limit_switches, "");
}

fn wpos_and_inch_reports_give_the_same_carriage_positions() {
    // An operator's G54 offset (set by other software) and reports in inches: the rig must
    // neither move by the offset nor misread the unit.
    let sim = grbl(0.0, true, &[(10, 0.0), (13, 1.0)]);
    {
        let mut f = common::open_nonblocking(&sim.port);
        raw_exchange(&mut f, b"", Duration::from_millis(50));
        let out = raw_exchange(&mut f, b"G10 L2 P1 X-12.5 Y3\n", Duration::from_millis(100));
        assert_eq!(out, "ok\r\n");
        let out = raw_exchange(&mut f, b"?", Duration::from_millis(100));
        assert!(
            out.contains("|WPos:") && out.contains("|WCO:-0.4921,0.1181,"),
            "{out:?}"
        );
    }
    let mut d = driver(&sim.port);
    let before = d.status().unwrap().position;
    let (tx, ty) = truth_mm(&sim);
    // Inch reports have 4 decimals: 2.54 µm.
    assert!(
        (before.x_mm() - tx).abs() < 0.005 && (before.y_mm() - ty).abs() < 0.005,
        "{before} vs {tx} {ty}"
    );
    let at = d.move_to(CarriageUm::from_mm(100.0, 120.0)).unwrap();
    let (tx, ty) = truth_mm(&sim);
    assert!(
        (tx - 100.0).abs() < 0.004 && (ty - 120.0).abs() < 0.004,
        "{tx} {ty}"
    );
    assert!((at.x_mm() - 100.0).abs() < 0.003, "{at}");
}

fn alarm_at_connect_is_reported_not_hidden() {
    let sim = grbl(0.0, false, &[]);
    let c = GrblController::open(&sim.port, &Default::default()).unwrap();
    let notes = c.info().notes.join("\n");
    assert!(
        notes.contains("locked in Alarm") && notes.contains("home"),
        "{notes}"
    );
    let mut d = Driver::new(c, DriverOptions::default());
    let st = d.status().unwrap();
    assert!(!st.homed);
    assert_eq!(st.controller_state, "Alarm");
    assert!(matches!(
        d.move_to(CarriageUm::from_mm(10.0, 10.0)),
        Err(StageError::NotHomed)
    ));
}

fn connecting_never_aborts_a_homing_cycle() {
    // Seed 1's cycle (8 s at half real time) outlasts the connection attempt (2.5 s).
    let sim = grbl(0.5, false, &[]);
    {
        let mut f = common::open_nonblocking(&sim.port);
        raw_exchange(&mut f, b"$H\n", Duration::from_millis(50));
    }
    let t = Instant::now();
    let e = match GrblController::open(&sim.port, &Default::default()) {
        Err(e) => e,
        Ok(_) => panic!("a board in a homing cycle cannot answer"),
    };
    assert!(t.elapsed() < Duration::from_secs(5));
    let m = e.to_string();
    assert!(
        m.contains("homing cycle") && m.contains("No reset was sent"),
        "{m}"
    );
    // The cycle goes on to its end: the board was not reset (that would be ALARM:6).
    let deadline = Instant::now() + Duration::from_secs(30);
    while !sim.world.stage().homed && Instant::now() < deadline {
        std::thread::sleep(Duration::from_millis(50));
    }
    assert!(sim.world.stage().homed, "homing was aborted");
    let c = GrblController::open(&sim.port, &Default::default()).unwrap();
    assert!(c.info().notes.iter().all(|n| !n.contains("Alarm")));
}

fn absurd_settings_are_refused_by_name_before_anything_moves() {
    for (k, v) in [
        (110, 0.0),
        (111, 1e12),
        (120, -1.0),
        (130, 1e9),
        (131, 0.0),
        (27, 1e6),
        (24, 0.0),
        (25, 0.0),
        (13, 2.0),
    ] {
        let sim = grbl(0.0, true, &[(k, v)]);
        let e = match GrblController::open(&sim.port, &Default::default()) {
            Err(e) => e,
            Ok(_) => panic!("${k}={v} accepted"),
        };
        assert!(matches!(e, StageError::BadSetting { .. }), "${k}={v}: {e}");
        let m = e.to_string();
        assert!(
            m.contains(&format!("${k} (")) && m.contains("allowed range"),
            "{m}"
        );
        assert_eq!(e.exit_code(), 8);
    }
}

fn wrong_dialect_first_does_not_spoil_the_next_connection() {
    let sim = grbl(0.0, true, &[]);
    let e = match rig::stage::native::NativeController::open(&sim.port, &Default::default()) {
        Err(e) => e,
        Ok(_) => panic!("GRBL is not the native protocol"),
    };
    assert!(e.exit_code() == 8 || e.exit_code() == 4, "{e}");
    // Silence at the handshake points at the dialect.
    assert!(
        e.exit_code() == 8 || e.to_string().contains("--dialect grbl"),
        "{e}"
    );
    let mut d = driver(&sim.port);
    d.move_to(CarriageUm::from_mm(50.0, 60.0)).unwrap();
    let (tx, ty) = truth_mm(&sim);
    assert!((tx - 50.0).abs() < 0.003 && (ty - 60.0).abs() < 0.003);
    // And GRBL's client on a native controller says what it heard.
    let native = EmbeddedSim::start(SimConfig {
        time_scale: 0.0,
        start_homed: true,
        ..Default::default()
    })
    .unwrap();
    let m = match GrblController::open(&native.port, &Default::default()) {
        Err(e) => e.to_string(),
        Ok(_) => panic!("the native protocol is not GRBL"),
    };
    assert!(m.contains("heard") || m.contains("nothing at all"), "{m}");
}

fn a_late_report_never_answers_a_later_question() {
    let fake = FakeGrbl::start(Script::default());
    let mut c = GrblController::open(&fake.port, &Default::default()).unwrap();
    // Silent now (as in a homing cycle): the question times out.
    fake.set(|s| s.silent = true);
    assert!(matches!(c.status(), Err(StageError::Timeout { .. })));
    // It speaks again; its late answer (at machine −7, −7) comes first, then the truth
    // (machine −100, −100: carriage 150, 150).
    fake.set(|s| {
        s.silent = false;
        s.late_pos = "MPos:-7.000,-7.000,0.000".into();
    });
    let st = c.status().unwrap();
    assert_eq!(st.position, CarriageUm::from_mm(150.0, 150.0), "{st:?}");
    assert_eq!(
        c.late_reports, 1,
        "the late report was recognised and set aside"
    );
}

/// A noisy line can lose `$H`'s `ok` (or its ALARM): the wait then learns from a status report
/// that the cycle is over, within seconds, instead of waiting out the homing bound.
fn a_lost_homing_answer_is_recovered_from_the_board_state() {
    for (state, homed) in [("Idle", true), ("Alarm", false)] {
        let fake = FakeGrbl::start(Script {
            lost_home_answer: Some(state.into()),
            ..Script::default()
        });
        // The homing bound of these settings is over a minute; waiting for the lost answer
        // would end in a motion timeout at this 10 s cap.
        let mut d = Driver::new(
            GrblController::open(&fake.port, &Default::default()).unwrap(),
            DriverOptions {
                timeouts: TimeoutPolicy {
                    cap: Duration::from_secs(10),
                    ..TimeoutPolicy::default()
                },
                ..DriverOptions::default()
            },
        );
        match (d.home(), homed) {
            (Ok(p), true) => {
                // Machine −1, −1 mm with the + switches: 1 mm inside the 250 mm travel.
                assert_eq!(p, CarriageUm::from_mm(249.0, 249.0), "{state}");
            }
            (Err(e), false) => {
                assert!(matches!(e, StageError::Fault { .. }), "{state}: {e}");
                assert!(e.to_string().contains("Alarm"), "{e}");
            }
            (r, _) => panic!("{state}: {r:?}"),
        }
    }
}

fn a_stop_acts_at_once_and_escalates_to_a_reset() {
    let fake = FakeGrbl::start(Script {
        hang_on_move: true,
        ignore_hold: true,
        ..Script::default()
    });
    let mut c = GrblController::open(&fake.port, &Default::default()).unwrap();
    c.start_move(CarriageUm::from_mm(20.0, 20.0), 10_000.0)
        .unwrap();
    let q0 = fake.seen().questions;
    let t = Instant::now();
    let action = c.stop().unwrap();
    let took = t.elapsed();
    assert_eq!(action, StopAction::Reset);
    let seen = fake.seen();
    assert!(seen.holds >= 1 && seen.resets == 1, "{seen:?}");
    // Polled, not spun: at most one question per 25 ms over the wait.
    let asked = seen.questions - q0;
    let most = (took.as_secs_f64() / 0.025).ceil() as u64 + 2;
    assert!(asked <= most, "{asked} questions in {took:?}");
}

fn a_stop_that_is_not_confirmed_is_never_reported_as_done() {
    let fake = FakeGrbl::start(Script {
        hang_on_move: true,
        ignore_hold: true,
        ignore_reset: true,
        ..Script::default()
    });
    let c = GrblController::open(&fake.port, &Default::default()).unwrap();
    let mut d = Driver::new(
        c,
        DriverOptions {
            timeouts: TimeoutPolicy {
                cap: Duration::from_secs(3),
                ..TimeoutPolicy::default()
            },
            ..DriverOptions::default()
        },
    );
    let e = d.move_to(CarriageUm::from_mm(200.0, 200.0)).unwrap_err();
    assert!(matches!(e, StageError::StopFailed { .. }), "{e}");
    let m = e.to_string();
    assert!(
        m.contains("NOT confirmed") && !m.contains("stages stopped"),
        "{m}"
    );
    assert_eq!(e.exit_code(), 9);
    assert!(fake.seen().resets >= 1, "a reset was tried");
}

fn a_position_far_outside_the_travel_is_a_fault() {
    let fake = FakeGrbl::start(Script {
        pos: "MPos:-5000.000,-100.000,0.000".into(),
        ..Script::default()
    });
    let mut d = Driver::new(
        GrblController::open(&fake.port, &Default::default()).unwrap(),
        DriverOptions::default(),
    );
    let e = d.status().unwrap_err();
    assert!(
        matches!(
            e,
            StageError::Fault {
                kind: FaultKind::ImplausiblePosition { .. },
                ..
            }
        ),
        "{e}"
    );
    assert!(e.to_string().contains("far outside"), "{e}");
}

fn a_settings_dump_answered_with_an_error_is_asked_again() {
    let fake = FakeGrbl::start(Script {
        settings_errors: 2,
        ..Script::default()
    });
    let c = GrblController::open(&fake.port, &Default::default()).unwrap();
    assert_eq!(c.raw_settings.get(&130), Some(&250.0));
    let dumps = fake.seen().lines.iter().filter(|l| *l == "$$").count();
    assert!(dumps >= 4, "two refused, two that agree: {dumps}");
}

fn a_silent_line_is_reported_as_silence_without_a_reset() {
    let fake = FakeGrbl::start(Script {
        silent: true,
        deaf: true,
        ..Script::default()
    });
    let m = match GrblController::open(&fake.port, &Default::default()) {
        Err(e) => e.to_string(),
        Ok(_) => panic!("nothing answered"),
    };
    assert!(m.contains("nothing at all was heard"), "{m}");
    assert_eq!(fake.seen().resets, 0, "connecting must not reset the board");
}

/// `rig stage --sim --dialect grbl --sim-grbl-setting SETTING ACTION`: exit code, stdout,
/// stderr.
fn grbl_cli(setting: &str, action: &str) -> (i32, String, String) {
    let out = common::rig()
        .args([
            "stage",
            "--sim",
            "--dialect",
            "grbl",
            "--sim-time-scale",
            "0",
        ])
        .args(["--sim-grbl-setting", setting, action])
        .output()
        .unwrap();
    (
        out.status.code().unwrap_or(-1),
        String::from_utf8_lossy(&out.stdout).to_string(),
        String::from_utf8_lossy(&out.stderr).to_string(),
    )
}

fn check_setup_says_what_to_change() {
    let (code, text, err) = grbl_cli("20=0", "check-setup");
    assert_eq!(code, 0, "{err}");
    assert!(
        text.contains("$20: now 0") && text.contains("`$20=1`"),
        "{text}"
    );
    assert!(text.contains("HOMING_CYCLE_0"), "{text}");
    let (code, _, err) = grbl_cli("110=0", "status");
    assert_eq!(code, 8, "{err}");
    assert!(err.contains("$110 (X max rate"), "{err}");
    assert!(!err.contains("panicked"));
}

crate::waiting_tests!(
    emulator_is_silent_while_homing_and_answers_once_before_its_ok,
    rig_homes_a_board_that_is_silent_while_homing,
    homing_toward_the_minus_switches_moves_limits_and_frame_with_them,
    wpos_and_inch_reports_give_the_same_carriage_positions,
    alarm_at_connect_is_reported_not_hidden,
    connecting_never_aborts_a_homing_cycle,
    absurd_settings_are_refused_by_name_before_anything_moves,
    wrong_dialect_first_does_not_spoil_the_next_connection,
    a_late_report_never_answers_a_later_question,
    a_lost_homing_answer_is_recovered_from_the_board_state,
    a_stop_acts_at_once_and_escalates_to_a_reset,
    a_stop_that_is_not_confirmed_is_never_reported_as_done,
    a_position_far_outside_the_travel_is_a_fault,
    a_settings_dump_answered_with_an_error_is_asked_again,
    a_silent_line_is_reported_as_silence_without_a_reset,
    check_setup_says_what_to_change,
);
