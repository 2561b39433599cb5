//! What every method is handed by the driver ([`crate::matching::run`]): the project, its
//! photos, the output directory, the reference DEM read beforehand, the memory limit and
//! where to report progress; and the one writer of a model's files.

use crate::geometry::control_fit::ControlFit;
use crate::geometry::{Crs, PhotoSensor, Resection};
use crate::matching::accuracy::figures::ModelFigures;
use crate::matching::block::photo::Photo;
use crate::matching::grid::{ElevationGrid, NodeQuality};
use crate::matching::products::write::{check_out_dir, write_model};
use crate::matching::progress::Progress;
use crate::matching::project::Project;
use crate::matching::{MatchedPoint, MatchingError};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// What a run must know before its long work, so that a bad path fails first: that `out`
/// can take its files, and the project's reference DEM.
pub fn prepare(p: &Project, out: &Path) -> Result<Option<ElevationGrid>, MatchingError> {
    check_out_dir(out)?;
    ModelFigures::read_reference(p)
}

/// What every method is handed: the project, its photos, where to write, the reference DEM
/// read beforehand, the memory limit and where to report progress.
pub struct Run<'a> {
    pub project: &'a Project,
    pub photos: &'a [Photo],
    pub out: &'a Path,
    /// The project's `[check] reference`, read before the matching ([`prepare`]).
    pub reference: Option<&'a ElevationGrid>,
    /// `--max-memory`, over the project's `[limits] max_memory_mb`.
    pub max_memory_mb: Option<u64>,
    pub progress: &'a dyn Progress,
}

impl Run<'_> {
    /// The same run into another directory (the object-space matching's coarse model).
    pub fn into_dir<'b>(&'b self, out: &'b Path) -> Run<'b> {
        Run {
            project: self.project,
            photos: self.photos,
            out,
            reference: self.reference,
            max_memory_mb: self.max_memory_mb,
            progress: self.progress,
        }
    }

    /// The model's files (dem.tif, quality.tif, ortho.tif, the point clouds, the maps,
    /// report.json and report.html) from any method.
    pub fn write_model(
        &self,
        figures: &ModelFigures,
        points: &[MatchedPoint],
        quality: &NodeQuality,
        sensors: &[PhotoSensor],
        report: &impl Serialize,
        summary: &[(String, String)],
    ) -> Result<(), MatchingError> {
        // Every method's report says which part of each photo it matched, and how much
        // smaller it was read ([`crate::matching::block::photos::views`]).
        let read: Vec<PhotoRead> = self
            .project
            .photos
            .iter()
            .zip(self.photos)
            .map(|(ph, photo)| PhotoRead {
                id: ph.id.clone(),
                window: photo.view.window,
                factor: photo.view.factor,
                size: photo.view.size(),
            })
            .collect();
        let mut report = serde_json::to_value(report).map_err(|e| MatchingError::Write {
            dir: self.out.to_path_buf(),
            cause: std::io::Error::other(e),
        })?;
        if let Some(o) = report.as_object_mut() {
            o.insert(
                "photos_read".into(),
                serde_json::to_value(&read).unwrap_or_default(),
            );
        }
        let mut summary = summary.to_vec();
        if let Some(f) = read.iter().map(|r| r.factor).max().filter(|&f| f > 1) {
            summary.insert(
                0,
                (
                    "photos read".into(),
                    format!(
                        "averaged over blocks of up to {f} × {f} pixels as they were read ([dem] photo_level; \"auto\": two pixels a post of {} m)",
                        self.project.cell_m
                    ),
                ),
            );
        }
        write_model(
            self.out,
            &figures.grid,
            points,
            quality,
            self.photos,
            sensors,
            self.reference.zip(figures.comparison.as_ref()),
            self.project.crs,
            &report,
            &summary,
        )
        .map_err(|cause| MatchingError::Write {
            dir: self.out.to_path_buf(),
            cause,
        })
    }
}

/// Which part of a photo a run matched (`window`, the whole image's pixels), averaged over
/// blocks of `factor` × `factor` pixels into `size`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PhotoRead {
    pub id: String,
    pub window: crate::coords::PixelWindow,
    pub factor: usize,
    pub size: (usize, usize),
}

/// The head of a multiphoto method's report.json (flattened into its top level): what was
/// run on what, and the orientations the model took.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ReportHead {
    pub project: PathBuf,
    pub method: String,
    pub crs: Crs,
    pub resected: Vec<(String, Resection)>,
    /// Given models corrected by their control points.
    #[serde(default)]
    pub corrected: Vec<(String, ControlFit)>,
}

impl ReportHead {
    /// The first lines of a summary: the method in words, the heights tried and the models
    /// the control points corrected.
    pub fn lines(&self, method: String, heights_m: [f64; 2]) -> Vec<(String, String)> {
        let mut v = vec![
            ("method".to_string(), method),
            (
                "heights tried".into(),
                format!("{:.1} … {:.1} m", heights_m[0], heights_m[1]),
            ),
        ];
        v.extend(crate::matching::block::orient::corrected_lines(
            &self.corrected,
        ));
        v
    }
}
