//! The session store: every calibration is a directory holding its JSON Lines log (start,
//! descriptor, event, stop documents, flushed line by line so a crash loses nothing already
//! measured), a crop of every mark with the fitted centre drawn, and the results document.

use crate::coords::PixelXY;
use crate::digitise::ImageF32;
use serde::{de::DeserializeOwned, Deserialize, Serialize};
use serde_json::{json, Value};
use std::fs::{File, OpenOptions};
use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::{Instant, SystemTime, UNIX_EPOCH};

pub const LOG: &str = "log.jsonl";
pub const RESULTS: &str = "results.json";

pub struct Session {
    pub dir: PathBuf,
    log: File,
    t0: Instant,
}

/// UTC date and time of a Unix time, as `YYYYMMDDTHHMMSSZ` (days to civil date by the
/// proleptic Gregorian calendar's 400-year cycle).
pub fn utc_stamp(t: SystemTime) -> String {
    let secs = t.duration_since(UNIX_EPOCH).map_or(0, |d| d.as_secs()) as i64;
    let (days, rem) = (secs.div_euclid(86_400), secs.rem_euclid(86_400));
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z - era * 146_097;
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = doy - (153 * mp + 2) / 5 + 1;
    let m = if mp < 10 { mp + 3 } else { mp - 9 };
    let y = yoe + era * 400 + (m <= 2) as i64;
    format!(
        "{y:04}{m:02}{d:02}T{:02}{:02}{:02}Z",
        rem / 3600,
        rem % 3600 / 60,
        rem % 60
    )
}

impl Session {
    /// A new session directory `STORE/<UTC time>-<kind>` (a suffix if that exists).
    pub fn new_in_store(store: &Path, kind: &str) -> std::io::Result<Session> {
        std::fs::create_dir_all(store)?;
        let base = format!("{}-{kind}", utc_stamp(SystemTime::now()));
        let mut dir = store.join(&base);
        let mut k = 1;
        while dir.exists() {
            k += 1;
            dir = store.join(format!("{base}-{k}"));
        }
        Self::create(&dir)
    }

    /// A session in `dir`, which must not exist yet or be empty: a session is never written
    /// over another.
    pub fn create(dir: &Path) -> std::io::Result<Session> {
        if dir.exists() && std::fs::read_dir(dir)?.next().is_some() {
            return Err(std::io::Error::new(
                std::io::ErrorKind::AlreadyExists,
                format!(
                    "{} is not empty: give a new directory (sessions are never overwritten)",
                    dir.display()
                ),
            ));
        }
        std::fs::create_dir_all(dir.join("crops"))?;
        Self::append(dir)
    }

    /// The session log in `dir`, appended to (created if absent): for work that is resumed
    /// in the same directory, such as a scan.
    pub fn append(dir: &Path) -> std::io::Result<Session> {
        std::fs::create_dir_all(dir)?;
        let log = OpenOptions::new()
            .create(true)
            .append(true)
            .open(dir.join(LOG))?;
        Ok(Session {
            dir: dir.to_path_buf(),
            log,
            t0: Instant::now(),
        })
    }

    fn write(&mut self, mut doc: Value) -> std::io::Result<()> {
        doc["t_s"] = json!(self.t0.elapsed().as_secs_f64());
        let mut line = serde_json::to_vec(&doc)?;
        line.push(b'\n');
        self.log.write_all(&line)?;
        self.log.sync_data()
    }

    /// The log's first two documents: the start, and the descriptor (one of the typed
    /// descriptors of [`super::documents`], read back by the same type).
    pub fn start<D: serde::Serialize>(
        &mut self,
        kind: &str,
        descriptor: &D,
    ) -> std::io::Result<()> {
        let start: LogDocument<&D> = LogDocument::Start {
            kind: kind.into(),
            time: utc_stamp(SystemTime::now()),
            rig_version: env!("CARGO_PKG_VERSION").into(),
        };
        self.write(serde_json::to_value(start)?)?;
        self.write(serde_json::to_value(LogDocument::Descriptor {
            data: descriptor,
        })?)
    }

    pub fn event(&mut self, name: &str, data: Value) -> std::io::Result<()> {
        self.write(json!({"doc": "event", "name": name, "data": data}))
    }

    pub fn stop(&mut self, status: &str, reason: Option<&str>) -> std::io::Result<()> {
        self.write(json!({"doc": "stop", "status": status, "reason": reason}))
    }

    /// Writes the results document atomically.
    pub fn write_results<C: serde::Serialize>(&self, r: &Results<C>) -> std::io::Result<PathBuf> {
        let p = self.dir.join(RESULTS);
        crate::atomic::write_json(&p, r)?;
        Ok(p)
    }

