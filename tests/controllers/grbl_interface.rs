//! The simulated GRBL speaks GRBL 1.1's documented interface, checked byte by byte over its
//! pseudo-terminal without the rig's client in between.

use crate::common;

use rig_sim::{Dialect, EmbeddedSim, SimConfig};
use std::io::{Read, Write};
use std::time::{Duration, Instant};

struct Raw {
    f: std::fs::File,
    _sim: EmbeddedSim,
}

impl Raw {
    fn open(start_homed: bool) -> Raw {
        Raw::attach(
            EmbeddedSim::start(SimConfig {
                dialect: Dialect::Grbl,
                time_scale: 0.0,
                start_homed,
                ..Default::default()
            })
            .unwrap(),
        )
    }

    fn attach(sim: EmbeddedSim) -> Raw {
        let f = common::open_nonblocking(&sim.port);
        let mut r = Raw { f, _sim: sim };
        r.drain();
        r
    }

    /// Discards what the controller printed so far (its power-on banner).
    fn drain(&mut self) {
        std::thread::sleep(Duration::from_millis(100));
        let mut buf = [0u8; 4096];
        while matches!(self.f.read(&mut buf), Ok(n) if n > 0) {}
    }

    /// Sends `bytes`, then collects output until `until` appears (or 2 s pass).
    fn tx(&mut self, bytes: &[u8], until: &str) -> String {
        self.f.write_all(bytes).unwrap();
        let deadline = Instant::now() + Duration::from_secs(2);
        let mut out = Vec::new();
        let mut buf = [0u8; 1024];
        while Instant::now() < deadline {
            match self.f.read(&mut buf) {
                Ok(n) if n > 0 => out.extend_from_slice(&buf[..n]),
                _ => std::thread::sleep(Duration::from_millis(2)),
            }
            if String::from_utf8_lossy(&out).contains(until) {
                break;
            }
        }
        String::from_utf8_lossy(&out).to_string()
    }
}

fn boot_alarm_lock_home_and_status_reports() {
    let mut g = Raw::open(false);
    // A soft reset prints the banner; with homing enabled and no reference it locks.
    let out = g.tx(&[0x18], "unlock]");
    assert!(out.contains("Grbl 1.1h ['$' for help]\r\n"), "{out:?}");
    assert!(out.contains("[MSG:'$H'|'$X' to unlock]"), "{out:?}");
    let out = g.tx(b"?", ">");
    assert!(out.starts_with("<Alarm|MPos:"), "{out:?}");
    // G-code is locked out in alarm: error:9.
    assert!(g.tx(b"G0 X-10\n", "\r\n").contains("error:9"));
    // $X unlocks.
    let out = g.tx(b"$X\n", "ok");
    assert!(
        out.contains("[MSG:Caution: Unlocked]") && out.ends_with("ok\r\n"),
        "{out:?}"
    );
    // $H homes toward +: machine position is minus the pull-off afterwards.
    assert_eq!(g.tx(b"$H\n", "ok"), "ok\r\n");
    let out = g.tx(b"?", ">");
    assert!(
        out.starts_with("<Idle|MPos:-1.000,-1.000,0.000|FS:"),
        "{out:?}"
    );
}

fn settings_moves_dwell_and_errors() {
    let mut g = Raw::open(true);
    let out = g.tx(b"$$\n", "ok\r\n");
    for s in [
        "$20=1\r\n",
        "$22=1\r\n",
        "$27=1\r\n",
        "$130=250\r\n",
        "$131=250\r\n",
        "$110=1200\r\n",
    ] {
        assert!(out.contains(s), "missing {s:?} in {out:?}");
    }
    // `ok` as soon as a move is planned; a G4 dwell answers only when motion is over.
    assert_eq!(
        g.tx(b"G90 G21 G1 X-100 Y-50 F600\nG4 P0.01\n", "ok\r\nok\r\n"),
        "ok\r\nok\r\n"
    );
    assert!(g
        .tx(b"?", ">")
        .starts_with("<Idle|MPos:-100.000,-50.000,0.000"));
    // Errors: bad number, unsupported command, undefined feed after reset, unknown $.
    assert_eq!(g.tx(b"G1 X-1.2.3\n", "\r\n"), "error:2\r\n");
    assert_eq!(g.tx(b"G5 X1\n", "\r\n"), "error:20\r\n");
    assert_eq!(g.tx(b"$999\n", "\r\n"), "error:3\r\n");
    // Jog beyond the travel: error:15, nothing moves.
    assert_eq!(g.tx(b"$J=G91 X-1000 F600\n", "\r\n"), "error:15\r\n");
    // A G-code target beyond the travel is a soft-limit alarm; only a reset continues, and
    // the position (nothing moved) is kept.
    let out = g.tx(b"G90 G0 X-300\n", "continue]\r\n");
    assert!(out.starts_with("ALARM:2\r\n"), "{out:?}");
    // Critical: no status report until a reset (Commands.md), no line either.
    assert_eq!(g.tx(b"?\n", "\n"), "");
    // The reset keeps the Alarm state (GRBL 1.1 keeps it across resets) and the position;
    // `$X` unlocks.
    let out = g.tx(&[0x18], "unlock]\r\n");
    assert!(
        out.contains("Grbl 1.1h") && out.contains("[MSG:'$H'|'$X' to unlock]"),
        "{out:?}"
    );
    assert!(g.tx(b"?", ">").starts_with("<Alarm|MPos:-100.000,-50.000"));
    assert!(g.tx(b"$X\n", "ok\r\n").ends_with("ok\r\n"));
    assert!(g.tx(b"?", ">").starts_with("<Idle|MPos:-100.000,-50.000"));
    // A reset while idle and unlocked comes up idle.
    let out = g.tx(&[0x18], "help]\r\n");
    assert!(!out.contains("unlock"), "{out:?}");
}

