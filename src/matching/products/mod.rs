//! What a run leaves: the one list of its files, the rasters and point clouds, the
//! orthophoto, the maps and the HTML report.

pub mod files;
pub mod html;
pub mod maps;
pub mod ortho;
pub mod outputs;
pub mod write;
