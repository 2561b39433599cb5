//! Planning a scan: the tiles that cover each region with the requested overlap, where the
//! stage must stand for each, whether every one of those positions lies inside the soft
//! limits, and how long the scan takes and how many bytes it writes. Nothing moves.

use super::calibration::ScanCalibration;
use super::script::ScanScript;
use crate::coords::{CarriageUm, PhotoMm, PixelXY};
use crate::geometry::PhotoGrid;
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
    #[error("{script}:{line}: region `{region}` needs {cols} × {rows} tiles (at most {MAX_TILES} in a scan): check the calibration's pixel size, or scan a smaller region")]
    TooManyTiles {
        script: String,
        line: usize,
        region: String,
        cols: f64,
        rows: f64,
    },
    #[error("{script}:{line}: region `{region}` makes a {width} × {height} px photo, which needs about {need_mib} MiB to mosaic; the limit is {max_mib} MiB: raise it with --max-memory, scan a smaller region or at a coarser resolution_um")]
    TooMuchMemory {
        script: String,
        line: usize,
        region: String,
        width: usize,
        height: usize,
        need_mib: u64,
        max_mib: u64,
    },
    #[error("{script}:{line}: region `{region}` is `whole = true`, but the certificate's innermost fiducial is {reach_mm:.1} mm from the centre: no picture area 6 mm inside it; give photo_mm instead")]
    NoPicture {
        script: String,
        line: usize,
        region: String,
        reach_mm: f64,
    },
    #[error("the calibration cannot be planned with: {0}")]
    Calibration(String),
}

/// Most tiles one scan may take (its manifest lists them all).
pub const MAX_TILES: usize = 100_000;
/// The default of `--max-memory`, MiB.
pub const DEFAULT_MAX_MEMORY_MIB: u64 = 4096;

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
    /// Of [`Estimate::seconds`]: the homing cycle, at most (the controller's own bound,
    /// recorded at calibration; the cycle is usually shorter).
    #[serde(default)]
    pub homing_s: f64,
    /// Of [`Estimate::seconds`]: the drive from the home corner to the flat field or the first
    /// tile.
    #[serde(default)]
    pub first_drive_s: f64,
    /// The largest region's mosaic, MiB of memory.
    #[serde(default)]
    pub mosaic_mib: u64,
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

impl Plan {
    /// Whether `other` (a plan as stored in a manifest) lays out the same scan as this one (the
    /// plan made again from the script and calibration): the same regions, grids, tiles and
    /// stage positions, to well below a micrometre (JSON may round the last digit). `Err`
    /// names the first difference. The estimate is not compared.
    pub fn same_layout(&self, other: &Plan) -> Result<(), String> {
        let near = |a: f64, b: f64, tol: f64| (a - b).abs() <= tol;
        let stage = |a: CarriageUm, b: CarriageUm| near(a.x, b.x, 1e-3) && near(a.y, b.y, 1e-3);
        if self.regions.len() != other.regions.len() {
            return Err(format!(
                "{} regions planned, {} stored",
                self.regions.len(),
                other.regions.len()
            ));
        }
        for (a, b) in self.regions.iter().zip(&other.regions) {
            let g = (&a.grid, &b.grid);
            if a.name != b.name
                || (a.cols, a.rows) != (b.cols, b.rows)
                || (g.0.width, g.0.height) != (g.1.width, g.1.height)
                || !near(g.0.step_mm, g.1.step_mm, 1e-12)
                || !near(g.0.corner_mm[0], g.1.corner_mm[0], 1e-9)
                || !near(g.0.corner_mm[1], g.1.corner_mm[1], 1e-9)
            {
                return Err(format!(
                    "region `{}` differs from the stored `{}`",
                    a.name, b.name
                ));
            }
        }
        if self.tiles.len() != other.tiles.len() {
            return Err(format!(
                "{} tiles planned, {} stored",
                self.tiles.len(),
                other.tiles.len()
            ));
        }
        for (a, b) in self.tiles.iter().zip(&other.tiles) {
            if a.id != b.id || a.region != b.region || !stage(a.stage_um, b.stage_um) {
                return Err(format!(
                    "tile {} at {} differs from the stored tile {} at {}",
                    a.id, a.stage_um, b.id, b.stage_um
                ));
            }
        }
        match (self.flat_stage_um, other.flat_stage_um) {
            (None, None) => Ok(()),
            (Some(a), Some(b)) if stage(a, b) => Ok(()),
            _ => Err("the flat field's stage position differs".into()),
        }
    }
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
    let half = [t * a0, t * b0];
    if half.iter().any(|h| !h.is_finite() || *h <= 0.0) {
        return Err(PlanError::Calibration(
            "the photo→pixel affine gives no usable tile area".into(),
        ));
    }
    Ok(half)
}

