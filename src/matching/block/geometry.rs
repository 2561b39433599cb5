//! What a multiphoto matcher needs to know about a block before it matches: which photo is
//! the reference (its pixels or its datum) and which overlap it, how many pixels of parallax
//! a metre of height makes, how large a ground pixel is and how high the sensor flies. Used by
//! the MGCM and the object-space matching alike; through [`Sensor`] only.

use crate::coords::PixelXY;
use crate::geometry::Sensor;
use crate::matching::block::orient::orient;
use crate::matching::block::orient::Oriented;
use crate::matching::block::photo::Photo;
use crate::matching::error::MatchingError;
use crate::matching::project::Project;

/// The photos that overlap photo `k` (`overlapping`: the pairs whose footprints overlap).
pub fn partners(overlapping: &[(usize, usize)], k: usize) -> Vec<usize> {
    overlapping
        .iter()
        .filter_map(|&(i, j)| {
            if i == k {
                Some(j)
            } else if j == k {
                Some(i)
            } else {
                None
            }
        })
        .collect()
}

/// The references a block needs: `first` (with `others`, the photos it overlaps), then,
/// while some overlapping pair has neither photo as a reference, the photo in most such
/// pairs (the first of those), with the photos it overlaps. A strip's first photo sees only
/// its own overlaps; one reference per pair covers every ground two photos see.
pub fn references_covering(
    first: usize,
    others: Vec<usize>,
    overlapping: &[(usize, usize)],
) -> Vec<(usize, Vec<usize>)> {
    let mut refs = vec![(first, others)];
    loop {
        let open: Vec<(usize, usize)> = overlapping
            .iter()
            .copied()
            .filter(|&(i, j)| !refs.iter().any(|(r, _)| *r == i || *r == j))
            .collect();
        let Some(next) = open.iter().flat_map(|&(i, j)| [i, j]).max_by_key(|&k| {
            (
                open.iter().filter(|&&(i, j)| i == k || j == k).count(),
                std::cmp::Reverse(k),
            )
        }) else {
            return refs;
        };
        refs.push((next, partners(overlapping, next)));
    }
}

/// The reference photo and the photos overlapping it. `named` (a photo id from `section` of
/// project `p`) if given, else the photo overlapping most others (the first of those);
/// `overlapping` are the pairs whose footprints overlap, `z` the height they were found at.
pub fn choose_reference(
    p: &Project,
    overlapping: &[(usize, usize)],
    named: Option<&str>,
    section: &str,
    z: f64,
) -> Result<(usize, Vec<usize>), MatchingError> {
    let r = match named {
        Some(id) => p.photos.iter().position(|ph| ph.id == id).ok_or_else(|| {
            MatchingError::Heights(format!(
                "{}: [{section}] reference = \"{id}\": no photo of that id in the project (its photos: {})",
                p.path.display(),
                p.photos.iter().map(|ph| ph.id.as_str()).collect::<Vec<_>>().join(", ")
            ))
        })?,
        None => (0..p.photos.len())
            .max_by_key(|&k| (partners(overlapping, k).len(), std::cmp::Reverse(k)))
            .unwrap_or(0),
    };
    let others = partners(overlapping, r);
    if others.is_empty() {
        return Err(MatchingError::Heights(format!(
            "{}: [{section}] reference = \"{}\" overlaps no other photo at {z:.0} m: name another",
            p.path.display(),
            p.photos[r].id,
        )));
    }
    Ok((r, others))
}

/// A block as a multiphoto matcher starts it: the photos oriented, the heights, extent and
/// overlaps ([`orient`]), the middle height, and the reference photo with the photos
/// overlapping it ([`choose_reference`]).
pub struct Block {
    pub oriented: Oriented,
    pub mid: f64,
    pub reference: usize,
    pub others: Vec<usize>,
}

/// [`Block`] of project `p` for `photos`, the reference `named` in `[section]` (or chosen).
pub fn block(
    p: &Project,
    photos: &[Photo],
    named: Option<&str>,
    section: &str,
) -> Result<Block, MatchingError> {
    let geometry: Vec<_> = photos.iter().map(Photo::geometry).collect();
    let oriented = orient(p, &geometry)?;
    let mid = 0.5 * (oriented.heights[0] + oriented.heights[1]);
    let (reference, others) = choose_reference(p, &oriented.overlapping, named, section, mid)?;
    Ok(Block {
        oriented,
        mid,
        reference,
        others,
    })
}

