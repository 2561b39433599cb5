//! Fiducials of any form for the simulated film: a mark file of primitives (dot, ring, bar,
//! spokes, sizes in µm; the format `rig measure` reads) drawn with the optics' blur in closed
//! form. The simulator parses and draws it with its own code, so the host's templates are
//! checked against an independent drawing of the same description.

use crate::edges::{band, disk};
use serde::{Deserialize, Serialize};
use std::path::Path;

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum SimPart {
    Dot {
        radius: f64,
    },
    Ring {
        radius: f64,
        width: f64,
    },
    Bar {
        length: f64,
        width: f64,
        #[serde(default)]
        angle_deg: f64,
    },
    Spokes {
        count: u32,
        from: f64,
        to: f64,
        width: f64,
        #[serde(default)]
        angle0_deg: f64,
    },
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct File {
    units: String,
    #[serde(default)]
    polarity: Option<String>,
    part: Vec<SimPart>,
}

/// A mark of primitives, µm about its centre (x, y as the film's photo axes).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct SimMark {
    pub parts: Vec<SimPart>,
}

impl SimMark {
    /// Reads a mark file; only `units = "um"` and dark marks (the film's fiducials are dark
    /// on its clear base), sizes up to 5 mm, at most 64 parts and 360 spokes.
    pub fn load(path: &Path) -> Result<SimMark, String> {
        let text = std::fs::read_to_string(path).map_err(|e| format!("{}: {e}", path.display()))?;
        Self::parse(&text, path)
    }

    pub fn parse(text: &str, path: &Path) -> Result<SimMark, String> {
        let f: File = toml_parse(text).map_err(|e| format!("{}: {e}", path.display()))?;
        let bad = |m: String| Err(format!("{}: {m}", path.display()));
        if f.units != "um" {
            return bad(format!(
                "units = \"{}\": the simulated film's fiducials are given in µm (units = \"um\")",
                f.units
            ));
        }
        if f.polarity.as_deref().is_some_and(|p| p != "dark_on_bright") {
            return bad(
                "the film's fiducials are dark on its clear base (polarity = \"dark_on_bright\")"
                    .into(),
            );
        }
        if f.part.is_empty() || f.part.len() > 64 {
            return bad(format!("{} parts: 1 to 64", f.part.len()));
        }
        for (i, p) in f.part.iter().enumerate() {
            let sizes: Vec<f64> = match *p {
                SimPart::Dot { radius } => vec![radius],
                SimPart::Ring { radius, width } => vec![radius, width],
                SimPart::Bar { length, width, .. } => vec![length, width],
                SimPart::Spokes {
                    count, to, width, ..
                } => {
                    if !(1..=360).contains(&count) {
                        return bad(format!("part {}: count {count}: 1 to 360", i + 1));
                    }
                    vec![to, width]
                }
            };
            // The rig's own bounds for a certificate's marks (1 µm to 10 mm, angles ±360°),
            // so that the certificate written from it reads.
            if sizes
                .iter()
                .any(|v| !(v.is_finite() && (1.0..=10_000.0).contains(v)))
            {
                return bad(format!("part {}: sizes from 1 to 10000 µm", i + 1));
            }
            if let SimPart::Ring { radius, width } = *p {
                if width / 2.0 > radius {
                    return bad(format!(
                        "part {}: a ring wider than twice its radius",
                        i + 1
                    ));
                }
            }
            let angle_ok = match *p {
                SimPart::Bar { angle_deg: a, .. } => a.is_finite() && a.abs() <= 360.0,
                SimPart::Spokes {
                    angle0_deg: a,
                    from,
                    to,
                    ..
                } => {
                    a.is_finite()
                        && a.abs() <= 360.0
                        && from.is_finite()
                        && from >= 0.0
                        && from < to
                }
                _ => true,
            };
            if !angle_ok {
                return bad(format!(
                    "part {}: angles within ±360°, 0 <= from < to",
                    i + 1
                ));
            }
        }
        Ok(SimMark { parts: f.part })
    }

    /// How far it reaches from its centre, µm.
    pub fn reach_um(&self) -> f64 {
        self.parts
            .iter()
            .map(|p| match *p {
                SimPart::Dot { radius } => radius,
                SimPart::Ring { radius, width } => radius + width,
                SimPart::Bar { length, width, .. } => length / 2.0 + width,
                SimPart::Spokes { to, width, .. } => to + width,
            })
            .fold(0.0, f64::max)
    }