    /// Keeps a certificate the session is measured against (the simulator's own, when none was
    /// given) as `name` in the session, atomically; its path.
    pub fn keep_certificate(&self, name: &str, text: &str) -> std::io::Result<PathBuf> {
        let p = self.dir.join(name);
        crate::atomic::write_with(&p, |w| w.write_all(text.as_bytes()))?;
        Ok(p)
    }

    /// Saves a crop of `img` around `centre` (3× enlarged, grey stretched to the crop) with the
    /// fitted centre drawn as a red cross with a gap, so the mark itself stays visible.
    pub fn save_crop(
        &self,
        name: &str,
        img: &ImageF32,
        centre: PixelXY,
        half: usize,
    ) -> std::io::Result<PathBuf> {
        let p = self.dir.join("crops").join(format!("{name}.png"));
        crop_png(img, centre, half)
            .save(&p)
            .map_err(|e| std::io::Error::other(e.to_string()))?;
        Ok(p)
    }
}

const ZOOM: usize = 3;

fn crop_png(img: &ImageF32, centre: PixelXY, half: usize) -> image::RgbImage {
    let n = 2 * half + 1;
    let (c0, r0) = (
        centre.col.floor() as i64 - half as i64,
        centre.row.floor() as i64 - half as i64,
    );
    let get = |c: i64, r: i64| -> Option<f32> {
        (c >= 0 && r >= 0 && (c as usize) < img.width && (r as usize) < img.height)
            .then(|| img.at(c as usize, r as usize))
    };
    let vals: Vec<f32> = (0..n as i64)
        .flat_map(|j| (0..n as i64).map(move |i| (i, j)))
        .filter_map(|(i, j)| get(c0 + i, r0 + j))
        .collect();
    let lo = vals.iter().copied().fold(f32::MAX, f32::min);
    let hi = vals.iter().copied().fold(f32::MIN, f32::max);
    let k = if hi > lo { 255.0 / (hi - lo) } else { 0.0 };
    let mut out = image::RgbImage::new((n * ZOOM) as u32, (n * ZOOM) as u32);
    for y in 0..n * ZOOM {
        for x in 0..n * ZOOM {
            let v = get(c0 + (x / ZOOM) as i64, r0 + (y / ZOOM) as i64)
                .map_or(0u8, |v| ((v - lo) * k).round().clamp(0.0, 255.0) as u8);
            out.put_pixel(x as u32, y as u32, image::Rgb([v, v, v]));
        }
    }
    // The centre in zoomed crop pixels.
    let cx = ((centre.col - c0 as f64) * ZOOM as f64).round() as i64;
    let cy = ((centre.row - r0 as f64) * ZOOM as f64).round() as i64;
    let (w, gap, arm) = (out.width() as i64, 3 * ZOOM as i64, 12 * ZOOM as i64);
    let mut dot = |x: i64, y: i64| {
        if x >= 0 && y >= 0 && x < w && y < w {
            out.put_pixel(x as u32, y as u32, image::Rgb([255, 32, 32]));
        }
    };
    for d in gap..=arm {
        dot(cx + d, cy);
        dot(cx - d, cy);
        dot(cx, cy + d);
        dot(cx, cy - d);
    }
    out
}

/// The sessions of a kind in the store, oldest first (their names sort by time).
pub fn list(store: &Path, kind: &str) -> std::io::Result<Vec<PathBuf>> {
    let mut v: Vec<PathBuf> = match std::fs::read_dir(store) {
        Ok(rd) => rd
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|p| {
                p.join(RESULTS).is_file()
                    && p.file_name()
                        .and_then(|n| n.to_str())
                        .is_some_and(|n| n.contains(&format!("-{kind}")))
            })
            .collect(),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Vec::new(),
        Err(e) => return Err(e),
    };
    v.sort();
    Ok(v)
}

/// The newest session of a kind in the store, if any.
pub fn newest(store: &Path, kind: &str) -> std::io::Result<Option<PathBuf>> {
    list(store, kind).map(|mut v| v.pop())
}

/// `results.json` of a session: what kind of calibration, where, and its result.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Results<C> {
    pub kind: String,
    pub session: PathBuf,
    pub calibration: C,
}

/// One line of a session's log.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(tag = "doc", rename_all = "snake_case")]
pub enum LogDocument<D> {
    Start {
        kind: String,
        time: String,
        rig_version: String,
    },
    Descriptor {
        data: D,
    },
    Event {
        name: String,
        data: serde_json::Value,
    },
    Stop {
        status: String,
        reason: Option<String>,
    },
}

