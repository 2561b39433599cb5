//! A scripted GRBL on a pseudo-terminal, for the controllers our emulator is too kind to be:
//! boards that stay silent, answer late, ignore a feed hold or a reset, report absurd settings
//! or positions. It speaks just enough of GRBL 1.1's interface for the rig to connect; each
//! test sets what goes wrong.

use rig_sim::pty::Pty;
use std::collections::BTreeMap;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

#[derive(Debug, Clone)]
pub struct Script {
    pub settings: BTreeMap<u32, f64>,
    /// The report's state and position field, e.g. ("Idle", "MPos:-10.000,-20.000,0.000").
    pub state: String,
    pub pos: String,
    /// `?` gets no answer now; the last one asked is answered once this is cleared (a late
    /// report with `late_state`), before the next line reply.
    pub silent: bool,
    pub late_state: String,
    pub late_pos: String,
    /// After a `G1`, the board reports `Run` until a reset (a hung motion).
    pub hang_on_move: bool,
    /// `!` does nothing (a board whose feed hold is broken).
    pub ignore_hold: bool,
    /// 0x18 does nothing (a board that is gone).
    pub ignore_reset: bool,
    /// Lines are never answered.
    pub deaf: bool,
    /// This many `$$` are answered `error:3` first (a garbled command).
    pub settings_errors: u32,
    /// `$H`'s answer is lost on the line: no `ok`; afterwards the board reports this state at
    /// the homed position (machine −$27, −$27 = −1, −1 mm).
    pub lost_home_answer: Option<String>,
}

impl Default for Script {
    fn default() -> Self {
        Script {
            settings: default_settings(),
            state: "Idle".into(),
            pos: "MPos:-100.000,-100.000,0.000".into(),
            silent: false,
            late_state: "Home".into(),
            late_pos: "MPos:-1.000,-1.000,0.000".into(),
            hang_on_move: false,
            ignore_hold: false,
            ignore_reset: false,
            deaf: false,
            settings_errors: 0,
            lost_home_answer: None,
        }
    }
}

pub fn default_settings() -> BTreeMap<u32, f64> {
    [
        (10, 1.0),
        (13, 0.0),
        (20, 1.0),
        (21, 1.0),
        (22, 1.0),
        (23, 0.0),
        (24, 25.0),
        (25, 600.0),
        (26, 250.0),
        (27, 1.0),
        (100, 4000.0),
        (101, 4000.0),
        (110, 1200.0),
        (111, 1200.0),
        (120, 100.0),
        (121, 100.0),
        (130, 250.0),
        (131, 250.0),
    ]
    .into_iter()
    .collect()
}

/// What the fake saw.
#[derive(Debug, Default, Clone)]
pub struct Seen {
    pub questions: u64,
    pub holds: u64,
    pub resets: u64,
    pub lines: Vec<String>,
    /// `?` asked while silent and not yet answered.
    pub owed: bool,
    /// Times each `?` arrived, from the start.
    pub question_times: Vec<Duration>,
}

pub struct FakeGrbl {
    pub port: std::path::PathBuf,
    pub script: Arc<Mutex<Script>>,
    pub seen: Arc<Mutex<Seen>>,
    stop: Arc<AtomicBool>,
    thread: Option<std::thread::JoinHandle<()>>,
}

impl FakeGrbl {
    pub fn start(script: Script) -> FakeGrbl {
        let pty = Pty::open(None).expect("pty");
        let port = pty.slave_path.clone();
        let script = Arc::new(Mutex::new(script));
        let seen = Arc::new(Mutex::new(Seen::default()));
        let stop = Arc::new(AtomicBool::new(false));
        let (sc, se, st) = (script.clone(), seen.clone(), stop.clone());
        let thread = std::thread::spawn(move || serve(pty, sc, se, st));
        FakeGrbl {
            port,
            script,
            seen,
            stop,
            thread: Some(thread),
        }
    }

    pub fn set(&self, f: impl FnOnce(&mut Script)) {
        f(&mut self.script.lock().unwrap())
    }