fn realtime_hold_resume_and_jog_cancel() {
    // At real time so the motion is still under way when the real-time bytes arrive.
    let sim = EmbeddedSim::start(SimConfig {
        dialect: Dialect::Grbl,
        time_scale: 1.0,
        start_homed: true,
        ..Default::default()
    })
    .unwrap();
    let mut g = Raw::attach(sim);
    g.tx(b"G90 G21 G1 X-200 F600\n", "ok\r\n"); // 10 mm/s: a few seconds of motion
    std::thread::sleep(Duration::from_millis(100));
    assert!(g.tx(b"?", ">").starts_with("<Run|"));
    g.tx(b"!", "");
    std::thread::sleep(Duration::from_millis(300));
    let out = g.tx(b"?", ">");
    assert!(
        out.starts_with("<Hold:0|"),
        "feed hold decelerates to Hold:0: {out:?}"
    );
    g.tx(b"~", "");
    std::thread::sleep(Duration::from_millis(50));
    assert!(g.tx(b"?", ">").starts_with("<Run|"), "cycle start resumes");
    // A reset while running loses the position: ALARM:3.
    let out = g.tx(&[0x18], "unlock]\r\n");
    assert!(out.contains("ALARM:3"), "{out:?}");
    assert!(g.tx(b"$X\n", "ok\r\n").ends_with("ok\r\n"));
    let mpos_x = |r: &str| -> f64 {
        r.split("MPos:")
            .nth(1)
            .unwrap()
            .split(',')
            .next()
            .unwrap()
            .parse()
            .unwrap()
    };
    let x0 = mpos_x(&g.tx(b"?", ">"));
    // A jog, cancelled with 0x85.
    assert_eq!(g.tx(b"$J=G91 G21 X-50 F600\n", "ok\r\n"), "ok\r\n");
    std::thread::sleep(Duration::from_millis(100));
    assert!(g.tx(b"?", ">").starts_with("<Jog|"));
    g.tx(&[0x85], "");
    std::thread::sleep(Duration::from_millis(300));
    let out = g.tx(b"?", ">");
    assert!(out.starts_with("<Idle|"), "jog cancelled: {out:?}");
    let moved = x0 - mpos_x(&out);
    assert!(
        moved > 0.5 && moved < 10.0,
        "stopped part way through the 50 mm jog: moved {moved} mm"
    );
}

fn client_unlocks_a_soft_limit_alarm_keeping_the_position() {
    use rig::coords::CarriageUm;
    use rig::stage::grbl::GrblController;
    use rig::stage::{Controller, FaultKind, StageError, StageState};
    let sim = EmbeddedSim::start(SimConfig {
        dialect: Dialect::Grbl,
        time_scale: 0.0,
        start_homed: true,
        ..Default::default()
    })
    .unwrap();
    let mut c = GrblController::open(&sim.port, &Default::default()).unwrap();
    let before = c.status().unwrap();
    assert_eq!(before.state, StageState::Idle);
    // Below the driver: a target past GRBL's travel, so that GRBL itself refuses it.
    let e = c
        .start_move(CarriageUm::new(-5_000.0, 10_000.0), 5_000.0)
        .and_then(|_| c.wait_done(Duration::from_secs(5)))
        .unwrap_err();
    assert!(
        matches!(
            e,
            StageError::Fault {
                kind: FaultKind::Alarm { code: 2, .. },
                ..
            }
        ),
        "{e}"
    );
    // A critical alarm answers no `?` until a reset (Commands.md): the silence is the alarm's.
    // The stop gives it the reset, and the board then reports the alarm (kept across it).
    assert!(
        matches!(
            c.status(),
            Err(StageError::Fault {
                kind: FaultKind::Alarm { code: 2, .. },
                ..
            })
        ),
        "GRBL is silent in a critical alarm"
    );
    c.stop().unwrap();
    assert_eq!(c.status().unwrap().state, StageState::Fault);
    // Soft-limit alarm: nothing moved, so reset + `$X` gives back an idle, referenced stage.
    c.clear_fault().unwrap();
    let st = c.status().unwrap();
    assert_eq!((st.state, st.homed), (StageState::Idle, true), "{st:?}");
    assert_eq!(st.position, before.position);
}

crate::waiting_tests!(
    boot_alarm_lock_home_and_status_reports,
    settings_moves_dwell_and_errors,
    realtime_hold_resume_and_jog_cancel,
    client_unlocks_a_soft_limit_alarm_keeping_the_position,
);