/// How many tiles [`centres`] lays along one axis (a float, to be checked before use).
fn count(lo: f64, hi: f64, half: f64, overlap: f64) -> f64 {
    let span = hi - lo;
    if span <= 2.0 * half {
        return 1.0;
    }
    let step = 2.0 * half * (1.0 - overlap);
    ((span - 2.0 * half) / step - 1e-9).ceil() + 1.0
}

/// Tile centres along one axis covering [lo, hi] with tiles of half-size `half`, neighbours
/// overlapping by `overlap` of a tile: evenly spread, the outer ones flush with the ends.
/// The count ([`count`]) must have been checked.
fn centres(lo: f64, hi: f64, half: f64, overlap: f64) -> Vec<f64> {
    let n = count(lo, hi, half, overlap) as usize;
    if n <= 1 {
        return vec![0.5 * (lo + hi)];
    }
    let span = hi - lo;
    let d = (span - 2.0 * half) / (n - 1) as f64;
    (0..n).map(|k| lo + half + k as f64 * d).collect()
}

/// The square inside the camera's fiducials, for `whole = true`: 6 mm in from the innermost
/// fiducial, clear of the marks and the frame's edge. `Err` with the innermost fiducial's
/// reach when that leaves less than a millimetre.
fn whole_picture(cal: &ScanCalibration) -> Result<[f64; 4], f64> {
    let reach = cal
        .certificate
        .fiducials
        .iter()
        .map(|f| f.photo.x.abs().max(f.photo.y.abs()))
        .fold(f64::INFINITY, f64::min);
    let h = if reach.is_finite() {
        reach - 6.0
    } else {
        100.0
    };
    if h < 1.0 {
        return Err(reach);
    }
    Ok([-h, -h, h, h])
}

/// Memory (bytes) the mosaic of a `grid` takes: the 16-bit output, and the tiles of two bands
/// held as 32-bit images twice (as read and smoothed).
fn mosaic_bytes(grid: &PhotoGrid, cols: usize, cal: &ScanCalibration) -> u64 {
    let out = 2 * grid.width as u64 * grid.height as u64;
    let tile = 4 * cal.rig.width as u64 * cal.rig.height as u64;
    out + 2 * 2 * (cols as u64 + 1) * tile
}

