//! A film on the carriage: an RC10-like frame (230 mm, fiducial centre as photo origin) with 8
//! fiducials of two shapes (4 corner rings with a centre dot; 4 mid-side dots with short lines
//! pointing to the centre), laid on the carriage with an unknown shift, rotation and slight
//! film deformation, all part of the truth. The picture area carries an aerial photo rendered
//! from a DEM ([`crate::scene`]).

use crate::edges::{band, disk};
use crate::rng::Rng;
use crate::scene::AerialPhoto;
use serde::Serialize;
use std::sync::Arc;

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum FiducialShape {
    /// A ring (radius 300 µm) around a centre dot (radius 40 µm); lines 40 µm wide.
    RingWithDot,
    /// A dot (radius 60 µm) with a line 40 µm wide from 150 to 600 µm toward the photo centre.
    DotWithLine,
    /// A ring (radius 300 µm) around a centre dot (radius 40 µm) with four radial lines from
    /// 340 to 440 µm along the photo axes; lines 40 µm wide (corner fiducials of cameras
    /// whose mid-sides are plain rings).
    RingDotSpokes,
    /// The film's own mark ([`Film::mark_file`]), from a mark file.
    FromFile,
}

#[derive(Debug, Clone, Copy, Serialize)]
pub struct Fiducial {
    pub id: u32,
    pub shape: FiducialShape,
    /// Where the fiducial really is, photo mm.
    pub photo_mm: [f64; 2],
    /// The camera certificate's error for it, µm: the certificate lists photo_mm + this.
    /// Seed 002: the mid-side fiducials "are not so precisely calibrated" as the corners.
    pub cert_error_um: [f64; 2],
    /// Not on the film (never exposed, or damaged away).
    pub missing: bool,
}

#[derive(Debug, Clone, Serialize)]
pub struct Film {
    pub fiducials: Vec<Fiducial>,
    /// Photo (mm) → carriage (µm): `x = p[0] + p[1]·u + p[2]·v`, `y = p[3] + p[4]·u + p[5]·v`.
    pub photo_to_carriage: [f64; 6],
    /// Transmittance of the clear film base and of a fiducial's dark.
    pub base: f64,
    pub mark: f64,
    /// Half-size of the film frame and of the picture area, mm.
    pub frame_half_mm: f64,
    pub picture_half_mm: f64,
    /// Which photo of the block this film is (1–4).
    pub photo_number: u32,
    /// The aerial photo in the picture area (none: clear base).
    pub aerial: Option<Arc<AerialPhoto>>,
    /// Every fiducial's form, when a mark file gives it.
    pub mark_file: Option<crate::marks::SimMark>,
}

const LINE_UM: f64 = 40.0;

impl Film {
    /// The same film with every fiducial of the form `mark` (from a mark file).
    pub fn with_mark(mut self, mark: crate::marks::SimMark) -> Film {
        for f in self.fiducials.iter_mut() {
            f.shape = FiducialShape::FromFile;
        }
        self.mark_file = Some(mark);
        self
    }

    /// The same film from a camera whose corner fiducials are rings with a dot and four
    /// radial lines and whose mid-side fiducials are rings with a dot (the certificate errors
    /// stay those of the corners and mid-sides).
    pub fn with_ring_fiducials(mut self) -> Film {
        for f in self.fiducials.iter_mut() {
            f.shape = if f.id <= 4 {
                FiducialShape::RingDotSpokes
            } else {
                FiducialShape::RingWithDot
            };
        }
        self
    }

