//! The simulated camera served on a Unix socket (CAMERA_SOCKET.md beside this crate).

use crate::frames::FrameSource;
use crate::server::World;
use serde_json::{json, Value};
use std::io::{BufRead, BufReader, Write};
use std::os::unix::net::{UnixListener, UnixStream};
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// A listening camera socket; the socket file is removed on drop.
pub struct CameraSocket {
    path: PathBuf,
}

impl Drop for CameraSocket {
    fn drop(&mut self) {
        let _ = std::fs::remove_file(&self.path);
    }
}

/// Starts serving `world`'s camera at `path` on a background thread.
pub fn serve_camera(world: Arc<World>, path: &Path, drop_p: f64) -> std::io::Result<CameraSocket> {
    if let Ok(md) = std::fs::symlink_metadata(path) {
        use std::os::unix::fs::FileTypeExt;
        if !md.file_type().is_socket() {
            return Err(std::io::Error::new(
                std::io::ErrorKind::AlreadyExists,
                format!(
                    "{} exists and is not a socket; refusing to replace it",
                    path.display()
                ),
            ));
        }
        std::fs::remove_file(path)?;
    }
    let listener = UnixListener::bind(path)?;
    std::thread::Builder::new()
        .name("rig-sim camera".into())
        .spawn(move || {
            for conn in listener.incoming().flatten() {
                let _ = serve_client(conn, FrameSource::new(world.clone(), drop_p));
            }
        })?;
    Ok(CameraSocket {
        path: path.to_path_buf(),
    })
}

fn serve_client(conn: UnixStream, mut src: FrameSource) -> std::io::Result<()> {
    let mut reader = BufReader::new(conn.try_clone()?);
    let mut out = std::io::BufWriter::new(conn);
    let mut line = String::new();
    loop {
        line.clear();
        if reader.read_line(&mut line)? == 0 {
            return Ok(());
        }
        let req: Value = match serde_json::from_str(line.trim()) {
            Ok(v) => v,
            Err(e) => {
                writeln!(
                    out,
                    "{}",
                    json!({"ok": false, "error": format!("not JSON: {e}")})
                )?;
                out.flush()?;
                continue;
            }
        };
        match req["cmd"].as_str() {
            Some("info") => {
                let c = src.config();
                let gain = if c.auto_gain {
                    Value::Null
                } else {
                    json!(c.gain)
                };
                writeln!(
                    out,
                    "{}",
                    json!({"ok": true, "width": c.width, "height": c.height, "bit_depth": c.bit_depth, "exposure_ms": c.exposure_ms, "gain": gain, "frame_rate_hz": c.frame_rate_hz})
                )?;
            }
            Some("exposure") => match req["ms"].as_f64().filter(|v| *v > 0.0 && *v < 10_000.0) {
                Some(ms) => {
                    src.set_exposure(ms);
                    writeln!(out, "{}", json!({"ok": true}))?;
                }
                None => writeln!(
                    out,
                    "{}",
                    json!({"ok": false, "error": "exposure needs \"ms\" between 0 and 10000"})
                )?,
            },
            Some("gain") => match &req["value"] {
                Value::Null => {
                    src.set_gain(None);
                    writeln!(out, "{}", json!({"ok": true}))?;
                }
                v => match v.as_f64().filter(|g| *g > 0.0) {
                    Some(g) => {
                        src.set_gain(Some(g));
                        writeln!(out, "{}", json!({"ok": true}))?;
                    }
                    None => writeln!(
                        out,
                        "{}",
                        json!({"ok": false, "error": "gain needs a positive \"value\" or null"})
                    )?,
                },
            },
            Some("now") => {
                writeln!(out, "{}", json!({"ok": true, "t_s": src.now_s()}))?;
            }
            Some("frame") => {
                let f = src.next_frame();
                let bytes: Vec<u8> = f.data.iter().flat_map(|v| v.to_le_bytes()).collect();
                writeln!(
                    out,
                    "{}",
                    json!({"ok": true, "seq": f.seq, "t_s": f.t_s, "width": f.width, "height": f.height, "bit_depth": f.bit_depth, "bytes": bytes.len()})
                )?;
                out.write_all(&bytes)?;
            }
            other => writeln!(
                out,
                "{}",
                json!({"ok": false, "error": format!("unknown cmd {other:?} (info, exposure, gain, now, frame)")})
            )?,
        }
        out.flush()?;
    }
}
