//! The one driver of the matchers: a project's loaded photos to a model in an output
//! directory. It checks the directory and reads the reference DEM before the long work (a bad
//! path fails first), hands the method named by `[matching] method` one [`Run`], and returns
//! its report; every method writes its model through [`Run::write_model`].

use crate::coords::PixelView;
use crate::matching::block::photo::Photo;
use crate::matching::methods::context::{prepare, Run};
use crate::matching::methods::mgcm::run::MgcmReport;
use crate::matching::methods::oslsm::run::OslsmReport;
use crate::matching::methods::sweep::SweepReport;
use crate::matching::progress::Progress;
use crate::matching::project::{Method, Project};
use crate::matching::MatchingError;
use serde::Serialize;
use std::path::Path;

/// A run's report, as its method wrote it into report.json.
#[derive(Debug, Clone, Serialize)]
#[serde(untagged)]
pub enum Report {
    Sweep(Box<SweepReport>),
    Mgcm(Box<MgcmReport>),
    Oslsm(Box<OslsmReport>),
}

impl Report {
    /// The model's figures, whichever method made it.
    pub fn model(&self) -> &crate::matching::accuracy::figures::ModelFigures {
        match self {
            Report::Sweep(r) => &r.model,
            Report::Mgcm(r) => &r.model,
            Report::Oslsm(r) => &r.model,
        }
    }

    /// The figures a person looks at first, for report.html.
    pub fn summary(&self) -> Vec<(String, String)> {
        match self {
            Report::Sweep(r) => r.summary(),
            Report::Mgcm(r) => r.summary(),
            Report::Oslsm(r) => r.summary(),
        }
    }

    /// The ground coordinates' system of the model.
    pub fn crs(&self) -> crate::geometry::Crs {
        match self {
            Report::Sweep(r) => r.crs,
            Report::Mgcm(r) => r.head.crs,
            Report::Oslsm(r) => r.head.crs,
        }
    }
}

/// What can be refused before a pixel is read: the photos' views held at once against the
/// memory limit and, for the sweep, every pair's work and memory from the views' sizes (a
/// 12 800² pair at `photo_level = 0` is refused in a second, not after reading 400 Mpx).
/// Returns the views, for [`crate::matching::block::photos::load_viewed`].
pub fn preflight(
    p: &Project,
    scan: &crate::matching::block::photo::ScanReader,
    max_memory_mb: Option<u64>,
) -> Result<Vec<Option<PixelView>>, MatchingError> {
    use crate::matching::block::photos::{check_held, geometries, views};
    let v = views(p, scan)?;
    check_held(p, scan, &v)?;
    if p.matching.method == Method::Sweep {
        let g = geometries(p, scan, &v)?;
        crate::matching::methods::sweep::plan::plan(p, &g, max_memory_mb)?;
    }
    Ok(v)
}

/// Runs project `p`'s method on its loaded `photos` into `out`.
pub fn run(
    p: &Project,
    photos: &[Photo],
    out: &Path,
    max_memory_mb: Option<u64>,
    progress: &dyn Progress,
) -> Result<Report, MatchingError> {
    let reference = prepare(p, out)?;
    let run = Run {
        project: p,
        photos,
        out,
        reference: reference.as_ref(),
        max_memory_mb,
        progress,
    };
    use crate::matching::methods::{mgcm, oslsm, sweep};
    Ok(match p.matching.method {
        Method::Sweep => Report::Sweep(Box::new(sweep::run(&run)?)),
        Method::Mgcm => Report::Mgcm(Box::new(mgcm::run::run(&run)?)),
        Method::Oslsm => Report::Oslsm(Box::new(oslsm::run::run(&run)?)),
    })
}