    /// Coverage (0–1) at `d` µm from the centre, each edge softened by a Gaussian of σ `s` µm;
    /// overlapping parts combine as independent coverages.
    pub fn coverage(&self, d: [f64; 2], s: f64) -> f64 {
        let r = d[0].hypot(d[1]);
        let strip = |deg: f64, mid: f64, half_len: f64, half_w: f64| {
            let (sn, cs) = deg.to_radians().sin_cos();
            let along = d[0] * cs + d[1] * sn;
            let across = -d[0] * sn + d[1] * cs;
            band(across, half_w, s) * band(along - mid, half_len, s)
        };
        let mut clear = 1.0;
        for p in &self.parts {
            match *p {
                SimPart::Dot { radius } => clear *= 1.0 - disk(r, radius, s),
                SimPart::Ring { radius, width } => clear *= 1.0 - band(r - radius, width / 2.0, s),
                SimPart::Bar {
                    length,
                    width,
                    angle_deg,
                } => clear *= 1.0 - strip(angle_deg, 0.0, length / 2.0, width / 2.0),
                SimPart::Spokes {
                    count,
                    from,
                    to,
                    width,
                    angle0_deg,
                } => {
                    for k in 0..count {
                        let deg = angle0_deg + 360.0 * k as f64 / count as f64;
                        clear *=
                            1.0 - strip(deg, (from + to) / 2.0, (to - from) / 2.0, width / 2.0);
                    }
                }
            }
        }
        1.0 - clear
    }

    /// The mark as a camera certificate's `[shapes.NAME]` of `kind = "parts"`.
    pub fn certificate_shape(&self, name: &str) -> String {
        let mut s = format!("\n[shapes.{name}]\nkind = \"parts\"\n");
        for p in &self.parts {
            s += &format!("[[shapes.{name}.part]]\n");
            match *p {
                SimPart::Dot { radius } => s += &format!("kind = \"dot\"\nradius = {radius:?}\n"),
                SimPart::Ring { radius, width } => {
                    s += &format!("kind = \"ring\"\nradius = {radius:?}\nwidth = {width:?}\n")
                }
                SimPart::Bar {
                    length,
                    width,
                    angle_deg,
                } => {
                    s += &format!(
                        "kind = \"bar\"\nlength = {length:?}\nwidth = {width:?}\nangle_deg = {angle_deg:?}\n"
                    )
                }
                SimPart::Spokes {
                    count,
                    from,
                    to,
                    width,
                    angle0_deg,
                } => {
                    s += &format!(
                        "kind = \"spokes\"\ncount = {count}\nfrom = {from:?}\nto = {to:?}\nwidth = {width:?}\nangle0_deg = {angle0_deg:?}\n"
                    )
                }
            }
        }
        s
    }
}

fn toml_parse(text: &str) -> Result<File, String> {
    toml::from_str(text).map_err(|e| e.to_string().trim_end().to_string())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bad_mark_files_are_refused() {
        let good = "units = \"um\"\n[[part]]\nkind = \"dot\"\nradius = 40.0\n";
        assert!(SimMark::parse(good, Path::new("m.toml")).is_ok());
        for (bad, want) in [
            (good.replace("um", "px"), "units"),
            (good.replace("40.0", "-1.0"), "part 1"),
            (good.replace("40.0", "nan"), "part 1"),
            (good.replace("40.0", "1e9"), "part 1"),
            (good.replace("radius", "radius = 1.0\nwidht"), "widht"),
            (good.replace("dot", "star"), "star"),
            (
                "units = \"um\"\n[[part]]\nkind = \"spokes\"\ncount = 0\nfrom = 1.0\nto = 2.0\nwidth = 1.0\n"
                    .to_string(),
                "count 0",
            ),
            (
                "units = \"um\"\n[[part]]\nkind = \"spokes\"\ncount = 2\nfrom = 3.0\nto = 2.0\nwidth = 1.0\n"
                    .to_string(),
                "from < to",
            ),
            ("units = \"um\"\npart = []\n".to_string(), "0 parts"),
        ] {
            let e = SimMark::parse(&bad, Path::new("m.toml")).unwrap_err();
            assert!(e.starts_with("m.toml") && e.contains(want), "{want}: {e}");
        }
    }

    #[test]
    fn a_ring_with_spokes_is_dark_where_its_parts_are() {
        let m = SimMark {
            parts: vec![
                SimPart::Dot { radius: 40.0 },
                SimPart::Ring {
                    radius: 300.0,
                    width: 40.0,
                },
                SimPart::Spokes {
                    count: 3,
                    from: 340.0,
                    to: 440.0,
                    width: 40.0,
                    angle0_deg: 90.0,
                },
            ],
        };
        let s = 1.0;
        assert!(m.coverage([0.0, 0.0], s) > 0.99);
        assert!(m.coverage([300.0, 0.0], s) > 0.99);
        assert!(m.coverage([0.0, 390.0], s) > 0.99, "the spoke at 90°");
        assert!(m.coverage([0.0, -390.0], s) < 0.01, "none at 270°");
        assert!(m.coverage([150.0, 0.0], s) < 0.01);
        assert_eq!(m.reach_um(), 480.0);
        assert!(m.certificate_shape("x").contains("count = 3"));
    }
}
