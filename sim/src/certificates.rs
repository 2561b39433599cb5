//! Certificates of the simulated world, written as a calibration laboratory would issue them
//! (the TOML format the rig's README documents): the plate's crosses at their calibrated
//! positions. The host reads them through its own parser; nothing else is shared.

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
