//! The form of a mark as primitives (issue 17): dots, rings, bars and spokes, in micrometres
//! about the mark's centre, x along the image's columns and y down its rows (as the carriage
//! axes appear under the camera); angles in degrees from +x toward +y. A cross is two bars, a
//! corner fiducial a dot, a ring and four spokes. The symmetry of the parts decides which
//! geometric parameters least squares can determine ([`MarkShape::geometry`]).

use serde::{Deserialize, Serialize};

/// One primitive. Sizes are radii and full lengths; a ring's radius is its centre line;
/// spokes run radially from `from` to `to`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum Part {
    Dot {
        radius: f64,
    },
    Ring {
        radius: f64,
        width: f64,
    },
    /// A bar through the centre.
    Bar {
        length: f64,
        width: f64,
        #[serde(default)]
        angle_deg: f64,
    },
    /// `count` spokes evenly spaced from `angle0_deg`.
    Spokes {
        count: u32,
        from: f64,
        to: f64,
        width: f64,
        #[serde(default)]
        angle0_deg: f64,
    },
}

/// Most spokes in one part.
pub const MAX_SPOKES: u32 = 360;
/// Most parts in one mark.
pub const MAX_PARTS: usize = 64;

/// (cos, sin) of an angle in degrees.
fn dir(deg: f64) -> [f64; 2] {
    let (s, c) = deg.to_radians().sin_cos();
    [c, s]
}

/// Whether `p` lies on the strip of half-width `hw` along `d` with its along-coordinate in
/// `lo..=hi`.
/// Wholly in (`Some(true)`) when `inside` holds, wholly out when `outside` does, else `None`.
fn either(inside: bool, outside: bool) -> Option<bool> {
    if inside {
        Some(true)
    } else if outside {
        Some(false)
    } else {
        None
    }
}

/// A disk against a union of parts: wholly in when it is wholly in one, wholly out when it is
/// out of every one.
fn union(parts: impl Iterator<Item = Option<bool>>) -> Option<bool> {
    let mut all_out = true;
    for p in parts {
        match p {
            Some(true) => return Some(true),
            Some(false) => {}
            None => all_out = false,
        }
    }
    all_out.then_some(false)
}

fn on_strip(p: [f64; 2], d: [f64; 2], lo: f64, hi: f64, hw: f64) -> bool {
    let along = p[0] * d[0] + p[1] * d[1];
    let across = -p[0] * d[1] + p[1] * d[0];
    across.abs() <= hw && along >= lo && along <= hi
}

impl Part {
    /// Whether the point (the part's units from the centre) is on the part.
    pub fn contains(&self, p: [f64; 2]) -> bool {
        match *self {
            Part::Dot { radius } => p[0].hypot(p[1]) <= radius,
            Part::Ring { radius, width } => (p[0].hypot(p[1]) - radius).abs() <= width / 2.0,
            Part::Bar {
                length,
                width,
                angle_deg,
            } => on_strip(p, dir(angle_deg), -length / 2.0, length / 2.0, width / 2.0),
            Part::Spokes {
                count,
                from,
                to,
                width,
                angle0_deg,
            } => {
                // Only spokes within asin(w/2 / r) of the point's direction can hold it:
                // those around the nearest in angle, not all `count`.
                let step = 360.0 / count as f64;
                let r = p[0].hypot(p[1]);
                // Beyond the spokes' ring of radii nothing (the along-coordinate is at most r).
                if r < from || r > to.hypot(width / 2.0) {
                    return false;
                }
                let a = p[1].atan2(p[0]).to_degrees() - angle0_deg;
                let k = (a / step).round() as i64;
                let spread = (width / 2.0 / r.max(1e-300)).min(1.0).asin().to_degrees();
                let m = ((spread / step).ceil() as i64 + 1).min(count as i64);
                (k - m..=k + m)
                    .any(|k| on_strip(p, dir(angle0_deg + step * k as f64), from, to, width / 2.0))
            }
        }
    }

