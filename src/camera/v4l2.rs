//! Video4Linux2 cameras and frame grabbers (the `v4l` crate, mmap streaming). Chooses the best
//! greyscale format the device offers (Y16, Y12, Y10, GREY, then the luma of YUYV) at its largest
//! size, refuses lossy formats for measurement, drives exposure and gain where the device has
//! them, and counts gaps in the driver's sequence numbers as dropped frames.

use super::convert::{classify, preference, to_grey16, Grey};
use super::{Camera, CameraError, CameraInfo, FormatInfo, Frame, Result, SeqTracker};
use std::time::Duration;
use v4l::buffer::Type;
use v4l::control::{Control, Value};
use v4l::io::mmap::Stream;
use v4l::io::traits::CaptureStream;
use v4l::video::Capture;
use v4l::{Device, FourCC};

// Control ids from <linux/v4l2-controls.h>.
const CID_EXPOSURE_AUTO: u32 = 0x009a_0901;
const CID_EXPOSURE_ABSOLUTE: u32 = 0x009a_0902; // units of 100 µs
const CID_AUTOGAIN: u32 = 0x0098_0912;
const CID_GAIN: u32 = 0x0098_0913;
const EXPOSURE_MANUAL: i64 = 1;

/// Devices present, as (path, name).
pub fn list_devices() -> Vec<(String, String)> {
    v4l::context::enum_devices()
        .into_iter()
        .map(|n| (n.path().display().to_string(), n.name().unwrap_or_default()))
        .collect()
}

pub struct V4l2Camera {
    path: String,
    dev: Device,
    stream: Option<Stream<'static>>,
    fourcc: [u8; 4],
    width: usize,
    height: usize,
    stride: usize,
    bit_depth: u32,
    name: String,
    exposure_ms: Option<f64>,
    gain: Option<f64>,
    seq: SeqTracker,
}

fn io(e: std::io::Error) -> CameraError {
    CameraError::Io(e.to_string())
}

impl V4l2Camera {
    /// Opens `path` (e.g. /dev/video0) and sets the best greyscale format at its largest size.
    pub fn open(path: &str) -> Result<Self> {
        let open_err = |why: String| CameraError::Open {
            device: path.into(),
            why,
        };
        let dev = Device::with_path(path).map_err(|e| open_err(e.to_string()))?;
        let caps = dev.query_caps().map_err(|e| open_err(e.to_string()))?;
        let formats = dev.enum_formats().map_err(|e| open_err(e.to_string()))?;
        let best = formats
            .iter()
            .filter(|f| matches!(classify(&f.fourcc.repr), Grey::Bits(_)))
            .max_by_key(|f| preference(&f.fourcc.repr))
            .ok_or_else(|| CameraError::NoUsableFormat {
                device: path.into(),
                why: format!(
                    "it offers {}; the rig needs GREY, Y10, Y12, Y16 or YUYV (lossy formats such as MJPG move edges)",
                    formats.iter().map(|f| String::from_utf8_lossy(&f.fourcc.repr).trim().to_string()).collect::<Vec<_>>().join(", ")
                ),
            })?;
        let fourcc = best.fourcc.repr;
        let (w, h) = dev
            .enum_framesizes(best.fourcc)
            .map_err(io)?
            .into_iter()
            .flat_map(|s| s.size.to_discrete())
            .map(|d| (d.width, d.height))
            .max_by_key(|&(w, h)| w as u64 * h as u64)
            .unwrap_or((640, 480));
        let mut fmt = dev.format().map_err(io)?;
        fmt.width = w;
        fmt.height = h;
        fmt.fourcc = FourCC::new(&fourcc);
        let fmt = dev.set_format(&fmt).map_err(io)?;
        if fmt.fourcc.repr != fourcc {
            return Err(open_err(format!(
                "the driver would not set {}",
                String::from_utf8_lossy(&fourcc)
            )));
        }
        let Grey::Bits(bit_depth) = classify(&fourcc) else {
            unreachable!("chosen among usable formats")
        };
        Ok(V4l2Camera {
            path: path.into(),
            dev,
            stream: None,
            fourcc,
            width: fmt.width as usize,
            height: fmt.height as usize,
            stride: fmt.stride as usize,
            bit_depth,
            name: caps.card,
            exposure_ms: None,
            gain: None,
            seq: SeqTracker::default(),
        })
    }

    fn set(&mut self, id: u32, v: i64, what: &'static str) -> Result<()> {
        self.dev
            .set_control(Control {
                id,
                value: Value::Integer(v),
            })
            .map_err(|_| CameraError::Unsupported(what))
    }
}