    /// Photo `number` of an RC10-like camera laid on the middle of the carriage, slightly
    /// shifted, rotated and deformed. The camera (its fiducials and their certificate) comes
    /// from `rng`; how the film lies from `rng` and the photo's number, so each photo of a
    /// block lies differently. The aerial picture is added by [`Film::with_aerial`].
    pub fn rc10(rng: &mut Rng, number: u32) -> Film {
        let mut fiducials = Vec::new();
        let mut cal = |x: f64, y: f64| [x + 0.005 * rng.normal(), y + 0.005 * rng.normal()];
        for (i, (x, y)) in [
            (-106.0, -106.0),
            (106.0, -106.0),
            (106.0, 106.0),
            (-106.0, 106.0),
        ]
        .into_iter()
        .enumerate()
        {
            fiducials.push(Fiducial {
                id: i as u32 + 1,
                shape: FiducialShape::RingWithDot,
                photo_mm: cal(x, y),
                cert_error_um: [0.0; 2],
                missing: false,
            });
        }
        for (i, (x, y)) in [(0.0, -112.0), (112.0, 0.0), (0.0, 112.0), (-112.0, 0.0)]
            .into_iter()
            .enumerate()
        {
            fiducials.push(Fiducial {
                id: i as u32 + 5,
                shape: FiducialShape::DotWithLine,
                photo_mm: cal(x, y),
                cert_error_um: [0.0; 2],
                missing: false,
            });
        }
        // The camera's certificate errors from their own stream: corners σ 0.3 µm, mid-sides
        // 2 µm (seed 002: the mid-sides "are not so precisely calibrated").
        let camera_seed = rng.next_u64();
        let mut cert = Rng::new(camera_seed ^ 0xCE27_1F1C);
        for f in fiducials.iter_mut() {
            let s = if f.id <= 4 { 0.3 } else { 2.0 };
            f.cert_error_um = [s * cert.normal(), s * cert.normal()];
        }
        let mut lay = Rng::new(camera_seed ^ (number as u64).wrapping_mul(0xA24B_AED4_963E_E407));
        let rng = &mut lay;
        let rot = (rng.uniform() - 0.5) * 0.6f64.to_radians();
        let (sx, sy, shear) = (
            1.0 + 2e-4 * rng.normal(),
            1.0 + 2e-4 * rng.normal(),
            1e-4 * rng.normal(),
        );
        let (c, s) = (rot.cos(), rot.sin());
        let centre = [
            125_000.0 + 800.0 * rng.normal(),
            125_000.0 + 800.0 * rng.normal(),
        ];
        // µm per mm, with the deformation, then the rotation.
        let (a1, a2) = (1000.0 * sx, 1000.0 * shear);
        let (b1, b2) = (0.0, 1000.0 * sy);
        let photo_to_carriage = [
            centre[0],
            c * a1 - s * b1,
            c * a2 - s * b2,
            centre[1],
            s * a1 + c * b1,
            s * a2 + c * b2,
        ];
        Film {
            fiducials,
            photo_to_carriage,
            base: 0.9,
            mark: 0.08,
            frame_half_mm: 116.0,
            picture_half_mm: 100.0,
            photo_number: number,
            aerial: None,
            mark_file: None,
        }
    }

    /// The same film with its aerial photo rendered over the terrain of the world `seed`.
    pub fn with_aerial(mut self, seed: u64) -> Film {
        self.aerial = Some(Arc::new(AerialPhoto::new(
            crate::scene::jacksboro(),
            seed,
            self.photo_number,
            self.picture_half_mm + 1.0,
        )));
        self
    }

    pub fn to_carriage(&self, photo_mm: [f64; 2]) -> [f64; 2] {
        let p = &self.photo_to_carriage;
        [
            p[0] + p[1] * photo_mm[0] + p[2] * photo_mm[1],
            p[3] + p[4] * photo_mm[0] + p[5] * photo_mm[1],
        ]
    }

    pub fn to_photo(&self, carriage_um: [f64; 2]) -> [f64; 2] {
        let p = &self.photo_to_carriage;
        let det = p[1] * p[5] - p[2] * p[4];
        let (dx, dy) = (carriage_um[0] - p[0], carriage_um[1] - p[3]);
        [
            (p[5] * dx - p[2] * dy) / det,
            (-p[4] * dx + p[1] * dy) / det,
        ]
    }

    /// The picture's transmittance at photo coordinates (mm): the aerial photo, or the
    /// clear base where there is none.
    pub fn picture(&self, u: f64, v: f64) -> f64 {
        match &self.aerial {
            Some(a) => self.base * a.transmittance([u, v]),
            None => self.base,
        }
    }