/// Why a session's document could not be read.
#[derive(Debug, thiserror::Error)]
#[error("{path}: {message}")]
pub struct DocumentError {
    pub path: PathBuf,
    pub message: String,
}

fn fail(path: &Path, message: impl Into<String>) -> DocumentError {
    DocumentError {
        path: path.to_path_buf(),
        message: message.into(),
    }
}

/// A session's results document, of kind `kind`.
pub fn read_results<C: DeserializeOwned>(
    dir: &Path,
    kind: &str,
) -> Result<Results<C>, DocumentError> {
    let p = dir.join(super::session::RESULTS);
    let text = std::fs::read_to_string(&p).map_err(|e| fail(&p, e.to_string()))?;
    // The kind first, so that the wrong kind of session is named as such.
    let head: serde_json::Value =
        serde_json::from_str(&text).map_err(|e| fail(&p, format!("not JSON: {e}")))?;
    if head["kind"] != kind {
        let article = if kind.starts_with(['a', 'e', 'i', 'o', 'u']) {
            "an"
        } else {
            "a"
        };
        return Err(fail(
            &p,
            format!("not {article} {kind} session (run `rig calibrate {kind}`)"),
        ));
    }
    serde_path_to_error::deserialize(head).map_err(|e| {
        fail(
            &p,
            format!(
                "not a {kind} session's results: at {}: {}",
                e.path(),
                e.inner()
            ),
        )
    })
}

/// A session log's descriptor document.
pub fn read_descriptor<D: DeserializeOwned>(dir: &Path) -> Result<D, DocumentError> {
    let p = dir.join(super::session::LOG);
    let text = std::fs::read_to_string(&p).map_err(|e| fail(&p, e.to_string()))?;
    for (n, line) in text.lines().enumerate() {
        let v: serde_json::Value = match serde_json::from_str(line) {
            Ok(v) => v,
            // A crash can leave a last line cut short; it is not the descriptor.
            Err(_) => continue,
        };
        if v["doc"] == "descriptor" {
            // The data read as D directly (not through the tagged enum, whose buffering
            // would lose the path of a bad field).
            let mut v = v;
            return serde_path_to_error::deserialize::<_, D>(v["data"].take()).map_err(|e| {
                fail(
                    &p,
                    format!(
                        "line {}: the descriptor's {}: {}",
                        n + 1,
                        e.path(),
                        e.inner()
                    ),
                )
            });
        }
    }
    Err(fail(&p, "no descriptor document in the log"))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A kept certificate is the text given, under its name in the session, and nothing else
    /// is left beside the session's own files (no temporary file of the atomic write).
    #[test]
    fn a_kept_certificate_is_the_text_given() {
        let d = tempfile::tempdir().unwrap();
        let s = Session::create(&d.path().join("s")).unwrap();
        let text = "[plate]\nname = \"x\"\n";
        let p = s.keep_certificate("plate-cert.toml", text).unwrap();
        assert_eq!(p, s.dir.join("plate-cert.toml"));
        assert_eq!(std::fs::read_to_string(&p).unwrap(), text);
        let mut names: Vec<String> = std::fs::read_dir(&s.dir)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        names.sort();
        assert_eq!(names, ["crops", LOG, "plate-cert.toml"], "{names:?}");
    }

    #[test]
    fn utc_stamps_are_civil_dates() {
        let t = |s: u64| utc_stamp(UNIX_EPOCH + std::time::Duration::from_secs(s));
        assert_eq!(t(0), "19700101T000000Z");
        assert_eq!(t(951_782_400), "20000229T000000Z"); // a leap day
        assert_eq!(t(1_795_314_645), "20261122T023045Z");
    }

    #[test]
    fn a_session_is_never_written_over() {
        let d = tempfile::tempdir().unwrap();
        let mut s = Session::create(&d.path().join("s")).unwrap();
        s.start("pixel", &json!({"x": 1})).unwrap();
        s.event("measured", json!({"id": 5})).unwrap();
        s.stop("done", None).unwrap();
        let log = std::fs::read_to_string(d.path().join("s").join(LOG)).unwrap();
        let docs: Vec<Value> = log
            .lines()
            .map(|l| serde_json::from_str(l).unwrap())
            .collect();
        let kinds: Vec<&str> = docs.iter().map(|d| d["doc"].as_str().unwrap()).collect();
        assert_eq!(kinds, ["start", "descriptor", "event", "stop"]);
        assert!(Session::create(&d.path().join("s")).is_err());
    }
}