    /// The cost of one [`Part::contains`] at the worst point, in tests of a strip or circle:
    /// the spokes within asin(w/2 / r) of a point's direction, r at least `from` (or w/2).
    /// Whether every point within `r` µm of `c` is in the part (`Some(true)`), none is
    /// (`Some(false)`), or either may be (`None`). Conservative: a disk on a boundary, or one
    /// too near it to tell, is `None`, so that drawing by samples decides there (the drawn
    /// coverage is the same to the bit).
    pub fn disk(&self, c: [f64; 2], r: f64) -> Option<bool> {
        let strip = |d: [f64; 2], lo: f64, hi: f64, hw: f64| {
            let along = c[0] * d[0] + c[1] * d[1];
            let across = -c[0] * d[1] + c[1] * d[0];
            either(
                across.abs() + r < hw && along - r > lo && along + r < hi,
                across.abs() - r > hw || along + r < lo || along - r > hi,
            )
        };
        let d = c[0].hypot(c[1]);
        match *self {
            Part::Dot { radius } => either(d + r < radius, d - r > radius),
            Part::Ring { radius, width } => {
                let off = (d - radius).abs();
                either(off + r < width / 2.0, off - r > width / 2.0)
            }
            Part::Bar {
                length,
                width,
                angle_deg,
            } => strip(dir(angle_deg), -length / 2.0, length / 2.0, width / 2.0),
            Part::Spokes {
                count,
                from,
                to,
                width,
                angle0_deg,
            } => {
                if d + r < from || d - r > to.hypot(width / 2.0) {
                    Some(false)
                } else if count > 8 {
                    None
                } else {
                    // A few spokes: each one's strip, as a bar from `from` to `to`.
                    let step = 360.0 / count as f64;
                    union(
                        (0..count).map(|k| {
                            strip(dir(angle0_deg + step * k as f64), from, to, width / 2.0)
                        }),
                    )
                }
            }
        }
    }

    pub fn cost(&self) -> f64 {
        match *self {
            Part::Spokes {
                count, from, width, ..
            } => {
                let step = 360.0 / count as f64;
                let r = from.max(width / 2.0).max(1e-300);
                let spread = (width / 2.0 / r).min(1.0).asin().to_degrees();
                let m = ((spread / step).ceil() + 1.0).min(count as f64);
                2.0 * m + 1.0
            }
            _ => 1.0,
        }
    }

    /// How far the part reaches from the centre.
    pub fn reach(&self) -> f64 {
        match *self {
            Part::Dot { radius } => radius,
            Part::Ring { radius, width } => radius + width / 2.0,
            Part::Bar { length, width, .. } => (length / 2.0).hypot(width / 2.0),
            Part::Spokes { to, width, .. } => to.hypot(width / 2.0),
        }
    }

    /// The directions of its lines, degrees in [0, 180): none for dots and rings.
    fn line_directions(&self) -> Vec<f64> {
        let m = |a: f64| a.rem_euclid(180.0);
        match *self {
            Part::Dot { .. } | Part::Ring { .. } => Vec::new(),
            Part::Bar { angle_deg, .. } => vec![m(angle_deg)],
            Part::Spokes {
                count, angle0_deg, ..
            } => (0..count)
                .map(|k| m(angle0_deg + 360.0 * k as f64 / count as f64))
                .collect(),
        }
    }

    /// The same part `s` times larger.
    fn scaled(&self, s: f64) -> Part {
        match *self {
            Part::Dot { radius } => Part::Dot { radius: radius * s },
            Part::Ring { radius, width } => Part::Ring {
                radius: radius * s,
                width: width * s,
            },
            Part::Bar {
                length,
                width,
                angle_deg,
            } => Part::Bar {
                length: length * s,
                width: width * s,
                angle_deg,
            },
            Part::Spokes {
                count,
                from,
                to,
                width,
                angle0_deg,
            } => Part::Spokes {
                count,
                from: from * s,
                to: to * s,
                width: width * s,
                angle0_deg,
            },
        }
    }