impl Camera for V4l2Camera {
    fn info(&self) -> CameraInfo {
        CameraInfo {
            name: self.name.clone(),
            driver: format!(
                "v4l2 {} {}",
                self.path,
                String::from_utf8_lossy(&self.fourcc).trim()
            ),
            width: self.width,
            height: self.height,
            bit_depth: self.bit_depth,
            exposure_ms: self.exposure_ms,
            gain: self.gain,
            frame_rate_hz: None,
        }
    }

    fn formats(&mut self) -> Result<Vec<FormatInfo>> {
        let mut out = Vec::new();
        for f in self.dev.enum_formats().map_err(io)? {
            let (bits, refused) = match classify(&f.fourcc.repr) {
                Grey::Bits(b) => (b, None),
                Grey::Refused(why) => (0, Some(why.to_string())),
            };
            for s in self.dev.enum_framesizes(f.fourcc).map_err(io)? {
                for d in s.size.to_discrete() {
                    out.push(FormatInfo {
                        fourcc: String::from_utf8_lossy(&f.fourcc.repr).trim().to_string(),
                        width: d.width as usize,
                        height: d.height as usize,
                        bit_depth: bits,
                        refused: refused.clone(),
                    });
                }
            }
        }
        Ok(out)
    }

    fn set_exposure_ms(&mut self, ms: f64) -> Result<()> {
        self.set(CID_EXPOSURE_AUTO, EXPOSURE_MANUAL, "manual exposure")?;
        self.set(
            CID_EXPOSURE_ABSOLUTE,
            (ms * 10.0).round() as i64,
            "exposure",
        )?;
        self.exposure_ms = Some(ms);
        Ok(())
    }

    fn set_gain(&mut self, gain: Option<f64>) -> Result<()> {
        match gain {
            None => self.set(CID_AUTOGAIN, 1, "automatic gain")?,
            Some(g) => {
                self.set(CID_AUTOGAIN, 0, "manual gain")?;
                self.set(CID_GAIN, g.round() as i64, "gain")?;
            }
        }
        self.gain = gain;
        Ok(())
    }

    fn next_frame(&mut self, timeout: Duration) -> Result<Frame> {
        if self.stream.is_none() {
            let mut s = Stream::with_buffers(&self.dev, Type::VideoCapture, 4).map_err(io)?;
            s.set_timeout(timeout);
            self.stream = Some(s);
        }
        let s = self.stream.as_mut().expect("just started");
        let (buf, meta) = s.next().map_err(|e| {
            if e.kind() == std::io::ErrorKind::TimedOut {
                CameraError::Timeout(timeout)
            } else {
                io(e)
            }
        })?;
        let used = &buf[..(meta.bytesused as usize).min(buf.len())];
        let (data, bit_depth) = to_grey16(&self.fourcc, self.width, self.height, self.stride, used)
            .map_err(|e| CameraError::Io(e.to_string()))?;
        let seq = meta.sequence as u64;
        self.seq.see(seq);
        // V4L2 stamps buffers on the monotonic clock (V4L2_BUF_FLAG_TIMESTAMP_MONOTONIC, what
        // UVC and most capture drivers use), the clock `now` reads.
        // time_t and suseconds_t are 32 bits on some targets.
        #[allow(clippy::unnecessary_cast)]
        let (sec, usec) = (meta.timestamp.sec as i64, meta.timestamp.usec as i64);
        if sec < 0 || !(0..1_000_000).contains(&usec) {
            return Err(CameraError::Io(format!(
                "frame {seq}: timestamp {sec} s {usec} µs is not a time"
            )));
        }
        Ok(Frame {
            seq,
            timestamp: Duration::from_secs(sec as u64) + Duration::from_micros(usec as u64),
            width: self.width,
            height: self.height,
            bit_depth,
            data,
        })
    }

    /// CLOCK_MONOTONIC, the clock of V4L2's buffer timestamps.
    fn now(&mut self) -> Result<Duration> {
        let mut ts = libc::timespec {
            tv_sec: 0,
            tv_nsec: 0,
        };
        // SAFETY: clock_gettime writes one timespec we own.
        let r = unsafe { libc::clock_gettime(libc::CLOCK_MONOTONIC, &mut ts) };
        if r != 0 || ts.tv_sec < 0 {
            return Err(CameraError::Io(
                "clock_gettime(CLOCK_MONOTONIC) failed".into(),
            ));
        }
        Ok(Duration::new(
            ts.tv_sec as u64,
            ts.tv_nsec.clamp(0, 999_999_999) as u32,
        ))
    }

    fn dropped(&self) -> u64 {
        self.seq.dropped
    }
}