    pub fn seen(&self) -> Seen {
        self.seen.lock().unwrap().clone()
    }
}

impl Drop for FakeGrbl {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::SeqCst);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

fn report(state: &str, pos: &str) -> String {
    format!("<{state}|{pos}|FS:0,0>\r\n")
}

fn serve(pty: Pty, script: Arc<Mutex<Script>>, seen: Arc<Mutex<Seen>>, stop: Arc<AtomicBool>) {
    let t0 = Instant::now();
    let mut line = Vec::new();
    let mut buf = [0u8; 512];
    let mut moving = false;
    let send = |s: &str| {
        let mut b = s.as_bytes();
        while !b.is_empty() {
            match pty.write(b) {
                Ok(0) => std::thread::sleep(Duration::from_millis(1)),
                Ok(n) => b = &b[n..],
                Err(_) => return,
            }
        }
    };
    while !stop.load(Ordering::SeqCst) {
        // A late report is owed once the board speaks again.
        {
            let sc = script.lock().unwrap();
            let mut se = seen.lock().unwrap();
            if se.owed && !sc.silent {
                se.owed = false;
                send(&report(&sc.late_state, &sc.late_pos));
            }
        }
        if !pty.wait_readable(5) {
            continue;
        }
        let n = match pty.read(&mut buf) {
            Ok(n) => n,
            Err(_) => return,
        };
        for &b in &buf[..n] {
            let sc = script.lock().unwrap().clone();
            let mut se = seen.lock().unwrap();
            match b {
                b'?' => {
                    se.questions += 1;
                    se.question_times.push(t0.elapsed());
                    if sc.silent {
                        se.owed = true;
                    } else {
                        let state = if moving { "Run" } else { sc.state.as_str() };
                        send(&report(state, &sc.pos));
                    }
                }
                b'!' => {
                    se.holds += 1;
                    if !sc.ignore_hold && moving {
                        moving = false;
                        script.lock().unwrap().state = "Hold:0".into();
                    }
                }
                0x18 => {
                    se.resets += 1;
                    if !sc.ignore_reset {
                        let was_moving = moving;
                        moving = false;
                        line.clear();
                        if was_moving {
                            send("ALARM:3\r\n");
                        }
                        let mut s = script.lock().unwrap();
                        if s.state.starts_with("Hold") {
                            s.state = "Idle".into();
                        }
                        send("\r\nGrbl 1.1h ['$' for help]\r\n");
                    }
                }
                0x80..=0xff | b'~' => {}
                b'\n' | b'\r' => {
                    let l = String::from_utf8_lossy(&line).trim().to_string();
                    line.clear();
                    se.lines.push(l.clone());
                    if sc.deaf {
                        continue;
                    }
                    // A late report goes out before the reply that follows it.
                    if se.owed && !sc.silent {
                        se.owed = false;
                        send(&report(&sc.late_state, &sc.late_pos));
                    }
                    if l == "$$" && sc.settings_errors > 0 {
                        script.lock().unwrap().settings_errors -= 1;
                        send("error:3\r\n");
                        continue;
                    } else if l == "$$" {
                        for (k, v) in &sc.settings {
                            send(&format!("${k}={v}\r\n"));
                        }
                    } else if l == "$I" {
                        send("[VER:1.1h.20190830:fake]\r\n[OPT:V,15,128]\r\n");
                    } else if l == "$#" {
                        send("[G54:0.000,0.000,0.000]\r\n[G92:0.000,0.000,0.000]\r\n");
                    } else if l.contains("G1") && sc.hang_on_move {
                        moving = true;
                    } else if l == "$H" {
                        if let Some(state) = &sc.lost_home_answer {
                            let mut s = script.lock().unwrap();
                            s.state = state.clone();
                            s.pos = "MPos:-1.000,-1.000,0.000".into();
                            continue;
                        }
                    }
                    send("ok\r\n");
                }
                _ => line.push(b),
            }
        }
    }
}