    /// The same part turned by `deg`.
    fn turned(&self, deg: f64) -> Part {
        let mut p = self.clone();
        match &mut p {
            Part::Dot { .. } | Part::Ring { .. } => {}
            Part::Bar { angle_deg, .. } => *angle_deg += deg,
            Part::Spokes { angle0_deg, .. } => *angle0_deg += deg,
        }
        p
    }

    /// Its sizes by name, for range checks: (field, value, whether 0 is allowed).
    pub fn sizes(&self) -> Vec<(&'static str, f64, bool)> {
        match *self {
            Part::Dot { radius } => vec![("radius", radius, false)],
            Part::Ring { radius, width } => {
                vec![("radius", radius, false), ("width", width, false)]
            }
            Part::Bar { length, width, .. } => {
                vec![("length", length, false), ("width", width, false)]
            }
            Part::Spokes {
                from, to, width, ..
            } => vec![
                ("from", from, true),
                ("to", to, false),
                ("width", width, false),
            ],
        }
    }
}

/// A mark: the union of its parts, µm about its centre.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MarkShape {
    pub parts: Vec<Part>,
}

impl MarkShape {
    /// An engraved calibration cross: two bars `line_um` wide, each arm `arm_um` from the
    /// centre.
    pub fn cross(arm_um: f64, line_um: f64) -> MarkShape {
        let bar = |angle_deg| Part::Bar {
            length: 2.0 * arm_um,
            width: line_um,
            angle_deg,
        };
        MarkShape {
            parts: vec![bar(0.0), bar(90.0)],
        }
    }

    /// A ring (radius to the middle of its line, `line_um` wide) around a centre dot.
    pub fn ring_with_dot(ring_radius_um: f64, dot_radius_um: f64, line_um: f64) -> MarkShape {
        MarkShape {
            parts: vec![
                Part::Dot {
                    radius: dot_radius_um,
                },
                Part::Ring {
                    radius: ring_radius_um,
                    width: line_um,
                },
            ],
        }
    }

    /// A dot with one line from `from_um` to `to_um` along `direction` (any non-zero vector).
    pub fn dot_with_line(
        dot_radius_um: f64,
        line_um: f64,
        from_um: f64,
        to_um: f64,
        direction: [f64; 2],
    ) -> MarkShape {
        MarkShape {
            parts: vec![
                Part::Dot {
                    radius: dot_radius_um,
                },
                Part::Spokes {
                    count: 1,
                    from: from_um,
                    to: to_um,
                    width: line_um,
                    angle0_deg: direction[1].atan2(direction[0]).to_degrees(),
                },
            ],
        }
    }

    /// Whether the point (µm from the centre) is on the mark.
    pub fn contains(&self, p: [f64; 2]) -> bool {
        self.parts.iter().any(|part| part.contains(p))
    }

    /// Whether the disk of `r` µm about `c` is wholly in the mark, wholly out of it, or
    /// either may be (see [`Part::disk`]).
    pub fn disk(&self, c: [f64; 2], r: f64) -> Option<bool> {
        union(self.parts.iter().map(|part| part.disk(c, r)))
    }

    /// How far the mark reaches from its centre, µm.
    pub fn reach_um(&self) -> f64 {
        self.parts.iter().map(Part::reach).fold(0.0, f64::max)
    }

    /// The form to locate coarsely with. Bars are drawn past the template's border: their ends
    /// then carry no weight, so a cross cut by the frame is found by where its arms cross, and
    /// a pixel spacing a few per cent off does not pull it toward the one end in view.
    pub fn for_coarse(&self) -> MarkShape {
        MarkShape {
            parts: self
                .parts
                .iter()
                .map(|p| match *p {
                    Part::Bar {
                        length,
                        width,
                        angle_deg,
                    } => Part::Bar {
                        length: 100.0 * length,
                        width,
                        angle_deg,
                    },
                    ref other => other.clone(),
                })
                .collect(),
        }
    }

