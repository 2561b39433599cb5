//! Seed 000's pipeline from a project, as a library: the mapping functions (fitted to the
//! control points, read from a file, or derived from photos resected on the control points),
//! the height sweep, the removal of wrong heights, the grid, the comparison with a reference,
//! and the files a run leaves. It takes plain photos (an image and its pixel → photo grid);
//! whoever made them — the rig's scans or anyone's — hands them over as [`Photo`]s.

use crate::coords::{GroundM, PixelXY};
use crate::geometry::{resect, FrameCamera, FrameSensor, Resection};
use crate::matching::accuracy::averaging::{remove_window_averaging, AveragingReport, Kernel};
use crate::matching::accuracy::precision::{sigma_vs_reference, SigmaCheck};
use crate::matching::block::photo::Photo;
use crate::matching::error::MatchingError;
use crate::matching::mapping::pmf_set::FitReport;
use crate::matching::methods::sweep::height_sweep::{step_for_parallax, SweepParams};
use crate::matching::methods::sweep::pair_model::{
    pmf_dtm, Budget, PmfDtm, PmfDtmParams, PmfDtmReport,
};
use crate::matching::methods::sweep::regions::RegionParams;
use crate::matching::products::files::read_geotiff;
use crate::matching::products::ortho::View;
use crate::matching::products::outputs as O;
use crate::matching::products::write::{check_out_dir, write_outputs};
use crate::matching::project::pair::{PairProject, PmfSource};
use crate::matching::{PmfSet, StereoPoint};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// The resected photos, when the mappings were derived from them.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Orientation {
    pub left: Resection,
    pub right: Resection,
}

/// `report.json`: what a run did and found (seed 000 Tables 2–5), written and read as this type.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ScannedPairReport {
    pub project: PathBuf,
    pub pmf_from: PmfSource,
    pub orientation: Option<Orientation>,
    /// Seed 000 Table 2: each mapping's terms and RMSE at the control and check points.
    pub pmf: Vec<FitReport>,
    pub dtm: PmfDtmReport,
    /// quality.tif's σ (the matching's own, unscaled: one pair has no redundancy) against the
    /// reference model's differences.
    #[serde(default)]
    pub sigma_vs_reference: Option<SigmaCheck>,
    /// The window averaging taken out of the nodes (see [`crate::matching::accuracy::averaging`]).
    #[serde(default)]
    pub averaging: Option<AveragingReport>,
}

impl ScannedPairReport {
    /// The figures a person looks at first, for report.html.
    pub fn summary(&self) -> Vec<(String, String)> {
        let d = &self.dtm;
        let mut v = vec![
            (
                "mapping functions".into(),
                format!("{:?}, {} mappings", self.pmf_from, self.pmf.len()),
            ),
            (
                "matched".into(),
                format!(
                    "{} of {} points ({:.1} %), {:.1} % kept after the wrong-height criteria",
                    d.points_matched, d.points_total, d.matched_percent, d.remaining_percent
                ),
            ),
            (
                "grid".into(),
                format!(
                    "{} of {} nodes with a height, cell {} m",
                    d.grid_filled, d.grid_nodes, d.params.cell_m
                ),
            ),
        ];
        if let Some(c) = &d.comparison {
            v.push(("against the reference".into(), c.summary()));
        }
        if let Some(c) = &self.sigma_vs_reference {
            v.push((
                "σ against true errors".into(),
                format!(
                    "errors {:.1} × σ (RMS σ {:.2} m), {:.0} % within 2σ",
                    c.ratio, c.rms_sigma_m, c.within_2_sigma_percent
                ),
            ));
        }
        for w in d.warnings() {
            v.push(("warning".into(), w));
        }
        v
    }
}

/// The mapping functions the project asks for, and the resected photos when they were derived.
fn mappings(
    p: &PairProject,
    [left, right]: [&Photo; 2],
    pts: &crate::matching::project::pair::PointFile,
) -> Result<(PmfSet, Option<Orientation>), MatchingError> {
    match p.pmf.from {
        PmfSource::Points => PmfSet::from_points(p.pmf.order, &pts.gcps, &pts.cps)
            .map(|m| (m, None))
            .map_err(|source| MatchingError::Fit {
                path: p.points.file.clone(),
                cause: source,
            }),
        PmfSource::File => {
            let Some(path) = p.pmf.file.clone() else {
                return Err(MatchingError::PairMappings {
                    path: p.path.clone(),
                    message: "[pmf] from = \"file\" names no file".into(),
                });
            };
            let text = std::fs::read_to_string(&path).map_err(|e| MatchingError::PairMappings {
                path: path.clone(),
                message: e.to_string(),
            })?;
            serde_json::from_str::<PmfSet>(&text)
                .map(|m| (m, None))
                .map_err(|e| MatchingError::PairMappings {
                    path,
                    message: format!("not a set of mapping functions ({e})"),
                })
        }
        PmfSource::Rigorous => {
            let orient = |ph: &Photo, px: &dyn Fn(&StereoPoint) -> [f64; 2], which| {
                let obs: Vec<_> = pts
                    .gcps
                    .iter()
                    .map(|g| {
                        let q = px(g);
                        (ph.frame.photo(PixelXY::new(q[0], q[1])), g.ground)
                    })
                    .collect();
                resect(&ph.interior, &obs)
                    .map(|r| (ph.interior, r))
                    .map_err(|source| MatchingError::PairResection {
                        which,
                        cause: source,
                    })
            };
            let (il, rl) = orient(left, &|g| g.left, "left")?;
            let (ir, rr) = orient(right, &|g| g.right, "right")?;
            let photo = |interior, r: &Resection, frame| FrameSensor {
                camera: FrameCamera {
                    interior,
                    exterior: r.exterior,
                },
                frame,
                exterior_cov: Some(r.covariance),
            };
            let (l, r) = (photo(il, &rl, left.frame), photo(ir, &rr, right.frame));
            let m = PmfSet::from_sensors(&l, &r, [p.matching.h_min, p.matching.h_max], p.pmf.order)
                .map_err(MatchingError::Derive)?;
            Ok((
                m,
                Some(Orientation {
                    left: rl,
                    right: rr,
                }),
            ))
        }
    }
}

