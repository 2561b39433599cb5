//! A project's photos read for the matching: whole, or, when the project gives its `[dem]
//! extent`, only the window of each image that sees that area, and at the pyramid level its
//! posts need ([`level_for`]). A full satellite scene is 40 000 × 40 000 px; a DEM of a square
//! kilometre needs a few thousand pixels of it, and only those are read (strip- or tile-wise,
//! averaged as they are read: [`crate::image::load_grey_reduced`]). The window is where the
//! extent's ground projects through the photo's sensor at every height searched, with a
//! margin for the matchers' templates; each photo's sensor is then seen through the same view
//! ([`crate::geometry::PhotoSensor::viewed`]), so pixels and geometry agree.

use crate::coords::{GroundM, PixelView, PixelWindow, PixelXY};
use crate::geometry::{Interior, Sensor};
use crate::matching::block::orient::orient;
use crate::matching::block::photo::centred_grid;
use crate::matching::block::photo::frame_of;
use crate::matching::block::photo::PhotoGeometry;
use crate::matching::block::photo::{Photo, ScanReader};
use crate::matching::error::MatchingError;
use crate::matching::progress::Progress;
use crate::matching::project::{GivenModel, Project, Source};

/// Pixels read beyond where the extent projects, for the matchers' templates and search
/// windows at the edge of the area (the sweep's and the least-squares patches' few tens of
/// pixels, a pyramid's coarse levels).
pub const MARGIN_PX: usize = 96;

/// Points along each side of the extent projected to find its window.
const SAMPLES: usize = 9;

/// A photo not seeing the extent at all is read as a patch this many pixels wide at the image's
/// corner: it takes part in no pair (its footprint misses the extent).
const UNSEEN_SIDE: usize = 64;

/// Loads the project's photos (scans come through `scan`, the hardware side's hand-over), each
/// within the project's memory limit: the views of [`views`], their pixels counted on `progress`.
pub fn load_photos(
    p: &Project,
    scan: &ScanReader,
    progress: &dyn Progress,
) -> Result<Vec<Photo>, MatchingError> {
    let views = views(p, scan)?;
    check_held(p, scan, &views)?;
    load_viewed(p, scan, &views, progress)
}

/// Loads the project's photos through `views` (from [`views`], checked by [`check_held`]),
/// their pixels counted on `progress`.
pub fn load_viewed(
    p: &Project,
    scan: &ScanReader,
    views: &[Option<PixelView>],
    progress: &dyn Progress,
) -> Result<Vec<Photo>, MatchingError> {
    for (ph, v) in p.photos.iter().zip(views) {
        if let Some(v) = v {
            let w = v.window;
            tracing::info!(
                photo = %ph.id,
                columns = %format!("{} … {}", w.col0, w.col0 + w.width),
                rows = %format!("{} … {}", w.row0, w.row0 + w.height),
                factor = v.factor,
                "reading the part that sees the area, averaged over blocks of factor² pixels"
            );
        }
    }
    let pixels: u64 = (0..p.photos.len())
        .map(|k| match views[k] {
            Some(v) => Ok((v.window.width * v.window.height) as u64),
            None => size_of(p, k, scan).map(|(w, h)| (w * h) as u64),
        })
        .sum::<Result<u64, _>>()?;
    progress.begin("reading photos (pixels)", pixels);
    let photos = (0..p.photos.len())
        .map(|k| load_photo_with(p, k, scan, views[k], progress))
        .collect();
    progress.end();
    photos
}

/// Bytes a photo's view takes in memory (grey values as f32).
const BYTES_PER_PIXEL: u64 = 4;

/// Refuses, before anything is read, a set of photos held at once (`views`, `None`: whole)
/// whose grey values alone would pass `[limits] max_memory_mb`: each photo is checked as it is
/// read, but a block of a hundred photos each within the limit is not. The images' sizes come
/// from their headers, a scan's from its hand-over (the core reads its pixels as an image's).
pub fn check_held(
    p: &Project,
    scan: &ScanReader,
    views: &[Option<PixelView>],
) -> Result<(), MatchingError> {
    let mut bytes: u64 = 0;
    let mut largest: (u64, String) = (0, String::new());
    for (k, (ph, v)) in p.photos.iter().zip(views).enumerate() {
        let path = match &ph.source {
            Source::Scan { sidecar } => sidecar,
            Source::Image { path, .. } | Source::Model { path, .. } => path,
        };
        let (cols, rows) = match v {
            Some(v) => v.size(),
            None => size_of(p, k, scan)?,
        };
        let pixels = (cols * rows) as u64;
        let b = pixels.saturating_mul(BYTES_PER_PIXEL);
        bytes = bytes.saturating_add(b);
        if b > largest.0 {
            largest = (
                b,
                format!("`{}` ({}, {} MiB)", ph.id, path.display(), b >> 20),
            );
        }
    }
    let mib = bytes >> 20;
    if mib > p.limits.max_memory_mb {
        return Err(MatchingError::Memory(format!(
            "the {} photos held at once would take {mib} MiB as grey values (the largest {}); the limit is {} MiB: give [dem] extent to read only what sees it, read them smaller ([dem] photo_level), split the block, or raise [limits] max_memory_mb (or --max-memory)",
            p.photos.len(),
            largest.1,
            p.limits.max_memory_mb
        )));
    }
    Ok(())
}