    /// The geometric parameters least squares can determine: rotationally symmetric parts
    /// alone (dots, rings) look the same turned or sheared, so only shifts and scale; lines in
    /// one direction fix a rotation; lines in two or more directions fix all six, as seed
    /// 002's crosses.
    pub fn geometry(&self) -> Geometry {
        let mut dirs: Vec<f64> = Vec::new();
        for d in self.parts.iter().flat_map(Part::line_directions) {
            // Directions within half a degree (also across 0/180) are one.
            let same = |e: &f64| {
                let x = (d - e).abs();
                x.min(180.0 - x) < 0.5
            };
            if !dirs.iter().any(same) {
                dirs.push(d);
            }
        }
        match dirs.len() {
            0 => Geometry::ShiftScale,
            1 => Geometry::Similarity,
            _ => Geometry::Affine,
        }
    }

    /// The same mark `s` times larger (px sizes to µm).
    pub fn scaled(&self, s: f64) -> MarkShape {
        MarkShape {
            parts: self.parts.iter().map(|p| p.scaled(s)).collect(),
        }
    }

    /// The same mark turned by `deg` (from +x toward +y).
    pub fn turned(&self, deg: f64) -> MarkShape {
        MarkShape {
            parts: self.parts.iter().map(|p| p.turned(deg)).collect(),
        }
    }
}

/// Which of the template's geometric parameters least squares may change: the mark's
/// symmetry decides (seed 002 matched crosses with all six). A rotationally symmetric mark
/// (a dot, a ring) determines neither its rotation nor its shear: free, they swing by degrees
/// per iteration and carry the patch out of the template (ring fiducials failed so). The
/// parameters act in micrometres on the carriage (through the template's pixel → µm 2×2),
/// so that a rotation is a rotation on non-square pixels too.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum Geometry {
    /// The two shifts.
    Shift,
    /// Shifts and one scale: dots and rings.
    ShiftScale,
    /// Shifts, scale and rotation: marks with one or more lines or spokes.
    Similarity,
    /// The full affine: crosses, as seed 002.
    #[default]
    Affine,
}

impl Geometry {
    /// The number of geometric parameters.
    pub fn count(self) -> usize {
        match self {
            Geometry::Shift => 2,
            Geometry::ShiftScale => 3,
            Geometry::Similarity => 4,
            Geometry::Affine => 6,
        }
    }
}

/// Range checks of a list of parts; `at` prefixes the messages (e.g. `[shapes.corner] `).
pub fn check_parts(parts: &[Part], at: &str, lo: f64, hi: f64, unit: &str) -> Result<(), String> {
    if parts.is_empty() {
        return Err(format!(
            "{at}no [[part]]: a mark needs at least one (dot, ring, bar or spokes)"
        ));
    }
    if parts.len() > MAX_PARTS {
        return Err(format!("{at}{} parts; at most {MAX_PARTS}", parts.len()));
    }
    for (i, p) in parts.iter().enumerate() {
        let name = format!("{at}part {} ({})", i + 1, kind(p));
        for (field, v, zero_ok) in p.sizes() {
            let ok = v.is_finite() && ((zero_ok && v == 0.0) || (lo..=hi).contains(&v));
            if !ok {
                return Err(format!(
                    "{name}: {field} {v}: from {lo} to {hi} {unit}{}",
                    if zero_ok { " (or 0)" } else { "" }
                ));
            }
        }
        match *p {
            Part::Bar { angle_deg: a, .. } | Part::Spokes { angle0_deg: a, .. }
                if !(a.is_finite() && a.abs() <= 360.0) =>
            {
                return Err(format!("{name}: angle {a}: from -360 to 360 degrees"));
            }
            Part::Spokes { count, .. } if !(1..=MAX_SPOKES).contains(&count) => {
                return Err(format!("{name}: count {count}: from 1 to {MAX_SPOKES}"));
            }
            Part::Spokes { from, to, .. } if to <= from => {
                return Err(format!(
                    "{name}: from {from} and to {to}: spokes run outward, from < to"
                ));
            }
            Part::Ring { radius, width } if width / 2.0 > radius => {
                return Err(format!(
                    "{name}: width {width} is more than twice the radius {radius}: use a dot"
                ));
            }
            _ => {}
        }
    }
    Ok(())
}

