//! Mutation fuzzing in CI: every parser of a file an operator or another program writes (scan
//! scripts, plate and camera certificates, matching projects) is fed thousands of deterministic mutations of good
//! files — hostile numbers (0, −0, NaN, ±inf, 1e308, 1e-308, 2^32, 2^63), deleted, doubled and
//! truncated lines, flipped bytes — and must end every one with a value or a typed error within
//! seconds, never a panic. The cargo-fuzz targets in `fuzz/` run the same parsers for longer.

use rig::scan::script::ScanScript;
use rig::targets::certificate::{CameraCertificate, PlateCertificate};
use std::path::Path;
use std::time::Duration;

/// xorshift64*: a fixed sequence, so a failure replays.
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_f491_4f6c_dd1d)
    }

    fn below(&mut self, n: usize) -> usize {
        (self.next() % n.max(1) as u64) as usize
    }
}

const HOSTILE: [&str; 16] = [
    "0",
    "-0",
    "-1",
    "nan",
    "inf",
    "-inf",
    "1e308",
    "-1e308",
    "1e-308",
    "4294967296",
    "9223372036854775808",
    "-9223372036854775809",
    "1e9",
    "0.0000001",
    "\"x\"",
    "[]",
];

/// Byte ranges of the number tokens in `s`.
fn numbers(s: &str) -> Vec<(usize, usize)> {
    let b = s.as_bytes();
    let mut out = Vec::new();
    let mut i = 0;
    while i < b.len() {
        if b[i].is_ascii_digit() || (b[i] == b'-' && i + 1 < b.len() && b[i + 1].is_ascii_digit()) {
            let start = i;
            i += 1;
            while i < b.len()
                && (b[i].is_ascii_digit() || matches!(b[i], b'.' | b'e' | b'-' | b'_'))
            {
                i += 1;
            }
            out.push((start, i));
        } else {
            i += 1;
        }
    }
    out
}

fn mutate(seed: &str, rng: &mut Rng) -> String {
    let mut s = seed.to_string();
    for _ in 0..1 + rng.below(3) {
        match rng.below(6) {
            0 | 1 => {
                let nums = numbers(&s);
                if !nums.is_empty() {
                    let (a, b) = nums[rng.below(nums.len())];
                    s.replace_range(a..b, HOSTILE[rng.below(HOSTILE.len())]);
                }
            }
            2 => {
                let lines: Vec<&str> = s.lines().collect();
                let k = rng.below(lines.len());
                s = lines
                    .iter()
                    .enumerate()
                    .filter(|(i, _)| *i != k)
                    .map(|(_, l)| *l)
                    .collect::<Vec<_>>()
                    .join("\n");
            }
            3 => {
                let lines: Vec<&str> = s.lines().collect();
                let k = rng.below(lines.len());
                let mut v: Vec<&str> = lines.clone();
                if let Some(l) = lines.get(k) {
                    v.insert(k, l);
                }
                s = v.join("\n");
            }
            4 => {
                let mut b = s.into_bytes();
                if !b.is_empty() {
                    let k = rng.below(b.len());
                    b[k] ^= 1 << rng.below(8);
                }
                s = String::from_utf8_lossy(&b).to_string();
            }
            _ => {
                let mut k = rng.below(s.len() + 1);
                while !s.is_char_boundary(k) {
                    k -= 1;
                }
                s.truncate(k);
            }
        }
    }
    s
}

/// Runs `parse` on `n` mutations of `seed` in a thread; fails on a panic or if the whole
/// batch does not end within `limit` (a hang).
fn survive(name: &str, seed: String, n: usize, parse: fn(&str) -> bool) {
    let (tx, rx) = std::sync::mpsc::channel();
    let handle = std::thread::spawn(move || {
        let mut rng = Rng(0x9e37_79b9_7f4a_7c15 ^ seed.len() as u64);
        let mut accepted = 0;
        for i in 0..n {
            let text = mutate(&seed, &mut rng);
            let r = std::panic::catch_unwind(|| parse(&text));
            match r {
                Ok(ok) => accepted += ok as usize,
                Err(_) => {
                    let _ = tx.send(Err(format!("mutation {i} panicked:\n{text}")));
                    return;
                }
            }
        }
        let _ = tx.send(Ok(accepted));
    });
    match rx.recv_timeout(Duration::from_secs(60)) {
        Ok(Ok(accepted)) => {
            // The mutations must not all be trivially rejected (or the test proves little).
            assert!(
                accepted > 0 && accepted < n,
                "{name}: {accepted} of {n} accepted"
            );
        }
        Ok(Err(m)) => panic!("{name}: {m}"),
        Err(_) => panic!("{name}: {n} parses did not end within 60 s (a hang)"),
    }
    let _ = handle.join();
}

