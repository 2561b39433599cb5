//! Certificates of the simulated world, written as a calibration laboratory would issue them
//! (the TOML format the rig's README documents): the plate's crosses at their calibrated
//! positions, and the film camera's fiducials with the certificate's own small errors. The host reads them through its own parser; nothing else is shared.

use crate::film::{FiducialShape, Film};
use crate::plate::Plate;
use std::fmt::Write;

/// The carriage plate's certificate: every cross where it really is, to 0.01 µm.
pub fn plate_certificate(plate: &Plate, seed: u64) -> String {
    let mut s = String::new();
    let _ = writeln!(
        s,
        "# Calibration certificate of the simulated carriage plate (simulator seed {seed}).\n\
         [plate]\nname = \"simulated AC1 carriage plate, seed {seed}\"\narm_um = {:.1}\n\
         line_um = {:.1}\npolarity = \"dark_on_clear\"",
        plate.arm_um, plate.line_um
    );
    for c in &plate.crosses {
        let _ = writeln!(
            s,
            "\n[[cross]]\nid = {}\nx_um = {:.2}\ny_um = {:.2}",
            c.id, c.true_um[0], c.true_um[1]
        );
    }
    s
}

/// The film camera's certificate: each fiducial's calibrated photo coordinates (true position
/// plus the certificate's error), group and form.
pub fn camera_certificate(film: &Film, seed: u64) -> String {
    let mut s = String::new();
    let _ = writeln!(
        s,
        "# Calibration certificate of the simulated RC10-like film camera (simulator seed {seed}).\n\
         [camera]\nname = \"simulated RC10, seed {seed}\"\nfocal_length_mm = 153.0\n\
         polarity = \"dark_on_clear\"\n\n\
         [shapes.corner]\nkind = \"ring_with_dot\"\nring_radius_um = 300.0\ndot_radius_um = 40.0\n\
         line_um = 40.0\n\n\
         [shapes.mid_side]\nkind = \"dot_with_line\"\ndot_radius_um = 60.0\nline_um = 40.0\n\
         from_um = 150.0\nto_um = 600.0"
    );
    if let Some(m) = &film.mark_file {
        s += &m.certificate_shape("from_file");
    }
    if film
        .fiducials
        .iter()
        .any(|f| f.shape == FiducialShape::RingDotSpokes)
    {
        let _ = writeln!(
            s,
            "\n[shapes.corner_spokes]\nkind = \"parts\"\n\
             [[shapes.corner_spokes.part]]\nkind = \"dot\"\nradius = 40.0\n\
             [[shapes.corner_spokes.part]]\nkind = \"ring\"\nradius = 300.0\nwidth = 40.0\n\
             [[shapes.corner_spokes.part]]\nkind = \"spokes\"\ncount = 4\nfrom = 340.0\nto = 440.0\nwidth = 40.0"
        );
    }
    for f in &film.fiducials {
        let group = if f.id <= 4 { "corner" } else { "mid_side" };
        let shape = match f.shape {
            FiducialShape::RingWithDot => "corner",
            FiducialShape::DotWithLine => "mid_side",
            FiducialShape::RingDotSpokes => "corner_spokes",
            FiducialShape::FromFile => "from_file",
        };
        let _ = writeln!(
            s,
            "\n[[fiducial]]\nid = {}\nx_mm = {:.4}\ny_mm = {:.4}\ngroup = \"{group}\"\nshape = \"{shape}\"",
            f.id,
            f.photo_mm[0] + f.cert_error_um[0] / 1000.0,
            f.photo_mm[1] + f.cert_error_um[1] / 1000.0
        );
    }
    s
}