fn kind(p: &Part) -> &'static str {
    match p {
        Part::Dot { .. } => "dot",
        Part::Ring { .. } => "ring",
        Part::Bar { .. } => "bar",
        Part::Spokes { .. } => "spokes",
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shapes_contain_what_their_geometry_says() {
        let ring = MarkShape::ring_with_dot(300.0, 40.0, 40.0);
        assert!(ring.contains([0.0, 39.0]) && ring.contains([310.0, 0.0]));
        assert!(!ring.contains([100.0, 0.0]) && !ring.contains([0.0, 330.0]));
        let dl = MarkShape::dot_with_line(60.0, 40.0, 150.0, 600.0, [0.0, -1.0]);
        assert!(dl.contains([0.0, -400.0]) && !dl.contains([0.0, 400.0]));
        assert!(!dl.contains([0.0, -100.0]) && dl.contains([50.0, 0.0]));
        assert_eq!(ring.reach_um(), 320.0);
        let cross = MarkShape::cross(1000.0, 40.0);
        assert!(cross.contains([990.0, 19.0]) && cross.contains([-19.0, -990.0]));
        assert!(!cross.contains([1010.0, 0.0]) && !cross.contains([30.0, 30.0]));
        // Four spokes at 45°: on the diagonals only.
        let spokes = MarkShape {
            parts: vec![Part::Spokes {
                count: 4,
                from: 10.0,
                to: 20.0,
                width: 2.0,
                angle0_deg: 45.0,
            }],
        };
        let d = 15.0 / 2f64.sqrt();
        for p in [[d, d], [-d, d], [-d, -d], [d, -d]] {
            assert!(spokes.contains(p), "{p:?}");
        }
        assert!(!spokes.contains([15.0, 0.0]) && !spokes.contains([0.0, 5.0]));
    }

    /// The spokes' test by the nearest angles agrees with testing every spoke.
    #[test]
    fn spokes_by_angle_are_spokes_by_brute_force() {
        let mut seed = 1u64;
        let mut u = || {
            seed = seed
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (seed >> 11) as f64 / (1u64 << 53) as f64
        };
        for (count, from, to, width, a0) in [
            (4, 17.0, 22.0, 2.0, 0.0),
            (1, 5.0, 30.0, 3.0, -37.0),
            (360, 0.0, 40.0, 4.0, 0.5),
            (7, 0.0, 10.0, 25.0, 200.0),
            (3, 2.0, 9.0, 0.3, 90.0),
        ] {
            let part = Part::Spokes {
                count,
                from,
                to,
                width,
                angle0_deg: a0,
            };
            for _ in 0..20_000 {
                let p = [(u() - 0.5) * 100.0, (u() - 0.5) * 100.0];
                let brute = (0..count).any(|k| {
                    let a = a0 + 360.0 * k as f64 / count as f64;
                    on_strip(p, dir(a), from, to, width / 2.0)
                });
                assert_eq!(part.contains(p), brute, "{count} spokes at {p:?}");
            }
        }
    }

    #[test]
    fn the_geometry_follows_the_symmetry() {
        assert_eq!(
            MarkShape::ring_with_dot(300.0, 40.0, 40.0).geometry(),
            Geometry::ShiftScale
        );
        assert_eq!(
            MarkShape::dot_with_line(60.0, 40.0, 150.0, 600.0, [1.0, 1.0]).geometry(),
            Geometry::Similarity
        );
        assert_eq!(MarkShape::cross(1000.0, 40.0).geometry(), Geometry::Affine);
        // Two spokes make one line; a bar at 180° is the one at 0°.
        let two = |count, angle_deg| MarkShape {
            parts: vec![
                Part::Spokes {
                    count,
                    from: 1.0,
                    to: 2.0,
                    width: 0.5,
                    angle0_deg: 10.0,
                },
                Part::Bar {
                    length: 4.0,
                    width: 0.5,
                    angle_deg,
                },
            ],
        };
        assert_eq!(two(2, 190.0).geometry(), Geometry::Similarity);
        assert_eq!(two(2, 100.0).geometry(), Geometry::Affine);
        assert_eq!(two(4, 10.0).geometry(), Geometry::Affine);
    }
}