/// Pixels a side below which a photo is matched as scanned whatever its pixels on the ground:
/// a sweep of a photo this size takes seconds, and finer pixels than the cell needs still add
/// precision to each post (see [`level_for`]).
pub const MIN_LEVEL_SIDE: usize = 1024;

/// The pyramid level `photo_level = "auto"` reads a photo at: the coarsest L whose pixels,
/// 2ᴸ × `gsd_m` on the ground, are at most half the model's cell (two samples a post: the
/// grid shows nothing finer, Nyquist) and whose `side` / 2ᴸ keeps [`MIN_LEVEL_SIDE`] pixels.
/// A film scanned at 12–25 µm (9 000–19 000 px) with posts of a few metres is read 4–16 times
/// smaller; the sweep's work then follows the model, not the scan (seed 002 matches down a
/// pyramid; it is the level its last step would need).
pub fn level_for(gsd_m: f64, cell_m: f64, side: usize) -> u8 {
    let mut level = 0u8;
    while level < crate::matching::project::MAX_PHOTO_LEVEL {
        let f = 1usize << (level + 1);
        if !(gsd_m.is_finite() && gsd_m * f as f64 <= 0.5 * cell_m && side / f >= MIN_LEVEL_SIDE) {
            break;
        }
        level += 1;
    }
    level
}

/// The view of each photo to read (`None`: the whole image as it is):
/// where the project gives its `[dem] extent`, the part of the image that sees it at the
/// heights searched, with [`MARGIN_PX`]; at `[dem] photo_level`, or the level [`level_for`]
/// picks from each photo's pixel on the ground at its centre.
pub fn views(p: &Project, scan: &ScanReader) -> Result<Vec<Option<PixelView>>, MatchingError> {
    if p.extent.is_none() && p.photo_level.is_some() {
        let level = p.photo_level.unwrap_or(0);
        return (0..p.photos.len())
            .map(|k| {
                if level == 0 {
                    return Ok(None);
                }
                let (w, h) = size_of(p, k, scan)?;
                Ok(Some(PixelView {
                    window: PixelWindow::whole(w, h),
                    factor: 1 << level,
                }))
            })
            .collect();
    }
    let whole = (0..p.photos.len())
        .map(|k| whole_geometry(p, k, scan))
        .collect::<Result<Vec<_>, _>>()?;
    let oriented = orient(p, &whole)?;
    let mid = 0.5 * (oriented.heights[0] + oriented.heights[1]);
    Ok(oriented
        .sensors
        .iter()
        .map(|s| {
            let (w, h) = s.image_size();
            let window = match p.extent {
                Some(extent) => window_seeing(s, extent, oriented.heights),
                None => PixelWindow::whole(w, h),
            };
            let level = p.photo_level.unwrap_or_else(|| {
                let centre = PixelXY::new(0.5 * w as f64, 0.5 * h as f64);
                let gsd = s.ground_pixel_m(centre, mid).unwrap_or(f64::NAN);
                level_for(gsd, p.cell_m, window.width.min(window.height))
            });
            let view = PixelView {
                window,
                factor: 1 << level,
            };
            (!view.is_whole(w, h)).then_some(view)
        })
        .collect())
}

/// Every photo's geometry as it will be read through `views` (from `views`), without a
/// pixel: what a plan needs to refuse a run before the photos are read.
pub fn geometries(
    p: &Project,
    scan: &ScanReader,
    views: &[Option<PixelView>],
) -> Result<Vec<PhotoGeometry>, MatchingError> {
    (0..p.photos.len())
        .map(|k| {
            let mut g = whole_geometry(p, k, scan)?;
            if let Some(v) = views[k] {
                g.view = v;
            }
            Ok(g)
        })
        .collect()
}

/// Photo `k`'s image size, from its header (or its scan's sidecar).
fn size_of(p: &Project, k: usize, scan: &ScanReader) -> Result<(usize, usize), MatchingError> {
    let g = whole_geometry(p, k, scan)?;
    Ok((g.width, g.height))
}

