//! Writing a run's files.

use crate::coords::GroundM;
use crate::geometry::Crs;
use crate::geometry::{PhotoSensor, Sensor};
use crate::matching::block::photo::Photo;
use crate::matching::error::MatchingError;
use crate::matching::grid::{Comparison, ElevationGrid, NodeQuality};
use crate::matching::products::files::{
    write_geotiff, write_las, write_ortho, write_ply, write_quality,
};
use crate::matching::products::maps::{write_error_map, write_hillshade, write_sigma_map};
use crate::matching::products::ortho::{orthophoto, View};
use crate::matching::products::outputs as O;
use crate::matching::MatchedPoint;
use serde::Serialize;
use std::path::Path;

/// An output directory must be new, empty, or hold only an earlier run's outputs (a run that
/// was killed half way left some of them, or `.part` files): anything else is not ours to
/// replace.
pub(crate) fn check_out_dir(out: &Path) -> Result<(), MatchingError> {
    let foreign = crate::atomic::foreign_files(out, crate::matching::products::outputs::is_output)
        .map_err(|source| MatchingError::Write {
            dir: out.to_path_buf(),
            cause: source,
        })?;
    if foreign.is_empty() {
        return Ok(());
    }
    Err(MatchingError::Foreign {
        dir: out.to_path_buf(),
        files: foreign.join(", "),
    })
}

/// The files every run leaves in `out`: the model in `crs` with its quality and the
/// orthophoto from `views`, its points (PLY and LAS), the hillshade, the error map against the
/// reference (removed when there is none, so that a rerun leaves no old one) and the report.
/// Each written whole or not at all.
#[allow(clippy::too_many_arguments)] // the run's products, each a different thing to write
pub(crate) fn write_outputs(
    out: &Path,
    grid: &ElevationGrid,
    points: &[MatchedPoint],
    quality: &NodeQuality,
    views: &[View<'_>],
    reference: Option<(&ElevationGrid, &Comparison)>,
    crs: Crs,
    report: &impl Serialize,
    summary: &[(String, String)],
) -> std::io::Result<()> {
    std::fs::create_dir_all(out)?;
    write_geotiff(&out.join(O::DEM), grid, crs)?;
    write_quality(&out.join(O::QUALITY), grid, crs, quality)?;
    let sig: Vec<f32> = quality
        .sigma_m
        .iter()
        .copied()
        .filter(|v| v.is_finite())
        .collect();
    let rms =
        (sig.iter().map(|&v| (v as f64).powi(2)).sum::<f64>() / sig.len().max(1) as f64).sqrt();
    write_sigma_map(
        &out.join(O::QUALITY_MAP),
        grid,
        &quality.sigma_m,
        &format!("{crs}, RMS {rms:.2} m over {} nodes", sig.len()),
    )?;
    write_ortho(&out.join(O::ORTHO), grid, crs, &orthophoto(grid, views))?;
    write_ply(&out.join(O::POINTS_PLY), points, crs)?;
    write_las(&out.join(O::POINTS_LAS), points, crs)?;
    write_hillshade(&out.join(O::HILLSHADE), grid, crs)?;
    match reference {
        Some((g, c)) => {
            let d = grid.differences(|x, y| g.interpolate(x, y));
            let summary = format!(
                "RMSE {:.2} m, mean {:+.2} m, over {} nodes",
                c.rmse_m, c.mean_m, c.nodes
            );
            let span = crate::picture::nice((3.0 * c.rmse_m).max(0.1)) * 2.0;
            write_error_map(&out.join(O::ERROR_MAP), grid, &d, span, &summary)?;
        }
        None => {
            let _ = std::fs::remove_file(out.join(O::ERROR_MAP));
        }
    }
    crate::atomic::write_json(&out.join(O::REPORT_JSON), report)?;
    let mut maps = vec![
        (
            O::HILLSHADE.to_string(),
            format!("Heights in colour, shaded from the north-west ({crs})"),
        ),
        (
            O::QUALITY_MAP.to_string(),
            "Each node's standard deviation, m".to_string(),
        ),
    ];
    if reference.is_some() {
        maps.push((
            O::ERROR_MAP.into(),
            "The model minus the reference, m".into(),
        ));
    }
    crate::matching::products::html::Page {
        title: "rig dtm: elevation model".into(),
        intro: format!("Every file of this run is in this folder; the figures below are from report.json. Ground coordinates in {crs}."),
        sections: vec![
            crate::matching::products::html::Section {
                heading: "Figures".into(),
                rows: summary.to_vec(),
                ..Default::default()
            },
            crate::matching::products::html::Section {
                heading: "Maps".into(),
                pictures: maps,
                ..Default::default()
            },
            crate::matching::products::html::Section {
                heading: "Data".into(),
                links: O::data_links(),
                ..Default::default()
            },
        ],
    }
    .write(&out.join(O::REPORT_HTML))
}

/// A format-2 run's model files ([`crate::matching::products::write::write_outputs`]), the orthophoto from
/// `photos` through their `sensors`.
#[allow(clippy::too_many_arguments)]
pub(crate) fn write_model(
    out: &Path,
    grid: &ElevationGrid,
    points: &[MatchedPoint],
    quality: &crate::matching::grid::NodeQuality,
    photos: &[Photo],
    sensors: &[PhotoSensor],
    reference: Option<(&ElevationGrid, &Comparison)>,
    crs: Crs,
    report: &impl Serialize,
    summary: &[(String, String)],
) -> std::io::Result<()> {
    let projections: Vec<_> = sensors
        .iter()
        .map(|s| move |g: GroundM| s.ground_to_image(g))
        .collect();
    let views: Vec<View> = photos
        .iter()
        .zip(&projections)
        .map(|(ph, f)| View {
            image: &ph.image,
            project: f,
        })
        .collect();
    crate::matching::products::write::write_outputs(
        out, grid, points, quality, &views, reference, crs, report, summary,
    )
}
