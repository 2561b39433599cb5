//! `rig orient`'s run, and `rig dtm`'s first step on a block to orient:
//!
//! 1. the block on the points file's rays alone (when it has tie points enough), which brings
//!    the approximations to within a pixel or so;
//! 2. tie points found by the rig ([`super::ties`]) in every overlapping pair with those
//!    orientations (or the approximations, searched wider across the epipolar lines);
//! 3. the whole block adjusted again, each group of rays (measured, matched) reweighted by its
//!    own variance component until σ̂ of each is 1 (Förstner 1979: σ̂²_g = Σ_g vᵀPv / Σ_g r_i,
//!    with the rays' redundancy numbers r_i), so that the approximations' and the control's
//!    σ weigh against the rays' true precision.

use super::bundle::{adjust, Adjusted, Block, BlockPoint, Ray, RayStatus, Role, Settings};
use super::from_project::{block_of, OrientError, OrientOptions};
use super::oriented::Oriented;
use super::ties::{find, SearchPhoto, TieOptions};
use crate::geometry::{Exterior, FrameCamera, FrameSensor};
use crate::matching::block::orient::{footprint, overlap};
use crate::matching::block::photo::{Photo, PhotoGeometry};
use crate::matching::block::photos::load_photo;
use crate::matching::project::Project;
use std::path::Path;

/// The project's photos, read whole (scans through `scan`).
pub fn load(
    p: &Project,
    scan: &crate::matching::block::photo::ScanReader,
) -> Result<Vec<Photo>, OrientError> {
    crate::matching::block::photos::check_held(p, scan, &vec![None; p.photos.len()])?;
    (0..p.photos.len())
        .map(|k| Ok(load_photo(p, k, scan, None)?))
        .collect()
}

/// σ̂ of each group of rays: Σ (v/σ)² over Σ of their redundancy numbers.
fn components(b: &Block, a: &Adjusted) -> [Option<f64>; 2] {
    let mut s = [(0.0, 0.0); 2];
    for (r, x) in b.rays.iter().zip(&a.rays) {
        if x.status != RayStatus::Used {
            continue;
        }
        let v = (x.residual_mm[0].powi(2) + x.residual_mm[1].powi(2)) / (r.sigma_mm * r.sigma_mm);
        s[r.group].0 += v;
        s[r.group].1 += 2.0 * x.redundancy;
    }
    s.map(|(v, r)| (r > 2.0).then(|| (v / r).sqrt()))
}

/// Adjusts `block`, reweighting each group of rays until its σ̂ is within 5 % of 1 (at most
/// five passes). Returns the block as last weighted.
fn adjust_weighted(mut block: Block) -> Result<(Block, Adjusted), OrientError> {
    let mut a = adjust(&block, Settings::default())?;
    for _ in 0..5 {
        let c = components(&block, &a);
        if c.iter().flatten().all(|s| (s - 1.0).abs() < 0.05) {
            break;
        }
        for r in &mut block.rays {
            if let Some(s) = c[r.group] {
                r.sigma_mm *= s.clamp(0.05, 20.0);
            }
        }
        a = adjust(&block, Settings::default())?;
    }
    Ok((block, a))
}

/// The terrain's height range: the project's, else the adjusted points' with a margin of
/// 15 % of their range (at least 50 m). The tie points, some hundred a photo, sample the
/// terrain densely (on the validation block they reach its lowest post and come within 42 m,
/// 7 % of their range, of its highest). A wider range costs the sweep more than time: each
/// height tried is one more chance for a wrong peak, and a pixel near the overlap's edge for
/// which some height falls outside the other photo gets none (docs/orientation.md).
fn heights(p: &Project, block: &Block, a: Option<&Adjusted>) -> [f64; 2] {
    if let Some(h) = p.heights {
        return h;
    }
    let zs: Vec<f64> = match a {
        Some(a) => a.points.iter().flatten().map(|q| q.ground.z).collect(),
        None => block
            .points
            .iter()
            .filter_map(|q| match q.role {
                Role::Control { ground, .. } => Some(ground.z),
                _ => None,
            })
            .collect(),
    };
    let lo = zs.iter().copied().fold(f64::MAX, f64::min);
    let hi = zs.iter().copied().fold(f64::MIN, f64::max);
    let m = (0.15 * (hi - lo)).max(50.0);
    [lo - m, hi + m]
}

/// Pairs of photos whose footprints at the middle height overlap (as the matchers find theirs,
/// [`footprint`] and [`overlap`]); a photo that sees no ground there takes part in none.
fn pairs(cams: &[FrameCamera], geo: &[PhotoGeometry], z: f64) -> Vec<(usize, usize)> {
    let prints: Vec<Option<[f64; 4]>> = cams
        .iter()
        .zip(geo)
        .map(|(c, g)| {
            let s = FrameSensor {
                camera: *c,
                frame: g.frame,
                exterior_cov: None,
                radial: Default::default(),
            };
            footprint(&s, z).ok()
        })
        .collect();
    let mut out = Vec::new();
    for i in 0..cams.len() {
        for k in i + 1..cams.len() {
            if let (Some(a), Some(b)) = (prints[i], prints[k]) {
                if overlap(a, b).is_some() {
                    out.push((i, k));
                }
            }
        }
    }
    out
}