/// The pixels of sensor `s` that see `extent` (xmin, ymin, xmax, ymax) at the heights
/// `heights`, with [`MARGIN_PX`], within its image.
pub fn window_seeing(s: &dyn Sensor, extent: [f64; 4], heights: [f64; 2]) -> PixelWindow {
    let (w, h) = s.image_size();
    let mut b = [f64::MAX, f64::MAX, f64::MIN, f64::MIN];
    let zs = [heights[0], 0.5 * (heights[0] + heights[1]), heights[1]];
    for i in 0..SAMPLES {
        for j in 0..SAMPLES {
            let f = |k: usize| k as f64 / (SAMPLES - 1) as f64;
            let x = extent[0] + f(i) * (extent[2] - extent[0]);
            let y = extent[1] + f(j) * (extent[3] - extent[1]);
            for z in zs {
                if let Ok(q) = s.try_ground_to_image(GroundM::new(x, y, z)) {
                    b = [
                        b[0].min(q.col),
                        b[1].min(q.row),
                        b[2].max(q.col),
                        b[3].max(q.row),
                    ];
                }
            }
        }
    }
    let m = MARGIN_PX as f64;
    let clip = |v: f64, n: usize| v.clamp(0.0, n as f64) as usize;
    let (c0, r0) = (clip(b[0] - m, w), clip(b[1] - m, h));
    let (c1, r1) = (clip((b[2] + m).ceil(), w), clip((b[3] + m).ceil(), h));
    if c1 <= c0 || r1 <= r0 {
        return PixelWindow {
            col0: 0,
            row0: 0,
            width: w.min(UNSEEN_SIDE),
            height: h.min(UNSEEN_SIDE),
        };
    }
    PixelWindow {
        col0: c0,
        row0: r0,
        width: c1 - c0,
        height: r1 - r0,
    }
}

/// Photo `k`'s geometry over its whole image, from the image's header (and a scan's sidecar)
/// alone.
fn whole_geometry(
    p: &Project,
    k: usize,
    scan: &ScanReader,
) -> Result<PhotoGeometry, MatchingError> {
    let ph = &p.photos[k];
    let err = |message: String| MatchingError::Photo {
        id: ph.id.clone(),
        message,
    };
    match &ph.source {
        Source::Scan { sidecar } => {
            let s = scan(sidecar).map_err(err)?;
            Ok(PhotoGeometry {
                frame: s.frame,
                interior: s.interior,
                width: s.frame.width,
                height: s.frame.height,
                view: PixelView::whole(s.frame.width, s.frame.height),
            })
        }
        Source::Image { path, .. } | Source::Model { path, .. } => {
            let (w, h) = crate::image::grey_size(path).map_err(|e| err(e.to_string()))?;
            let (frame, interior) = frame_and_interior(p, k, w, h)?;
            Ok(PhotoGeometry {
                frame,
                interior,
                width: w,
                height: h,
                view: PixelView::whole(w, h),
            })
        }
    }
}

/// Which photo point each pixel of photo `k`'s whole `w × h` image shows, and its camera's
/// interior orientation (a unit grid for a photo with its own model, whose sensor is the
/// model: the type is kept whole).
fn frame_and_interior(
    p: &Project,
    k: usize,
    w: usize,
    h: usize,
) -> Result<(crate::geometry::PixelToPhoto, Interior), MatchingError> {
    let ph = &p.photos[k];
    let err = |message: String| MatchingError::Photo {
        id: ph.id.clone(),
        message,
    };
    match &ph.source {
        Source::Image { camera, .. } => Ok((
            frame_of(camera, w, h)
                .ok_or_else(|| err("its camera's pixel_to_photo is singular".into()))?,
            Interior {
                focal_mm: camera.focal_mm,
                principal_point: camera.principal_point,
                lens: camera.lens,
            },
        )),
        Source::Model { path, model } => {
            if let GivenModel::Pushbroom(m) = model.as_ref() {
                if (m.columns, m.lines) != (w, h) {
                    return Err(err(format!(
                        "its line-scanner model is for {} × {} pixels, its image {} has {w} × {h}",
                        m.columns,
                        m.lines,
                        path.display(),
                    )));
                }
            }
            Ok((
                centred_grid(w, h, 1.0).into(),
                Interior {
                    focal_mm: 1.0,
                    principal_point: crate::coords::PhotoMm::new(0.0, 0.0),
                    lens: crate::geometry::Lens::NONE,
                },
            ))
        }
        Source::Scan { .. } => Err(err(
            "a scan's geometry comes with its pixels (a defect of the caller)".into(),
        )),
    }
}

/// Loads photo `k` of the project: `view` of its image (`None`: the whole image as it is).
pub fn load_photo(
    p: &Project,
    k: usize,
    scan: &ScanReader,
    view: Option<PixelView>,
) -> Result<Photo, MatchingError> {
    load_photo_with(p, k, scan, view, &crate::matching::progress::Silent)
}