/// Plans the scan; refuses (before anything large is allocated) more than [`MAX_TILES`]
/// tiles or a mosaic above `max_memory_mib`.
pub fn plan(
    script: &ScanScript,
    cal: &ScanCalibration,
    max_memory_mib: u64,
) -> Result<Plan, PlanError> {
    cal.check().map_err(PlanError::Calibration)?;
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
    let mut biggest = 0u64;
    let mut planned = 0.0;
    for (ri, r) in script.regions.iter().enumerate() {
        let where_ = || (script.path.display().to_string(), r.line, r.name.clone());
        let area = match r.photo_mm {
            Some(a) => a,
            None => whole_picture(cal).map_err(|reach_mm| {
                let (script, line, region) = where_();
                PlanError::NoPicture {
                    script,
                    line,
                    region,
                    reach_mm,
                }
            })?,
        };
        // The script bounds the area (±120 mm) and the step (≥ 1 µm): at most 240 000 px.
        let grid = PhotoGrid::covering(area, step_mm);
        let e = grid.extent_mm();
        let (nc, nr) = (
            count(e[0], e[2], half[0], script.capture.overlap),
            count(e[1], e[3], half[1], script.capture.overlap),
        );
        planned += nc * nr;
        if planned.is_nan() || planned > MAX_TILES as f64 {
            let (script, line, region) = where_();
            return Err(PlanError::TooManyTiles {
                script,
                line,
                region,
                cols: nc,
                rows: nr,
            });
        }
        let bytes = mosaic_bytes(&grid, nc as usize, cal);
        if bytes > max_memory_mib << 20 {
            let (script, line, region) = where_();
            return Err(PlanError::TooMuchMemory {
                script,
                line,
                region,
                width: grid.width,
                height: grid.height,
                need_mib: bytes.div_ceil(1 << 20),
                max_mib: max_memory_mib,
            });
        }
        biggest = biggest.max(bytes);
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
    let mut estimate = estimate(script, cal, &regions, &tiles, flat_stage_um);
    estimate.mosaic_mib = biggest.div_ceil(1 << 20);
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
    let l = &cal.rig.limits;
    let first = flat.or(tiles.first().map(|t| t.stage_um));
    // Homing leaves the carriage at a corner of the travel ($23 decides which on GRBL): the
    // estimate starts from the corner farthest from the first stop, so it is not too short.
    let mut at = [
        l.min,
        l.max,
        CarriageUm::new(l.min.x, l.max.y),
        CarriageUm::new(l.max.x, l.min.y),
    ]
    .into_iter()
    .max_by(|a, b| {
        let f = first.unwrap_or(*a);
        (*a - f).norm().total_cmp(&(*b - f).norm())
    })
    .unwrap_or(l.min);
    let homing = cal.rig.homing_s.unwrap_or(0.0);
    let mut seconds = homing;
    let mut travel = 0.0;
    // The flat field: four times a tile's frames.
    let stops = flat
        .map(|f| (f, 4 * script.capture.frames))
        .into_iter()
        .chain(tiles.iter().map(|t| (t.stage_um, script.capture.frames)));
    let mut first_drive_s = 0.0;
    for (k, (to, frames)) in stops.enumerate() {
        let d = (to - at).norm();
        travel += d;
        let drive = crate::stage::move_duration(d, cal.rig.max_speed_um_s, cal.rig.accel_um_s2)
            .as_secs_f64();
        if k == 0 {
            first_drive_s = drive;
        }
        seconds += drive;
        seconds += script.capture.settle_ms / 1000.0;
        seconds += frames as f64 / rate;
        at = to;
    }
    // 16-bit TIFF: the pixels plus a few hundred bytes of header.
    let tile_bytes = tiles.len() as u64 * (cal.rig.width as u64 * cal.rig.height as u64 * 2 + 512);
    let mosaic_bytes = regions
        .iter()
        .map(|r| r.grid.width as u64 * r.grid.height as u64 * 2 + 512)
        .sum();
    Estimate {
        seconds,
        travel_mm: travel / 1000.0,
        tile_bytes,
        mosaic_bytes,
        frame_rate_hz: rate,
        frame_rate_assumed: assumed,
        homing_s: homing,
        first_drive_s,
        mosaic_mib: 0,
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

    #[test]
    fn the_estimate_includes_homing_and_the_drive_from_the_home_corner() {
        let text = "[film]\nname = \"f\"\n[output]\ndir = \"o\"\nresolution_um = 25.0\n\
                    [[region]]\nname = \"r\"\nphoto_mm = [0.0, 0.0, 8.0, 5.0]\n";
        let script = ScanScript::parse(text, std::path::Path::new("s.toml")).unwrap();
        let mut cal = ScanCalibration::synthetic();
        let with = plan(&script, &cal, DEFAULT_MAX_MEMORY_MIB).unwrap();
        cal.rig.homing_s = None;
        let without = plan(&script, &cal, DEFAULT_MAX_MEMORY_MIB).unwrap();
        let (e, e0) = (&with.estimate, &without.estimate);
        assert_eq!(e.homing_s, 20.0);
        assert!((e.seconds - e0.seconds - 20.0).abs() < 1e-9);
        // The first stop is the flat field; the farthest corner of 0…250 mm from it, driven at
        // 20 mm/s with 100 mm/s² (a long move: d/v + v/a, the trapezoid's closed form).
        let f = with.flat_stage_um.unwrap();
        let far = [0.0, 250_000.0]
            .iter()
            .flat_map(|&x| [0.0, 250_000.0].map(|y| (f.x - x).hypot(f.y - y)))
            .fold(0.0, f64::max);
        let want = far / 20_000.0 + 20_000.0 / 100_000.0;
        assert!(
            (e.first_drive_s - want).abs() < 1e-6,
            "{} vs {want}",
            e.first_drive_s
        );
        // Homing, the drive, the settles and the frames all counted.
        let frames = (4 * 8 + 8 * with.tiles.len()) as f64 / ASSUMED_FRAME_RATE_HZ;
        assert!(e.seconds > 20.0 + want + frames);
    }
}
