//! Planning a scan: the tiles that cover each region with the requested overlap, where the
//! stage must stand for each, whether every one of those positions lies inside the soft
//! limits, and how long the scan takes and how many bytes it writes. Nothing moves.

use super::calibration::ScanCalibration;
use super::grid::PhotoGrid;
use super::script::ScanScript;
use crate::coords::{CarriageUm, PhotoMm, PixelXY};
use serde::{Deserialize, Serialize};

/// A tile's usable area starts this far inside the camera frame (px): the stripe filter's and
/// the resampling kernel's edges stay out, and a stage that stops a few µm off cannot open a
/// gap (the mosaic uses pixels from [`MOSAIC_MARGIN_PX`] on).
pub const PLAN_MARGIN_PX: f64 = 8.0;
pub const MOSAIC_MARGIN_PX: f64 = 3.0;
/// Frame rate assumed when the session did not record the camera's.
pub const ASSUMED_FRAME_RATE_HZ: f64 = 25.0;

#[derive(Debug, thiserror::Error)]
pub enum PlanError {
    #[error("{script}:{line}: region `{region}` reaches photo ({x:.1}, {y:.1}) mm, which needs the stage at {stage} — outside the soft limits X {xmin:.1}…{xmax:.1} mm, Y {ymin:.1}…{ymax:.1} mm. Shrink the region or lay the film nearer the middle of the carriage.")]
    OutsideLimits {
        script: String,
        line: usize,
        region: String,
        x: f64,
        y: f64,
        stage: CarriageUm,
        xmin: f64,
        xmax: f64,
        ymin: f64,
        ymax: f64,
    },
    #[error("{script}: the flat field's spot, photo ({x:.1}, {y:.1}) mm, needs the stage at {stage}, outside the soft limits: set [capture] flat_photo_mm to clear film base nearer the middle")]
    FlatOutsideLimits {
        script: String,
        x: f64,
        y: f64,
        stage: CarriageUm,
    },
    #[error(
        "the camera frame ({width}×{height} px) is too small for the margins the mosaic needs"
    )]
    FrameTooSmall { width: usize, height: usize },
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Tile {
    /// `<region>-<k>`, k from 1 in the order taken; also the tile's file name.
    pub id: String,
    pub region: usize,
    /// The photo point at the frame's centre.
    pub photo_mm: PhotoMm,
    /// Where the stage is sent.
    pub stage_um: CarriageUm,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RegionPlan {
    pub name: String,
    pub grid: PhotoGrid,
    /// Tiles across and down.
    pub cols: usize,
    pub rows: usize,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Estimate {
    pub seconds: f64,
    pub travel_mm: f64,
    pub tile_bytes: u64,
    pub mosaic_bytes: u64,
    pub frame_rate_hz: f64,
    /// The session did not record the frame rate: [`ASSUMED_FRAME_RATE_HZ`] was used.
    pub frame_rate_assumed: bool,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Plan {
    pub regions: Vec<RegionPlan>,
    /// In the order they are taken: region by region, rows from the top, serpentine.
    pub tiles: Vec<Tile>,
    /// Half the width and height of a tile's usable area in the photo, mm.
    pub tile_half_mm: [f64; 2],
    /// Where the stage stands for the flat field (taken first), if one is taken.
    pub flat_stage_um: Option<CarriageUm>,
    pub estimate: Estimate,
}

/// Half-sizes (mm) of the largest photo-axis-aligned box around the frame's centre whose image
/// stays [`PLAN_MARGIN_PX`] inside the frame.
fn usable_half_mm(cal: &ScanCalibration) -> Result<[f64; 2], PlanError> {
    let (w, h) = (cal.rig.width as f64, cal.rig.height as f64);
    let (lx, ly) = (0.5 * w - PLAN_MARGIN_PX, 0.5 * h - PLAN_MARGIN_PX);
    if lx < 4.0 * MOSAIC_MARGIN_PX || ly < 4.0 * MOSAIC_MARGIN_PX {
        return Err(PlanError::FrameTooSmall {
            width: cal.rig.width,
            height: cal.rig.height,
        });
    }
    let (_, m) = cal.photo_to_pixel(CarriageUm::default());
    // Pixel offsets of a box (a, b) are ±m·(a, ±b): keep |m00|a + |m01|b ≤ lx, likewise y.
    let (a0, b0) = (lx / m[0][0].abs(), ly / m[1][1].abs());
    let t = (lx / (m[0][0].abs() * a0 + m[0][1].abs() * b0))
        .min(ly / (m[1][0].abs() * a0 + m[1][1].abs() * b0));
    Ok([t * a0, t * b0])
}

/// Tile centres along one axis covering [lo, hi] with tiles of half-size `half`, neighbours
/// overlapping by `overlap` of a tile: evenly spread, the outer ones flush with the ends.
fn centres(lo: f64, hi: f64, half: f64, overlap: f64) -> Vec<f64> {
    let span = hi - lo;
    if span <= 2.0 * half {
        return vec![0.5 * (lo + hi)];
    }
    let step = 2.0 * half * (1.0 - overlap);
    let n = ((span - 2.0 * half) / step - 1e-9).ceil() as usize + 1;
    let d = (span - 2.0 * half) / (n - 1) as f64;
    (0..n).map(|k| lo + half + k as f64 * d).collect()
}

/// The square inside the camera's fiducials, for `whole = true`: 6 mm in from the innermost
/// fiducial, clear of the marks and the frame's edge.
fn whole_picture(cal: &ScanCalibration) -> [f64; 4] {
    let h = cal
        .certificate
        .fiducials
        .iter()
        .map(|f| f.photo.x.abs().max(f.photo.y.abs()))
        .fold(f64::MAX, f64::min);
    let h = if h.is_finite() { h - 6.0 } else { 100.0 };
    [-h, -h, h, h]
}

pub fn plan(script: &ScanScript, cal: &ScanCalibration) -> Result<Plan, PlanError> {
    let half = usable_half_mm(cal)?;
    let centre_px = PixelXY::new(0.5 * cal.rig.width as f64, 0.5 * cal.rig.height as f64);
    let step_mm = script.resolution_um / 1000.0;
    let flat_stage_um = match script.capture.flat_field {
        true => {
            let [x, y] = script.capture.flat_photo_mm;
            let stage = cal.stage_for(PhotoMm::new(x, y), centre_px);
            if cal.rig.limits.check(stage).is_err() {
                return Err(PlanError::FlatOutsideLimits {
                    script: script.path.display().to_string(),
                    x,
                    y,
                    stage,
                });
            }
            Some(stage)
        }
        false => None,
    };
    let mut regions = Vec::new();
    let mut tiles = Vec::new();
    for (ri, r) in script.regions.iter().enumerate() {
        let area = r.photo_mm.unwrap_or_else(|| whole_picture(cal));
        let grid = PhotoGrid::covering(area, step_mm);
        let e = grid.extent_mm();
        let xs = centres(e[0], e[2], half[0], script.capture.overlap);
        let mut ys = centres(e[1], e[3], half[1], script.capture.overlap);
        ys.reverse();
        for (row, &y) in ys.iter().enumerate() {
            let mut row_xs = xs.clone();
            if row % 2 == 1 {
                row_xs.reverse();
            }
            for x in row_xs {
                let p = PhotoMm::new(x, y);
                let stage = cal.stage_for(p, centre_px);
                if cal.rig.limits.check(stage).is_err() {
                    let l = &cal.rig.limits;
                    // Report the region's corner in the offending direction.
                    return Err(PlanError::OutsideLimits {
                        script: script.path.display().to_string(),
                        line: r.line,
                        region: r.name.clone(),
                        x: x + half[0] * (x - 0.5 * (e[0] + e[2])).signum(),
                        y: y + half[1] * (y - 0.5 * (e[1] + e[3])).signum(),
                        stage,
                        xmin: l.min.x / 1000.0,
                        xmax: l.max.x / 1000.0,
                        ymin: l.min.y / 1000.0,
                        ymax: l.max.y / 1000.0,
                    });
                }
                tiles.push(Tile {
                    id: format!(
                        "{}-{}",
                        r.name,
                        tiles.iter().filter(|t: &&Tile| t.region == ri).count() + 1
                    ),
                    region: ri,
                    photo_mm: p,
                    stage_um: stage,
                });
            }
        }
        regions.push(RegionPlan {
            name: r.name.clone(),
            grid,
            cols: xs.len(),
            rows: ys.len(),
        });
    }
    let estimate = estimate(script, cal, &regions, &tiles, flat_stage_um);
    Ok(Plan {
        regions,
        tiles,
        tile_half_mm: half,
        flat_stage_um,
        estimate,
    })
}

fn estimate(
    script: &ScanScript,
    cal: &ScanCalibration,
    regions: &[RegionPlan],
    tiles: &[Tile],
    flat: Option<CarriageUm>,
) -> Estimate {
    let (rate, assumed) = match cal.rig.frame_rate_hz {
        Some(r) if r > 0.0 => (r, false),
        _ => (ASSUMED_FRAME_RATE_HZ, true),
    };
    let mut seconds = 0.0;
    let mut travel = 0.0;
    // From the middle of the travel (where homing leaves it is the controller's business).
    let mut at = CarriageUm::new(
        0.5 * (cal.rig.limits.min.x + cal.rig.limits.max.x),
        0.5 * (cal.rig.limits.min.y + cal.rig.limits.max.y),
    );
    // The flat field: four times a tile's frames.
    let stops = flat
        .map(|f| (f, 4 * script.capture.frames))
        .into_iter()
        .chain(tiles.iter().map(|t| (t.stage_um, script.capture.frames)));
    for (to, frames) in stops {
        let d = (to - at).norm();
        travel += d;
        seconds += crate::stage::move_duration(d, cal.rig.max_speed_um_s, cal.rig.accel_um_s2)
            .as_secs_f64();
        seconds += script.capture.settle_ms / 1000.0;
        seconds += frames as f64 / rate;
        at = to;
    }
    // 16-bit TIFF: the pixels plus a few hundred bytes of header.
    let tile_bytes = tiles.len() as u64 * (cal.rig.width * cal.rig.height * 2 + 512) as u64;
    let mosaic_bytes = regions
        .iter()
        .map(|r| (r.grid.width * r.grid.height * 2 + 512) as u64)
        .sum();
    Estimate {
        seconds,
        travel_mm: travel / 1000.0,
        tile_bytes,
        mosaic_bytes,
        frame_rate_hz: rate,
        frame_rate_assumed: assumed,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn centres_cover_the_span_with_the_overlap() {
        let c = centres(-20.0, 20.0, 2.5, 0.2);
        assert_eq!(c.first(), Some(&-17.5));
        assert_eq!(c.last(), Some(&17.5));
        for w in c.windows(2) {
            // Neighbours share at least 20 % of a 5 mm tile.
            assert!(w[1] - w[0] <= 4.0 + 1e-9, "{c:?}");
        }
        assert_eq!(centres(0.0, 3.0, 2.5, 0.2), vec![1.5]);
    }
}