#[test]
fn scan_scripts_survive_mutation() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    for f in ["examples/scan-photo-1.toml", "examples/scan-photo-2.toml"] {
        let seed = std::fs::read_to_string(root.join(f)).unwrap();
        survive(f, seed, 3000, |t| {
            ScanScript::parse(t, Path::new("hostile.toml")).is_ok()
        });
    }
}

#[test]
fn mark_files_survive_mutation() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    for f in [
        "examples/marks/corner-fiducial.toml",
        "examples/marks/mid-side-fiducial.toml",
        "examples/marks/cross.toml",
    ] {
        let seed = std::fs::read_to_string(root.join(f)).unwrap();
        survive(f, seed, 3000, |t| {
            rig::targets::mark_file::MarkFile::parse(t, Path::new("mark.toml"))
                .map(|m| {
                    // What the rig does next with a file it accepted.
                    let (shape, a) = m.in_um(Some([10.0, 11.0])).unwrap();
                    let _ = (shape.geometry(), shape.reach_um(), a);
                    let _ = rig::targets::template::render_work(&shape, 101);
                })
                .is_ok()
        });
    }
}

#[test]
fn certificates_survive_mutation() {
    let w = rig_sim::World::new(&rig_sim::SimConfig {
        time_scale: 0.0,
        ..Default::default()
    });
    let plate = rig_sim::certificates::plate_certificate(&w.plate, 1);
    survive("plate certificate", plate, 3000, |t| {
        PlateCertificate::parse(t, Path::new("plate.toml")).is_ok()
    });
    let film = rig_sim::film::Film::rc10(&mut rig_sim::rng::Rng::new(1), 1);
    let camera = rig_sim::certificates::camera_certificate(&film, 1);
    survive("camera certificate", camera, 3000, |t| {
        CameraCertificate::parse(t, Path::new("camera.toml")).is_ok()
    });
}

#[test]
fn matching_projects_survive_mutation() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let f = "fuzz/seeds/project/project.toml";
    let seed = std::fs::read_to_string(root.join(f)).unwrap();
    survive(f, seed, 3000, |t| {
        rig::matching::project::pair::PairProject::parse(t, Path::new("hostile.toml")).is_ok()
    });
}

#[test]
fn format2_projects_and_points_files_survive_mutation() {
    use rig::matching::project::{parse_points, Project};
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let f = "fuzz/seeds/project/format2.toml";
    let seed = std::fs::read_to_string(root.join(f)).unwrap();
    survive(f, seed.clone(), 3000, |t| {
        Project::parse(t, Path::new("hostile.toml")).is_ok()
    });
    let csv = "id,kind,x,y,z,photo,col,row\np1,gcp,15100.5,13200.25,512.5,1,1200.5,1500.25\np1,gcp,15100.5,13200.25,512.5,2,340.0,1490.75\nt1,tie,,,,3,800.0,900.0\np2,cp,15400.0,13300.0,530.0,1,1300.0,1400.0\n".to_string();
    survive("points.csv", csv, 3000, |t| {
        let photos = Project::parse(
            &std::fs::read_to_string(
                Path::new(env!("CARGO_MANIFEST_DIR")).join("fuzz/seeds/project/format2.toml"),
            )
            .unwrap(),
            Path::new("p.toml"),
        )
        .unwrap()
        .photos;
        parse_points(t, Path::new("points.csv"), &photos).is_ok()
    });
}