/// [`load_photo`], its pixels counted on `progress` as they are read.
fn load_photo_with(
    p: &Project,
    k: usize,
    scan: &ScanReader,
    view: Option<PixelView>,
    progress: &dyn Progress,
) -> Result<Photo, MatchingError> {
    let max = p.limits.max_memory_mb << 20;
    let ph = &p.photos[k];
    let err = |message: String| MatchingError::Photo {
        id: ph.id.clone(),
        message,
    };
    // A scan's image and grid come from its hand-over; an image's grid from the project.
    let (path, handed) = match &ph.source {
        Source::Scan { sidecar } => {
            let s = scan(sidecar).map_err(err)?;
            (s.image, Some((s.frame, s.interior)))
        }
        Source::Image { path, .. } | Source::Model { path, .. } => (path.clone(), None),
    };
    let path = path.as_path();
    let (w, h) = crate::image::grey_size(path).map_err(|e| err(e.to_string()))?;
    let view = view.unwrap_or(PixelView::whole(w, h));
    let image = crate::image::load_grey_reduced_with(
        path,
        view.window,
        view.factor,
        max,
        &|n| progress.advance(n),
    )
    .map_err(|e| {
        let hint = if p.extent.is_none() && e.to_string().contains("the limit is") {
            ": give the project's [dem] extent to read only the part of each image that sees it, a coarser [dem] photo_level, or raise --max-memory"
        } else {
            ""
        };
        err(format!("{e}{hint}"))
    })?;
    let (frame, interior) = match handed {
        Some((frame, interior)) => {
            if (frame.width, frame.height) != (w, h) {
                return Err(err(format!(
                    "its image {} is {w} × {h} px, its sidecar's grid {} × {}",
                    path.display(),
                    frame.width,
                    frame.height
                )));
            }
            (frame, interior)
        }
        None => frame_and_interior(p, k, w, h)?,
    };
    Ok(Photo {
        image,
        frame,
        interior,
        view,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::matching::block::photo::ScanImage;

    /// "auto": the coarsest level with pixels at most half a cell and [`MIN_LEVEL_SIDE`] a
    /// side. A 12 800 px scan of 0.0625 m pixels, 1 m posts: 0.5 m at level 3 (1 600 px);
    /// the same film at 800 px (1 m pixels): as scanned; a 600 px photo of 5 m pixels under
    /// 80 m posts: as scanned (below 1 024 px a side whatever the cell); a pixel of no size
    /// (a sensor that cannot say): as scanned; never beyond the deepest level.
    #[test]
    fn auto_keeps_two_pixels_a_post_and_a_thousand_a_side() {
        assert_eq!(level_for(0.0625, 1.0, 12_800), 3);
        assert_eq!(level_for(0.25, 1.0, 3_200), 1);
        assert_eq!(level_for(1.0, 1.0, 800), 0);
        assert_eq!(level_for(5.4, 80.0, 640), 0);
        assert_eq!(level_for(5.4, 80.0, 4_096), 2);
        assert_eq!(level_for(f64::NAN, 1.0, 12_800), 0);
        assert_eq!(
            level_for(0.001, 1000.0, 1 << 30),
            crate::matching::project::MAX_PHOTO_LEVEL
        );
    }

    /// Two photos each within the memory limit but not together are refused before either
    /// is read, naming the total and the limit; with the limit raised, they pass.
    #[test]
    fn photos_held_together_are_checked_against_the_limit() {
        let dir = tempfile::tempdir().unwrap();
        let img = image::GrayImage::new(1500, 1500);
        for n in ["a.tif", "b.tif"] {
            img.save(dir.path().join(n)).unwrap();
        }
        let project = |mib: u64| {
            let text = format!(
                "format = 2\ncrs = \"local\"\n[camera.c]\nfocal_mm = 153.0\npixel_mm = 0.02\n\
                 [[photo]]\nid = \"a\"\nimage = \"a.tif\"\ncamera = \"c\"\nposition = [0.0, 0.0, 1000.0]\nangles_deg = [0.0, 0.0, 0.0]\n\
                 [[photo]]\nid = \"b\"\nimage = \"b.tif\"\ncamera = \"c\"\nposition = [100.0, 0.0, 1000.0]\nangles_deg = [0.0, 0.0, 0.0]\n\
                 [dem]\ncell_m = 10.0\nheights = [0.0, 100.0]\n[limits]\nmax_memory_mb = {mib}\n"
            );
            Project::parse(&text, &dir.path().join("project.toml")).unwrap()
        };
        let no_scans = |_: &std::path::Path| -> Result<ScanImage, String> {
            Err("no scans in this project".into())
        };
        // 1500² × 4 bytes = 8.6 MiB each, 17.2 together.
        let e = check_held(&project(16), &no_scans, &[None, None])
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("17 MiB") && e.contains("the limit is 16 MiB"),
            "{e}"
        );
        check_held(&project(18), &no_scans, &[None, None]).unwrap();
    }
}
