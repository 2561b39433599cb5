//! Measuring one mark in a captured picture: coarse location, then least-squares matching,
//! then the quality gate. A mark that fails any step is reported with why and never used.

use super::{
    locate, match_template, render, CoarseMatch, CoarseOptions, Geometry, LsmMatch, LsmOptions,
    MarkShape, Polarity, Template, TemplateSpec,
};
use crate::coords::PixelXY;
use crate::digitise::ImageF32;
use serde::Serialize;

/// The templates for one kind of mark at the current pixel spacing.
pub struct MarkTemplates {
    pub whole: Template,
    pub patch: Template,
    /// The geometric parameters the mark determines (see [`MarkShape::geometry`]).
    pub geometry: Geometry,
}

/// Largest template side drawn (px): a mark bigger than this in the image means the pixel size
/// or the certificate is wrong, and drawing it would take minutes and gigabytes.
pub const MAX_TEMPLATE_PX: usize = 1025;

impl MarkTemplates {
    /// `um_per_px`: the 2×2 of the pixel→carriage transformation as far as it is known.
    /// Refused (with what to check) when the mark would be larger than [`MAX_TEMPLATE_PX`].
    pub fn new(
        shape: &MarkShape,
        polarity: Polarity,
        um_per_px: [[f64; 2]; 2],
        patch: usize,
        blur_px: f64,
    ) -> Result<Self, String> {
        let px = um_per_px[0][0].abs().min(um_per_px[1][1].abs());
        let side = 2.0 * shape.reach_um() / px + 12.0;
        if !side.is_finite() || side > MAX_TEMPLATE_PX as f64 || patch > MAX_TEMPLATE_PX {
            return Err(format!(
                "a mark reaching {:.0} µm at {px:.4} µm/px would need a template of {side:.0} px \
                 (patch {patch} px; at most {MAX_TEMPLATE_PX}): check the certificate's mark sizes \
                 and the pixel size (--pixel-um)",
                shape.reach_um()
            ));
        }
        if !(blur_px.is_finite() && (0.0..=50.0).contains(&blur_px)) {
            return Err(format!("blur {blur_px} px: 0 to 50 px"));
        }
        let whole = side.ceil() as usize;
        let spec = |size, fine| TemplateSpec {
            size,
            um_per_px,
            blur_px,
            polarity,
            fine,
        };
        Ok(MarkTemplates {
            whole: render(&shape.for_coarse(), &spec(whole, false)),
            patch: render(shape, &spec(patch, true)),
            geometry: shape.geometry(),
        })
    }
}

/// Thresholds a match must pass to be used.
#[derive(Debug, Clone, Copy)]
pub struct Quality {
    /// Clean marks on 32-frame averages correlate at 0.999 with their template; dirt over a
    /// cross brings it to 0.96 (seed 002's own data reached 0.96–0.99: lower it for data as
    /// poor).
    pub min_correlation: f64,
    /// σ0 as a share of the mark's contrast r1: 1 % when clean, 8 % with dirt.
    pub max_sigma0_rel: f64,
    pub coarse: CoarseOptions,
    pub lsm: LsmOptions,
}

impl Default for Quality {
    fn default() -> Self {
        Quality {
            min_correlation: 0.98,
            max_sigma0_rel: 0.04,
            coarse: CoarseOptions::default(),
            lsm: LsmOptions::default(),
        }
    }
}

/// What became of one mark.
#[derive(Debug, Clone, Serialize, serde::Deserialize)]
pub struct MarkResult {
    pub coarse: Option<CoarseMatch>,
    pub lsm: Option<LsmMatch>,
    /// Why the mark is not used; `None` = used.
    pub rejected: Option<String>,
}

impl MarkResult {
    /// Where the mark was seen at all (fine if measured, else coarse): for the crop.
    pub fn seen_at(&self) -> Option<PixelXY> {
        self.lsm
            .as_ref()
            .map(|m| m.centre)
            .or(self.coarse.map(|c| c.centre))
    }

    pub fn centre(&self) -> Option<PixelXY> {
        match (&self.lsm, &self.rejected) {
            (Some(m), None) => Some(m.centre),
            _ => None,
        }
    }
}

