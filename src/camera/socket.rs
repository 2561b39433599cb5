//! A simulated camera in another process (`rig-sim --camera-socket PATH`), opened as
//! `sim:PATH`. The protocol is sim/CAMERA_SOCKET.md: JSON request lines, JSON header lines,
//! raw little-endian 16-bit pixels.

use super::{Camera, CameraError, CameraInfo, FormatInfo, Frame, Result, SeqTracker};
use serde_json::{json, Value};
use std::io::{BufRead, BufReader, Read, Write};
use std::os::unix::net::UnixStream;
use std::time::Duration;

pub struct SocketCamera {
    path: String,
    reader: BufReader<UnixStream>,
    writer: UnixStream,
    info: CameraInfo,
    seq: SeqTracker,
}

impl SocketCamera {
    pub fn open(path: &str) -> Result<Self> {
        let conn = UnixStream::connect(path).map_err(|e| CameraError::Open {
            device: format!("sim:{path}"),
            why: format!("{e}; is `rig-sim --camera-socket {path}` running?"),
        })?;
        conn.set_read_timeout(Some(Duration::from_secs(5)))
            .map_err(|e| CameraError::Io(e.to_string()))?;
        let writer = conn
            .try_clone()
            .map_err(|e| CameraError::Io(e.to_string()))?;
        let mut c = SocketCamera {
            path: path.into(),
            reader: BufReader::new(conn),
            writer,
            info: CameraInfo {
                name: "rig-sim camera".into(),
                driver: format!("sim socket {path}"),
                width: 0,
                height: 0,
                bit_depth: 8,
                exposure_ms: None,
                gain: None,
                frame_rate_hz: None,
            },
            seq: SeqTracker::default(),
        };
        let r = c.request(json!({"cmd": "info"}))?;
        // What the camera says of itself is input: sizes, depth and rate in their ranges.
        let num = |k: &str, lo: u64, hi: u64| {
            r[k].as_u64()
                .filter(|v| (lo..=hi).contains(v))
                .ok_or_else(|| {
                    CameraError::Io(format!("camera info: {k} = {} is not in {lo}..={hi}", r[k]))
                })
        };
        c.info.width = num("width", 1, 16_384)? as usize;
        c.info.height = num("height", 1, 16_384)? as usize;
        c.info.bit_depth = num("bit_depth", 1, 16)? as u32;
        c.info.exposure_ms = r["exposure_ms"]
            .as_f64()
            .filter(|v| v.is_finite() && *v > 0.0);
        c.info.gain = r["gain"].as_f64().filter(|v| v.is_finite() && *v > 0.0);
        c.info.frame_rate_hz = r["frame_rate_hz"]
            .as_f64()
            .filter(|v| v.is_finite() && *v > 0.0 && *v < 100_000.0);
        Ok(c)
    }

    fn request(&mut self, req: Value) -> Result<Value> {
        let io = |e: std::io::Error| {
            if matches!(
                e.kind(),
                std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut
            ) {
                CameraError::Timeout(Duration::from_secs(5))
            } else {
                CameraError::Io(format!("sim:{}: {e}", self.path))
            }
        };
        writeln!(self.writer, "{req}").map_err(io)?;
        let mut line = String::new();
        if self.reader.read_line(&mut line).map_err(io)? == 0 {
            return Err(CameraError::Io(format!(
                "sim:{}: the simulator closed the connection",
                self.path
            )));
        }
        let v: Value = serde_json::from_str(line.trim())
            .map_err(|e| CameraError::Io(format!("bad reply {line:?}: {e}")))?;
        if v["ok"] != true {
            return Err(CameraError::Io(format!(
                "the simulated camera refused {req}: {}",
                v["error"]
            )));
        }
        Ok(v)
    }
}

impl Camera for SocketCamera {
    fn info(&self) -> CameraInfo {
        self.info.clone()
    }

    fn formats(&mut self) -> Result<Vec<FormatInfo>> {
        Ok(vec![FormatInfo {
            fourcc: "GREY".into(),
            width: self.info.width,
            height: self.info.height,
            bit_depth: self.info.bit_depth,
            refused: None,
        }])
    }

    fn set_exposure_ms(&mut self, ms: f64) -> Result<()> {
        self.request(json!({"cmd": "exposure", "ms": ms}))?;
        self.info.exposure_ms = Some(ms);
        Ok(())
    }

    fn set_gain(&mut self, gain: Option<f64>) -> Result<()> {
        self.request(json!({"cmd": "gain", "value": gain}))?;
        self.info.gain = gain;
        Ok(())
    }

    fn next_frame(&mut self, timeout: Duration) -> Result<Frame> {
        let _ = self
            .reader
            .get_ref()
            .set_read_timeout(Some(timeout.max(Duration::from_millis(10))));
        let h = self.request(json!({"cmd": "frame"}))?;
        let get = |k: &str| {
            h[k].as_u64()
                .ok_or_else(|| CameraError::Io(format!("frame header without {k}: {h}")))
        };
        let (seq, width, height, bytes) =
            (get("seq")?, get("width")?, get("height")?, get("bytes")?);
        // The camera said its size when it was opened: a frame of another size (or a header
        // asking for gigabytes) is refused before anything is allocated.
        if (width, height) != (self.info.width as u64, self.info.height as u64)
            || Some(bytes) != width.checked_mul(height).and_then(|n| n.checked_mul(2))
        {
            return Err(CameraError::Io(format!(
                "frame {seq}: {bytes} bytes for {width}×{height} pixels; the camera is {}×{}",
                self.info.width, self.info.height
            )));
        }
        let (width, height, bytes) = (self.info.width, self.info.height, bytes as usize);
        let t_s = h["t_s"].as_f64().unwrap_or(f64::NAN);
        let timestamp = super::secs(t_s).ok_or_else(|| {
            CameraError::Io(format!("frame {seq}: timestamp {t_s} is not a time"))
        })?;
        let mut buf = vec![0u8; bytes];
        self.reader
            .read_exact(&mut buf)
            .map_err(|e| CameraError::Io(format!("frame {seq}: {e}")))?;
        self.seq.see(seq);
        Ok(Frame {
            seq,
            timestamp,
            width,
            height,
            bit_depth: get("bit_depth")? as u32,
            data: buf
                .chunks_exact(2)
                .map(|p| u16::from_le_bytes([p[0], p[1]]))
                .collect(),
        })
    }

    fn now(&mut self) -> Result<Duration> {
        let r = self.request(json!({"cmd": "now"}))?;
        let t_s = r["t_s"].as_f64().unwrap_or(f64::NAN);
        super::secs(t_s)
            .ok_or_else(|| CameraError::Io(format!("the camera's clock says {t_s}: not a time")))
    }

    fn dropped(&self) -> u64 {
        self.seq.dropped
    }
}
