//! The simulated frame grabber: frames of the simulated camera, looking at the world's plate or
//! film wherever the world's stage really is, streamed into buffers as a V4L2 driver does.

use crate::camera::{expose, render_scene, CameraConfig};
use crate::rng::Rng;

/// What the camera looked at: where the measuring mark was (carriage µm), the film laid or not.
type View = ([f64; 2], bool);

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
/// world's stage really is. Frames come at the camera's frame rate, never faster (time-scaled;
/// never waits at time scale 0); with `drop_p` > 0 frames are lost on the way, leaving gaps in `seq`.
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
    /// The last noiseless image, by where the mark was and whether the film was laid.
    cache: Option<(View, Vec<f32>)>,
    /// The camera clock's tick of the last frame captured (frame periods from the start).
    tick: Option<f64>,
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
            tick: None,
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
            // The camera runs on its own clock: frame k can be captured at k frame periods
            // (time-scaled) from the start, each at the first tick after the last frame and
            // after now. A stream the host left idle does not catch up afterwards with frames
            // faster than the frame rate (counting due times from the sequence number did, and
            // a long scan ran as fast as the frames could be rendered, not at 25 frames a
            // second). A period that is no duration (NaN, huge) means no waiting rather than a
            // panic; no frame waits more than a minute.
            let period = ts / self.cfg.frame_rate_hz;
            if ts > 0.0 && period.is_finite() && period > 0.0 {
                let now = self.started.elapsed().as_secs_f64();
                let k = (now / period).ceil();
                let k = match self.tick {
                    Some(last) => k.max(last + 1.0),
                    None => k,
                };
                self.tick = Some(k);
                let due = std::time::Duration::try_from_secs_f64(k * period);
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
            // The scene only changes when the stage moves or the film is laid or lifted.
            let film = self.world.film_on_carriage();
            let key = (mark_um, film.is_some());
            let ideal = match &self.cache {
                Some((p, img)) if *p == key => {
                    self.here += 1;
                    img.clone()
                }
                _ => {
                    self.here = 0;
                    let img = render_scene(&self.cfg, &self.world.plate, film, mark_um);
                    self.cache = Some((key, img.clone()));
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::server::{SimConfig, World};
    use std::time::{Duration, Instant};

    /// A camera at 25 frames a second, time-scaled by a half: a period of 20 ms (exposing a
    /// frame takes a few).
    fn source() -> FrameSource {
        let world = World::new(&SimConfig {
            time_scale: 0.5,
            ..SimConfig::default()
        });
        FrameSource::new(world, 0.0)
    }

    #[test]
    fn frames_never_come_faster_than_the_frame_rate_even_after_the_host_idled() {
        let mut src = source();
        let period = 0.5 / src.config().frame_rate_hz;
        for _ in 0..3 {
            src.next_frame();
        }
        // The host leaves the stream for 30 periods (a move), then takes 20 frames: a camera
        // on its own clock delivers them one a period (the 4 buffered ones, filled before,
        // aside), not in a burst making up for the idle time.
        std::thread::sleep(Duration::from_secs_f64(30.0 * period));
        let t0 = Instant::now();
        for _ in 0..20 {
            src.next_frame();
        }
        let took = t0.elapsed().as_secs_f64();
        assert!(
            took >= 19.0 * period,
            "20 frames in {:.1} periods",
            took / period
        );
    }
}