    /// Transmittance of the film at carriage point `c` (µm), blurred by `s` µm; 1 off the film.
    pub fn transmittance(&self, c: [f64; 2], s: f64) -> f64 {
        let [u, v] = self.to_photo(c);
        if u.abs() > self.frame_half_mm || v.abs() > self.frame_half_mm {
            return 1.0;
        }
        if u.abs() <= self.picture_half_mm && v.abs() <= self.picture_half_mm {
            return self.picture(u, v);
        }
        let mut clear = 1.0;
        for f in self.fiducials.iter().filter(|f| !f.missing) {
            let d = [(u - f.photo_mm[0]) * 1000.0, (v - f.photo_mm[1]) * 1000.0];
            let r = d[0].hypot(d[1]);
            let reach = self
                .mark_file
                .as_ref()
                .map_or(1_000.0, |m| m.reach_um().max(1_000.0));
            if r > reach {
                continue;
            }
            let cov = match f.shape {
                FiducialShape::FromFile => {
                    self.mark_file.as_ref().map_or(0.0, |m| m.coverage(d, s))
                }
                FiducialShape::RingDotSpokes => {
                    let ring = band(r - 300.0, LINE_UM / 2.0, s);
                    let dot = disk(r, 40.0, s);
                    // Four spokes along ±u and ±v: two bars of 340–440 µm each way.
                    let spoke = |along: f64, across: f64| {
                        band(across, LINE_UM / 2.0, s) * band(along.abs() - 390.0, 50.0, s)
                    };
                    let (h, v) = (spoke(d[0], d[1]), spoke(d[1], d[0]));
                    let mut clear = 1.0;
                    for c in [ring, dot, h, v] {
                        clear *= 1.0 - c;
                    }
                    1.0 - clear
                }
                FiducialShape::RingWithDot => {
                    let ring = band(r - 300.0, LINE_UM / 2.0, s);
                    let dot = disk(r, 40.0, s);
                    ring + dot - ring * dot
                }
                FiducialShape::DotWithLine => {
                    let n = f.photo_mm[0].hypot(f.photo_mm[1]);
                    let inward = [-f.photo_mm[0] / n, -f.photo_mm[1] / n];
                    let along = d[0] * inward[0] + d[1] * inward[1];
                    let across = -d[0] * inward[1] + d[1] * inward[0];
                    let line = band(across, LINE_UM / 2.0, s) * band(along - 375.0, 225.0, s);
                    let dot = disk(r, 60.0, s);
                    line + dot - line * dot
                }
            };
            clear *= 1.0 - cov;
        }
        self.base * (1.0 - (1.0 - self.mark / self.base) * (1.0 - clear))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn placement_inverts() {
        let f = Film::rc10(&mut Rng::new(3), 1);
        for p in [[0.0, 0.0], [106.0, -106.0], [-50.5, 77.25]] {
            let q = f.to_photo(f.to_carriage(p));
            assert!((q[0] - p[0]).abs() < 1e-9 && (q[1] - p[1]).abs() < 1e-9);
        }
        // Fiducials stay inside the 250 mm travel.
        for fid in &f.fiducials {
            let c = f.to_carriage(fid.photo_mm);
            assert!(c.iter().all(|&v| v > 2_000.0 && v < 248_000.0), "{c:?}");
        }
    }

    #[test]
    fn fiducials_are_dark_at_their_centre_and_clear_around() {
        let f = Film::rc10(&mut Rng::new(4), 1);
        for fid in &f.fiducials {
            let c = f.to_carriage(fid.photo_mm);
            assert!(f.transmittance(c, 5.0) < 0.15, "{:?} centre", fid.id);
            // 200 µm off the centre, away from every line: clear base.
            let off = f.to_carriage([
                fid.photo_mm[0] + 0.15 * fid.photo_mm[1].signum(),
                fid.photo_mm[1] - 0.15 * fid.photo_mm[0].signum(),
            ]);
            assert!(f.transmittance(off, 5.0) > 0.85, "{:?} surround", fid.id);
        }
    }
}
