//! The carriage plate: 9 engraved calibration crosses on a 3×3 grid, each off its
//! nominal position by a small engraving error, which a plate certificate would list. This is
//! the world's truth; the host learns it only from a certificate.

use crate::rng::Rng;
use serde::Serialize;

/// One engraved cross, in carriage coordinates (µm).
#[derive(Debug, Clone, Copy, Serialize)]
pub struct Cross {
    /// Grid label, row-major from the origin corner: 1..=9.
    pub id: u32,
    pub nominal_um: [f64; 2],
    /// Where it really is (nominal + engraving error).
    pub true_um: [f64; 2],
}

#[derive(Debug, Clone, Serialize)]
pub struct Plate {
    pub crosses: Vec<Cross>,
    /// Half length of each arm, µm.
    pub arm_um: f64,
    /// Width of the engraved lines, µm.
    pub line_um: f64,
    /// Transmittance of clear glass and of an engraved line (diapositive light).
    pub clear: f64,
    pub line: f64,
    /// Smudges of dirt: (x µm, y µm, radius µm, transmittance).
    pub dirt: Vec<[f64; 4]>,
}

impl Plate {
    /// The plate of a 250 × 250 mm carriage: crosses at 25/125/225 mm on both axes, each
    /// engraved within about ±1.5 µm of nominal.
    pub fn new(rng: &mut Rng) -> Plate {
        let mut crosses = Vec::new();
        for (j, y) in [25_000.0, 125_000.0, 225_000.0].into_iter().enumerate() {
            for (i, x) in [25_000.0, 125_000.0, 225_000.0].into_iter().enumerate() {
                let err = [rng.normal() * 0.8, rng.normal() * 0.8];
                crosses.push(Cross {
                    id: (j * 3 + i + 1) as u32,
                    nominal_um: [x, y],
                    true_um: [x + err[0], y + err[1]],
                });
            }
        }
        Plate {
            crosses,
            arm_um: 1_000.0,
            line_um: 40.0,
            clear: 0.85,
            line: 0.12,
            dirt: Vec::new(),
        }
    }

    /// Crosses whose arms reach within `r` µm of `p`.
    pub fn crosses_near(&self, p: [f64; 2], r: f64) -> impl Iterator<Item = &Cross> {
        let reach = r + self.arm_um + self.line_um;
        self.crosses.iter().filter(move |c| {
            (c.true_um[0] - p[0]).abs() < reach && (c.true_um[1] - p[1]).abs() < reach
        })
    }
}
