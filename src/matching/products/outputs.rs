//! The one list of the files `rig dtm` writes into its output directory: their names, what
//! each holds and which runs write it. The writers take their names from here, the check of an
//! output directory knows its own files by it, the HTML report links the data files from it,
//! the CLI's summary lists them from it, and a test holds docs/elevation-models.md's table to
//! it.

/// Which runs write a file.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Writer {
    /// Every run, whichever matcher.
    Every,
    /// Every run given a reference DEM (`[check] reference`).
    WithReference,
    /// The height sweep (`method = "sweep"`).
    Sweep,
    /// The multiphoto matching (`method = "mgcm"`).
    Mgcm,
    /// The multiphoto matching given a reference DEM (its accuracy analysis).
    MgcmWithReference,
    /// The object-space matching (`method = "oslsm"`).
    Oslsm,
    /// A project whose photos are approximate: the block is oriented first.
    Orienting,
}

impl Writer {
    /// Which runs, in words (docs/elevation-models.md's table says it so).
    pub fn said(self) -> &'static str {
        match self {
            Writer::Every => "every run",
            Writer::WithReference => "a run with a reference DEM",
            Writer::Sweep => "the sweep",
            Writer::Mgcm => "MGCM",
            Writer::MgcmWithReference => "MGCM with a reference DEM",
            Writer::Oslsm => "OSLSM",
            Writer::Orienting => "a project with approximate photos",
        }
    }
}

/// One file of a run's output directory.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct OutputFile {
    pub name: &'static str,
    /// What it holds and in what form.
    pub holds: &'static str,
    pub writer: Writer,
    /// Linked from report.html's "Data" (the files a GIS or a script reads).
    pub data: bool,
}

pub const DEM: &str = "dem.tif";
pub const QUALITY: &str = "quality.tif";
pub const ORTHO: &str = "ortho.tif";
pub const POINTS_LAS: &str = "points.las";
pub const POINTS_PLY: &str = "points.ply";
pub const REPORT_JSON: &str = "report.json";
pub const REPORT_HTML: &str = "report.html";
pub const QUALITY_MAP: &str = "quality.png";
pub const HILLSHADE: &str = "hillshade.png";
pub const ERROR_MAP: &str = "error.png";
pub const MAPPINGS: &str = "mappings.json";
pub const POINTS_CSV: &str = "points.csv";
pub const ACCURACY_TXT: &str = "accuracy.txt";
pub const ACCURACY_JSON: &str = "accuracy.json";
pub const COARSE: &str = "coarse";
pub const REFLECTANCE: &str = "reflectance.tif";
pub const CONVERGENCE: &str = "convergence.png";
/// The folder of the block's orientation, when `rig dtm` ran it first
/// ([`crate::orientation::run::before_matching`]).
pub const ORIENTATION: &str = "orientation";

const fn file(name: &'static str, holds: &'static str, writer: Writer, data: bool) -> OutputFile {
    OutputFile {
        name,
        holds,
        writer,
        data,
    }
}

/// Every file a run may write, in the order the summaries list them.
pub const OUTPUTS: [OutputFile; 18] = [
    file(
        DEM,
        "heights, float32 GeoTIFF, nodata −9999",
        Writer::Every,
        true,
    ),
    file(
        QUALITY,
        "band 1 σ of each height (m), band 2 its correlation",
        Writer::Every,
        true,
    ),
    file(ORTHO, "orthophoto on the DEM grid", Writer::Every, true),
    file(POINTS_LAS, "matched points, LAS 1.2", Writer::Every, true),
    file(
        POINTS_PLY,
        "matched points with correlation and σ",
        Writer::Every,
        true,
    ),
    file(REPORT_JSON, "everything the run found", Writer::Every, true),
    file(
        REPORT_HTML,
        "the figures, maps and links on one page",
        Writer::Every,
        false,
    ),
    file(
        HILLSHADE,
        "heights in colour, shaded from the north-west",
        Writer::Every,
        false,
    ),
    file(
        QUALITY_MAP,
        "each node's standard deviation, m",
        Writer::Every,
        false,
    ),
    file(
        ERROR_MAP,
        "the model minus the reference, m",
        Writer::WithReference,
        false,
    ),
    file(
        MAPPINGS,
        "each pair's mapping functions (`[matching] mappings = \"file\"` reads them)",
        Writer::Sweep,
        false,
    ),
    file(
        POINTS_CSV,
        "every point, kept or refused, and why",
        Writer::Mgcm,
        false,
    ),
    file(
        ACCURACY_TXT,
        "the accuracy analysis against the reference, as a table",
        Writer::MgcmWithReference,
        false,
    ),
    file(
        ACCURACY_JSON,
        "the same analysis, for scripts",
        Writer::MgcmWithReference,
        false,
    ),
    file(
        COARSE,
        "the coarse model from the sweep (a run's own folder)",
        Writer::Oslsm,
        false,
    ),
    file(
        REFLECTANCE,
        "the terrain's reflectance on the groundels",
        Writer::Oslsm,
        false,
    ),
    file(
        CONVERGENCE,
        "the heights' and gains' changes per iteration",
        Writer::Oslsm,
        false,
    ),
    file(
        ORIENTATION,
        "the block's orientation, as `rig orient` writes it (its project.toml is the one matched)",
        Writer::Orienting,
        false,
    ),
];

/// Whether `name` is one of a run's files (an output directory holding only these, or their
/// `.part` names, may be written again).
pub fn is_output(name: &str) -> bool {
    OUTPUTS.iter().any(|f| f.name == name)
}

/// The names of the files a run of `by` writes (besides every run's), comma-separated, for a
/// summary line; those that need a reference DEM only `with_reference`.
pub fn listed(by: Option<Writer>, with_reference: bool) -> String {
    OUTPUTS
        .iter()
        // The folders are said apart (their summaries name what is in them).
        .filter(|f| f.name != COARSE && f.name != ORIENTATION)
        .filter(|f| {
            f.writer == Writer::Every
                || Some(f.writer) == by
                || (f.writer == Writer::WithReference && with_reference)
                || (f.writer == Writer::MgcmWithReference
                    && by == Some(Writer::Mgcm)
                    && with_reference)
        })
        .map(|f| f.name)
        .collect::<Vec<_>>()
        .join(", ")
}

/// report.html's links: the data files, with what each holds.
pub fn data_links() -> Vec<(String, String)> {
    OUTPUTS
        .iter()
        .filter(|f| f.data)
        .map(|f| (f.name.to_string(), f.holds.to_string()))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Each name once; a summary lists what its run writes and nothing of the others'.
    #[test]
    fn names_are_unique_and_summaries_list_their_runs() {
        let mut names: Vec<_> = OUTPUTS.iter().map(|f| f.name).collect();
        names.sort();
        names.dedup();
        assert_eq!(names.len(), OUTPUTS.len());
        let mgcm = listed(Some(Writer::Mgcm), true);
        assert!(mgcm.contains("accuracy.txt") && mgcm.contains("dem.tif"));
        assert!(mgcm.contains("error.png") && !mgcm.contains("reflectance.tif"));
        let alone = listed(Some(Writer::Mgcm), false);
        assert!(!alone.contains("accuracy.txt") && !alone.contains("error.png"));
        assert!(listed(None, true).contains("error.png"));
        assert_eq!(data_links().len(), 6);
    }
}
