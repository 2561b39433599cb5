//! The one error of a matching run, whichever method and project format: the project, the
//! photos and their orientation, the plan, the matching and the files written.

use crate::geometry::ResectionError;
use crate::matching::grid::GridError;
use crate::matching::project::ProjectError;
use std::path::PathBuf;

#[derive(Debug, thiserror::Error)]
pub enum MatchingError {
    #[error(transparent)]
    Project(#[from] ProjectError),
    #[error("photo `{id}`: {message}")]
    Photo { id: String, message: String },
    #[error("photo `{id}`: resection from {points} control points: {cause}")]
    Resection {
        id: String,
        points: usize,
        cause: ResectionError,
    },
    #[error("{0}")]
    Heights(String),
    #[error("[orientation] covariance: {0}")]
    Covariance(String),
    #[error("no two photos overlap on the ground at {z:.0} m (the middle of the heights tried){within}: {prints}; check [dem] heights (do they bracket the terrain?), [dem] extent and the photos' orientations")]
    NoOverlap {
        z: f64,
        /// Each photo's footprint at `z`, in the project's CRS.
        prints: String,
        /// " within [dem] extent …" when the project gives one.
        within: String,
    },
    #[error("photos `{left}` and `{right}`: {cause}")]
    Pair {
        left: String,
        right: String,
        cause: DtmError,
    },
    #[error("photos `{left}` and `{right}`: mapping functions {message}")]
    Mappings {
        left: String,
        right: String,
        message: String,
    },
    #[error("[matching] mappings_file {path}: {message}")]
    GivenMappings { path: PathBuf, message: String },
    #[error("the DEM grid: {0}")]
    Grid(String),
    /// Memory a method would take beyond the limit, with what it is for.
    #[error("{0}")]
    Memory(String),
    /// Nothing to match, or nothing matched, with why.
    #[error("{0}")]
    NoMatch(String),
    #[error("the object-space matching: {0}")]
    Oslsm(String),
    // The reference model and the output directory.
    #[error("reading the reference model {path}: {cause}")]
    Reference {
        path: PathBuf,
        cause: std::io::Error,
    },
    #[error(
        "{dir} holds files that are not a `rig dtm` run's ({files}): give a new or empty directory"
    )]
    Foreign { dir: PathBuf, files: String },
    #[error("writing into {dir}: {cause}")]
    Write { dir: PathBuf, cause: std::io::Error },
}

/// A pair's sweep refused before it starts (its work or memory beyond the budget), or its
/// grid.
#[derive(Debug, thiserror::Error)]
pub enum DtmError {
    #[error("the sweep would try up to {candidates:.3e} candidate heights ({pixels} pixels × {heights} heights); the limit is {limit:.3e}: narrow h_min … h_max, take a larger h_step or stride, read the photos smaller ([dem] photo_level), or raise [limits] max_candidates_g")]
    TooMuchWork {
        candidates: f64,
        pixels: u64,
        heights: u64,
        limit: f64,
    },
    #[error("the run would hold about {mib:.0} MiB (photos, height map, points); the limit is {limit_mib} MiB: take a larger stride, read the photos smaller ([dem] photo_level), or raise [limits] max_memory_mb (or --max-memory)")]
    TooMuchMemory { mib: f64, limit_mib: u64 },
    #[error(transparent)]
    Grid(#[from] GridError),
}