/// Pixels of parallax per metre of height at reference pixel `q` and height `z`: the largest
/// over the search photos of how far their image of the reference's ray moves per metre
/// (NaN where the ray does not reach `z`).
pub fn parallax_per_m(reference: &dyn Sensor, searches: &[&dyn Sensor], q: PixelXY, z: f64) -> f64 {
    let (Some(a), Some(b)) = (
        reference.image_to_ground(q, z + 1.0),
        reference.image_to_ground(q, z - 1.0),
    ) else {
        return f64::NAN;
    };
    searches
        .iter()
        .filter_map(|s| {
            let (p, m) = (s.ground_to_image(a)?, s.ground_to_image(b)?);
            Some(0.5 * (p.col - m.col).hypot(p.row - m.row))
        })
        .fold(0.0, f64::max)
}

/// The height of the sensor above the ground at pixel `q` and height `z`, m, from how the
/// ground footprint of a pixel grows with the distance: for a frame camera d = (Z₀ − z) and a
/// pixel covers p·d/f, so d = gsd(z)·Δz / (gsd(z) − gsd(z + Δz)).
pub fn flying_height(s: &dyn Sensor, q: PixelXY, z: f64) -> Option<f64> {
    let dz = 50.0;
    let (g0, g1) = (s.ground_pixel_m(q, z)?, s.ground_pixel_m(q, z + dz)?);
    let d = g0 * dz / (g0 - g1);
    (d.is_finite() && d > 0.0).then_some(d)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A strip of four photos, each overlapping the next and the one after (60–65 % overlap):
    /// the photo overlapping most is the first reference; the pairs it leaves (3–4, 1–3 or
    /// 2–4) take one more, so every overlapping pair has a reference among its photos.
    #[test]
    fn every_overlapping_pair_has_a_reference() {
        let pairs = [(0, 1), (1, 2), (2, 3), (0, 2), (1, 3)];
        let refs = references_covering(1, vec![0, 2, 3], &pairs);
        assert_eq!(refs.len(), 2, "{refs:?}");
        for (i, j) in pairs {
            assert!(
                refs.iter().any(|(r, _)| *r == i || *r == j),
                "{i}-{j}: {refs:?}"
            );
        }
        assert_eq!(refs[1], (2, vec![1, 3, 0]), "{refs:?}");
        // Three photos in a strip whose ends do not meet: photo 1 alone covers both pairs.
        assert_eq!(
            references_covering(1, vec![0, 2], &[(0, 1), (1, 2)]).len(),
            1
        );
    }
    use crate::coords::GroundM;
    use crate::matching::block::orient::vertical_sensor;

    /// Vertical photos, f = 153 mm, 0.1 mm pixels, 1000 m above a datum, base 120 m: at
    /// height h a pixel covers 0.1·(1000 − h)/153 m, the parallax is f·B/((Z₀ − h)·s) px and
    /// changes by f·B/((Z₀ − h)²·s) px per metre, the flying height is Z₀ − h.
    #[test]
    fn closed_forms_of_vertical_photos() {
        let a = vertical_sensor(GroundM::new(0.0, 0.0, 1000.0), 153.0, 400, 0.1);
        let b = vertical_sensor(GroundM::new(120.0, 0.0, 1000.0), 153.0, 400, 0.1);
        let q = PixelXY::new(200.0, 200.0);
        let h = 50.0;
        let gsd = a.ground_pixel_m(q, h).unwrap();
        assert!((gsd - 0.1 * 950.0 / 153.0).abs() < 1e-9, "{gsd}");
        let pp = parallax_per_m(&a, &[&b], q, h);
        let want = 153.0 * 120.0 / (950.0f64.powi(2) * 0.1);
        assert!((pp - want).abs() < 1e-4 * want, "{pp} vs {want}");
        let d = flying_height(&a, q, h).unwrap();
        assert!((d - 950.0).abs() < 1e-6, "{d}");
    }
}