/// Finds and measures the mark in `img`.
pub fn measure(img: &ImageF32, t: &MarkTemplates, q: &Quality) -> MarkResult {
    let coarse = match locate(img, &t.whole, &q.coarse) {
        Ok(c) => c,
        Err(e) => {
            return MarkResult {
                coarse: None,
                lsm: None,
                rejected: Some(format!("not found: {e}")),
            }
        }
    };
    let lsm = LsmOptions {
        geometry: t.geometry,
        ..q.lsm
    };
    match match_template(img, &t.patch, coarse.centre, &lsm) {
        Err(e) => MarkResult {
            coarse: Some(coarse),
            lsm: None,
            rejected: Some(e.to_string()),
        },
        Ok(m) => {
            let rel = m.sigma0_dn / m.radiometric[1].abs().max(1e-9);
            let rejected = if m.correlation < q.min_correlation {
                Some(format!(
                    "poor match: correlation {:.3} below {:.2} (dirt or damage on the mark?)",
                    m.correlation, q.min_correlation
                ))
            } else if rel > q.max_sigma0_rel {
                Some(format!(
                    "poor match: σ0 {:.2} DN is {:.1} % of the mark's contrast (over {:.1} %: dirt or damage?)",
                    m.sigma0_dn,
                    100.0 * rel,
                    100.0 * q.max_sigma0_rel
                ))
            } else {
                None
            };
            MarkResult {
                coarse: Some(coarse),
                lsm: Some(m),
                rejected,
            }
        }
    }
}

/// Average, minimum and maximum of one column.
#[derive(Debug, Clone, Copy, Serialize, serde::Deserialize)]
pub struct Stat {
    pub average: f64,
    pub minimum: f64,
    pub maximum: f64,
}

impl Stat {
    fn of(v: impl Iterator<Item = f64>) -> Option<Stat> {
        let v: Vec<f64> = v.collect();
        (!v.is_empty()).then(|| Stat {
            average: v.iter().sum::<f64>() / v.len() as f64,
            minimum: v.iter().copied().fold(f64::MAX, f64::min),
            maximum: v.iter().copied().fold(f64::MIN, f64::max),
        })
    }
}

/// The columns of seed 002's Tables 1 and 4 over the marks used: how far fine matching moved
/// the coarse position, the shifts' standard deviations, the correlation, σ0, iterations.
#[derive(Debug, Clone, Serialize, serde::Deserialize)]
pub struct MatchTable {
    pub marks: usize,
    pub x_shift_px: Stat,
    pub y_shift_px: Stat,
    pub sigma_x_px: Stat,
    pub sigma_y_px: Stat,
    pub correlation: Stat,
    pub sigma0_dn: Stat,
    pub iterations: Stat,
}

pub fn match_table<'a>(results: impl Iterator<Item = &'a MarkResult>) -> Option<MatchTable> {
    let used: Vec<&LsmMatch> = results
        .filter(|r| r.rejected.is_none())
        .filter_map(|r| r.lsm.as_ref())
        .collect();
    let col = |f: &dyn Fn(&LsmMatch) -> f64| Stat::of(used.iter().map(|m| f(m)));
    Some(MatchTable {
        marks: used.len(),
        x_shift_px: col(&|m| m.moved_px[0].abs())?,
        y_shift_px: col(&|m| m.moved_px[1].abs())?,
        sigma_x_px: col(&|m| m.sigma_px[0])?,
        sigma_y_px: col(&|m| m.sigma_px[1])?,
        correlation: col(&|m| m.correlation)?,
        sigma0_dn: col(&|m| m.sigma0_dn)?,
        iterations: col(&|m| m.iterations as f64)?,
    })
}

/// Prints a match table as the seed lays it out.
pub fn print_match_table(t: &MatchTable, title: &str) {
    println!("{title} ({} marks; seed 002 Table 1 columns)", t.marks);
    println!(
        "           |x-shift|  |y-shift|   σ x-shift  σ y-shift  correlation   σ0 (DN)  iterations"
    );
    for (name, f) in [
        ("average", (|s: &Stat| s.average) as fn(&Stat) -> f64),
        ("minimum", |s: &Stat| s.minimum),
        ("maximum", |s: &Stat| s.maximum),
    ] {
        println!(
            "  {name:<8} {:>9.3}  {:>9.3}   {:>9.4}  {:>9.4}  {:>11.4}  {:>8.2}  {:>10.1}",
            f(&t.x_shift_px),
            f(&t.y_shift_px),
            f(&t.sigma_x_px),
            f(&t.sigma_y_px),
            f(&t.correlation),
            f(&t.sigma0_dn),
            f(&t.iterations)
        );
    }
}