/// Orients the project's block (see the module's documentation).
pub fn orient_block(
    p: &Project,
    photos: &[Photo],
    options: OrientOptions,
) -> Result<Oriented, OrientError> {
    let geo: Vec<PhotoGeometry> = photos.iter().map(|ph| ph.geometry()).collect();
    let obs = p.observations()?;
    let given = block_of(p, &geo, &obs, options)?;
    // 1. The measured rays alone, where they hold the block.
    let first = adjust_weighted(given.clone());
    let (start, across, first_adjusted): (Vec<FrameCamera>, f64, Option<Adjusted>) = match first {
        Ok((_, a)) => (a.cameras(), 3.0, Some(a)),
        Err(e) => {
            if given.photos.iter().any(|ph| ph.approx.is_none()) {
                return Err(e);
            }
            // From the approximations: across the epipolar lines by their σ, at most 64 px.
            let worst = given
                .photos
                .iter()
                .map(|ph| {
                    let pr = ph.prior.unwrap_or(super::bundle::Prior {
                        position_sigma_m: 0.0,
                        angles_sigma_rad: 0.0,
                    });
                    let e = ph.approx.unwrap();
                    let gsd_m = ph.pixel_mm / ph.interior.focal_mm * e.centre.z.abs().max(1.0);
                    (pr.position_sigma_m + e.centre.z.abs() * pr.angles_sigma_rad) / gsd_m.max(1e-9)
                })
                .fold(0.0, f64::max);
            let approx: Vec<Exterior> = given.photos.iter().map(|ph| ph.approx.unwrap()).collect();
            let start = given.cameras(&approx);
            (start, (2.0 * worst).clamp(3.0, 64.0), None)
        }
    };
    let mut cams = start;
    let mut across = across;
    let mut last: Option<(Block, Adjusted)> = None;
    let hs = heights(p, &given, first_adjusted.as_ref());
    for _round in 0..2 {
        let fc = cams.clone();
        let pr = pairs(&fc, &geo, 0.5 * (hs[0] + hs[1]));
        let side = geo.iter().map(|g| g.width.min(g.height)).min().unwrap_or(0);
        // The search level: the epipolar segment and the band across it a few tens of px.
        let level = {
            let mut l = 0;
            while l < 4 && (side >> (l + 1)) >= 64 && across / (1 << l) as f64 > 8.0 {
                l += 1;
            }
            l.max(usize::from(side >= 256))
        };
        let search: Vec<SearchPhoto> = photos
            .iter()
            .zip(&fc)
            .zip(&geo)
            .map(|((ph, c), g)| SearchPhoto::new(&ph.image, *c, &g.frame, level))
            .collect();
        let o = TieOptions {
            cell_px: (side / 16).clamp(8, 256),
            template: 15,
            min_ncc: 0.8,
            across_px: across,
            heights: hs,
        };
        let tracks = find(&search, &pr, &o, level);
        let mut block = given.clone();
        for (n, t) in tracks.iter().enumerate() {
            block.points.push(BlockPoint {
                id: format!("rig{:05}", n + 1),
                role: Role::Tie,
            });
            let j = block.points.len() - 1;
            for r in t {
                let g = &geo[r.photo];
                block.rays.push(Ray {
                    point: j,
                    photo: r.photo,
                    xy: g.frame.photo(r.pixel),
                    sigma_mm: r.sigma_px * given.photos[r.photo].pixel_mm,
                    group: 1,
                });
            }
        }
        let (block, a) = adjust_weighted(block)?;
        cams = a.cameras();
        last = Some((block, a));
        if across <= 3.0 {
            break;
        }
        across = 3.0;
    }
    let (block, adjusted) = last.expect("one round at least");
    let image_sigma_px = block
        .rays
        .iter()
        .find(|r| r.group == 0)
        .map_or(options.image_sigma_px, |r| {
            r.sigma_mm / block.photos[r.photo].pixel_mm
        });
    let heights = heights(p, &block, Some(&adjusted));
    let pairs = pairs(&adjusted.cameras(), &geo, 0.5 * (heights[0] + heights[1]));
    Ok(Oriented {
        block,
        adjusted,
        image_sigma_px,
        heights,
        pairs,
    })
}

/// A block `rig dtm` oriented before matching: the oriented project (read back from the
/// folder, as `rig dtm` on it would read it) and the orientation's report.
#[derive(Debug)]
pub struct OrientedFirst {
    pub project: Project,
    pub report: super::outputs::Report,
    pub folder: std::path::PathBuf,
}

/// `rig dtm`'s first step: a project with approximate photos (`position_sigma_m`) is oriented
/// as one block ([`orient_block`], the same as `rig orient`) into `out/orientation/`, and the
/// oriented project, with its covariance, is what the matchers take. `None` when no photo is
/// approximate. The output directory is checked first; nothing is written when the block
/// fails.
pub fn before_matching(
    p: &Project,
    out: &Path,
    scan: &crate::matching::block::photo::ScanReader,
    options: OrientOptions,
) -> Result<Option<OrientedFirst>, OrientError> {
    if !p.has_approximate_photos() {
        return Ok(None);
    }
    crate::matching::products::write::check_out_dir(out)?;
    let photos = load(p, scan)?;
    let o = orient_block(p, &photos, options)?;
    let folder = out.join(crate::matching::products::outputs::ORIENTATION);
    let report = super::outputs::write(&p.path, &folder, &o).map_err(OrientError::Write)?;
    let project = Project::load(&folder.join("project.toml"))?;
    Ok(Some(OrientedFirst {
        project,
        report,
        folder,
    }))
}