/// Runs project `p` on the photos it names (`photos`, left then right, already loaded) into
/// `out`: `dem.tif`, `points.ply`, `hillshade.png`, `error.png` (with a reference),
/// `report.json` and `pmfs.json`, each written whole or not at all. `max_memory_mb` overrides
/// the project's limit.
pub fn run(
    p: &PairProject,
    photos: [&Photo; 2],
    out: &Path,
    max_memory_mb: Option<u64>,
    progress: &dyn crate::matching::progress::Progress,
) -> Result<(PmfDtm, ScannedPairReport), MatchingError> {
    check_out_dir(out)?;
    let pts = p.points()?;
    let (pmfs, orientation) = mappings(p, photos, &pts)?;
    let heights = [p.matching.h_min, p.matching.h_max];
    let (w, h) = (photos[0].image.width, photos[0].image.height);
    let h_step = p
        .matching
        .h_step
        .or_else(|| step_for_parallax(&pmfs.left_to_right, w, h, heights, 0.5))
        .ok_or(MatchingError::NoParallax)?;
    let params = PmfDtmParams {
        sweep: SweepParams {
            h_min: p.matching.h_min,
            h_max: p.matching.h_max,
            h_step,
            window: p.matching.window,
            threshold: p.matching.threshold,
            subpixel: p.matching.subpixel,
            stride: p.matching.stride,
            ..Default::default()
        },
        regions: RegionParams {
            search_distance: p.regions.search_distance,
            height_threshold: p.height_threshold(h_step),
            population_threshold: p.regions.population_threshold,
        },
        cell_m: p.grid.cell_m,
    };
    let reference = match &p.grid.reference {
        Some(r) => Some(read_geotiff(r).map_err(|source| MatchingError::Reference {
            path: r.clone(),
            cause: source,
        })?),
        None => None,
    };
    let height_at = reference
        .as_ref()
        .map(|g| move |x: f64, y: f64| g.interpolate(x, y));
    let budget = Budget {
        max_memory_mb: max_memory_mb.unwrap_or(p.limits.max_memory_mb),
        max_candidates: p.limits.max_candidates_g * 1e9,
    };
    let mut r = pmf_dtm(
        &photos[0].image,
        &photos[1].image,
        &pmfs,
        &params,
        &budget,
        height_at.as_ref().map(|f| f as &dyn Fn(f64, f64) -> f64),
        p.grid.flying_height_m,
        progress,
    )
    .map_err(|source| MatchingError::Dtm {
        path: p.path.clone(),
        cause: source,
    })?;
    // One pair: no redundancy to scale the matching's σ by (see precision.rs). The window's
    // averaging on curved terrain out of the nodes, its unresolved share into their σ; the
    // window on the ground from the left photo's centre at the middle height.
    let mut quality = r.grid.quality(&r.points);
    let mid = 0.5 * (heights[0] + heights[1]);
    let (cx, cy) = (0.5 * w as f64, 0.5 * h as f64);
    let (a, b) = (
        pmfs.left_to_ground.eval([cx, cy, mid]),
        pmfs.left_to_ground.eval([cx + 1.0, cy, mid]),
    );
    let window_m = p.matching.window as f64 * (a[0] - b[0]).hypot(a[1] - b[1]);
    let averaging = remove_window_averaging(
        &mut r.grid,
        &mut quality,
        Kernel::cell_mean(window_m, p.grid.cell_m),
    );
    if let Some(f) = &height_at {
        r.report.comparison = Some(r.grid.compare(f));
        r.report.rmse_permille_of_flying_height =
            match (&r.report.comparison, p.grid.flying_height_m) {
                (Some(c), Some(h)) => Some(1000.0 * c.rmse_m / h),
                _ => None,
            };
    }
    let sigma_vs_reference = reference
        .as_ref()
        .and_then(|g| sigma_vs_reference(&r.grid, &quality.sigma_m, g));
    let report = ScannedPairReport {
        project: p.path.clone(),
        pmf_from: p.pmf.from,
        orientation,
        pmf: pmfs.report.clone(),
        dtm: r.report.clone(),
        sigma_vs_reference,
        averaging,
    };
    let write = |source| MatchingError::Write {
        dir: out.to_path_buf(),
        cause: source,
    };
    let to_left = |g: GroundM| {
        let q = pmfs.ground_to_left.eval([g.x, g.y, g.z]);
        Some(PixelXY::new(q[0], q[1]))
    };
    let to_right = |g: GroundM| {
        let q = pmfs.ground_to_right.eval([g.x, g.y, g.z]);
        Some(PixelXY::new(q[0], q[1]))
    };
    let views = [
        View {
            image: &photos[0].image,
            project: &to_left,
        },
        View {
            image: &photos[1].image,
            project: &to_right,
        },
    ];
    write_outputs(
        out,
        &r.grid,
        &r.points,
        &quality,
        &views,
        reference.as_ref().zip(r.report.comparison.as_ref()),
        p.crs,
        &report,
        &report.summary(),
    )
    .map_err(write)?;
    crate::atomic::write_json(&out.join(O::PMFS), &pmfs).map_err(write)?;
    Ok((r, report))
}
