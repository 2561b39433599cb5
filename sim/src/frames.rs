//! The simulated frame grabber: frames of the simulated camera, looking at the world's plate or
//! film wherever the world's stage really is, streamed into buffers as a V4L2 driver does.

use crate::camera::{expose, render_scene, CameraConfig};
use crate::rng::Rng;

/// One frame as the simulated frame grabber delivers it.
#[derive(Debug, Clone)]
pub struct SimFrame {
    pub seq: u64,
    /// When it was captured, on the simulated world's clock (seconds), the clock
    /// [`FrameSource::now_s`] reads: as a V4L2 buffer's timestamp is on the host's monotonic
    /// clock.
    pub t_s: f64,
    pub width: usize,
    pub height: usize,
    pub bit_depth: u32,
    pub data: Vec<u16>,
    /// Where the measuring mark really was (carriage µm): the truth behind this frame.
    pub mark_um: [f64; 2],
}

/// Buffers the simulated driver streams into, as a V4L2 mmap stream does.
pub const BUFFERS: usize = 4;

/// A stream of frames from the simulated camera, looking at the world's plate wherever the
/// world's stage really is. Frames come at the camera's frame rate (time-scaled; never waits at
/// time scale 0); with `drop_p` > 0 frames are lost on the way, leaving gaps in `seq`.
///
/// Like a V4L2 driver streaming into [`BUFFERS`] mmap buffers, the source fills every free
/// buffer as soon as it can and hands out the oldest filled one: after the stage has moved, the
/// first frames dequeued were captured before or during the move, with their capture times.
/// A host must drop them by timestamp (frames before the end of its settle).
pub struct FrameSource {
    world: std::sync::Arc<crate::server::World>,
    cfg: CameraConfig,
    next_seq: u64,
    drop_p: f64,
    rng: Rng,
    started: std::time::Instant,
    /// Sequence numbers lost on the way (the truth of the drop fault).
    pub dropped: Vec<u64>,
    cache: Option<([f64; 2], Vec<f32>)>,
    /// Frames taken since the stage last moved (for the repeatable world).
    here: u64,
    /// Filled buffers not yet handed out, oldest first.
    queue: std::collections::VecDeque<SimFrame>,
}

impl FrameSource {
    pub fn new(world: std::sync::Arc<crate::server::World>, drop_p: f64) -> Self {
        let cfg = world.camera.clone();
        let rng = Rng::new(world.seed ^ 0xF4A3E);
        FrameSource {
            world,
            cfg,
            next_seq: 0,
            drop_p,
            rng,
            started: std::time::Instant::now(),
            dropped: vec![],
            cache: None,
            here: 0,
            queue: std::collections::VecDeque::new(),
        }
    }

    /// The clock of the frames' `t_s`: the simulated world's time, seconds.
    pub fn now_s(&self) -> f64 {
        self.world.stage().t
    }

    /// The next frame: the oldest filled buffer, after every free buffer has been filled with
    /// a frame captured now.
    pub fn next_frame(&mut self) -> SimFrame {
        while self.queue.len() < BUFFERS {
            let f = self.capture();
            self.queue.push_back(f);
        }
        self.queue.pop_front().expect("just filled")
    }

    pub fn config(&self) -> &CameraConfig {
        &self.cfg
    }

    /// Exposure (ms) and gain (`None` = automatic gain).
    pub fn set_exposure(&mut self, ms: f64) {
        self.cfg.exposure_ms = ms;
    }

    pub fn set_gain(&mut self, gain: Option<f64>) {
        self.cfg.auto_gain = gain.is_none();
        self.cfg.gain = gain.unwrap_or(1.0);
    }

    /// Captures the next frame where the stage is now (after the frame period, time-scaled).
    fn capture(&mut self) -> SimFrame {
        loop {
            let seq = self.next_seq;
            self.next_seq += 1;
            let ts = self.world.time_scale;
            if ts > 0.0 {
                // A time scale or frame rate that makes the due time no duration (NaN, huge)
                // means no waiting rather than a panic; no frame waits more than a minute.
                let due = std::time::Duration::try_from_secs_f64(
                    seq as f64 / self.cfg.frame_rate_hz * ts,
                );
                if let Some(wait) = due.ok().and_then(|d| d.checked_sub(self.started.elapsed())) {
                    std::thread::sleep(wait.min(std::time::Duration::from_secs(60)));
                }
            }
            if self.rng.chance(self.drop_p) {
                self.dropped.push(seq);
                continue;
            }
            let (mut mark_um, t_s) = {
                let st = self.world.stage();
                ([st.carriage_true(0), st.carriage_true(1)], st.t)
            };
            if self.world.repeatable {
                // To the nanometre: two paths to one place may differ in a float's last bit.
                mark_um = mark_um.map(|v| (v * 1000.0).round() / 1000.0);
            }
            // The scene only changes when the stage moves.
            let ideal = match &self.cache {
                Some((p, img)) if *p == mark_um => {
                    self.here += 1;
                    img.clone()
                }
                _ => {
                    self.here = 0;
                    let img = render_scene(
                        &self.cfg,
                        &self.world.plate,
                        self.world.film.as_ref(),
                        mark_um,
                    );
                    self.cache = Some((mark_um, img.clone()));
                    img
                }
            };
            // The repeatable world draws a frame's noise from where it was taken and how many
            // came before it there, not from the stream's sequence number.
            let noise_seq = if self.world.repeatable {
                let nm = |v: f64| (v * 1000.0).round() as i64 as u64;
                (nm(mark_um[0]).wrapping_mul(0x9E37_79B9_7F4A_7C15))
                    ^ nm(mark_um[1]).rotate_left(29)
                    ^ self.here.wrapping_mul(0xD6E8_FEB8_6659_FD93)
            } else {
                seq
            };
            let data = expose(&self.cfg, &ideal, self.world.seed, noise_seq);
            return SimFrame {
                seq,
                t_s,
                width: self.cfg.width,
                height: self.cfg.height,
                bit_depth: self.cfg.bit_depth,
                data,
                mark_um,
            };
        }
    }
}
