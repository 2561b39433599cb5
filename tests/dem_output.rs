//! The elevation model's GeoTIFF as GDAL sees it. `gdalinfo` (Debian's gdal-bin) is needed
//! when RIG_GDALINFO=1, as `.ci/run` sets after installing it; elsewhere the test says it
//! skipped the GDAL half and checks the file with the rig's own reader only.

mod common;

use common::gdal_tools as gdal;
use rig::geometry::Crs;
use rig::matching::grid::ElevationGrid;
use rig::matching::products::files::{read_geotiff, write_geotiff};
use std::process::Command;

#[test]
fn gdalinfo_reads_the_elevation_model() {
    let d = tempfile::tempdir().unwrap();
    let mut g = ElevationGrid::covering([5000.0, 7000.0, 5100.0, 7060.0], 5.0, 64).unwrap();
    g.z = (0..g.z.len())
        .map(|i| {
            if i % 5 == 0 {
                f32::NAN
            } else {
                250.0 + (i % 97) as f32
            }
        })
        .collect();
    let p = d.path().join("dem.tif");
    write_geotiff(&p, &g, Crs::Epsg(32617)).unwrap();
    assert_eq!(read_geotiff(&p).unwrap().cols, g.cols);
    let required = std::env::var("RIG_GDALINFO").is_ok_and(|v| v == "1");
    let out = match std::process::Command::new("gdalinfo")
        .arg("-stats")
        .arg(&p)
        .output()
    {
        Ok(o) => o,
        Err(e) => {
            assert!(!required, "RIG_GDALINFO=1 but gdalinfo cannot run: {e}");
            eprintln!("gdalinfo not installed: GDAL half skipped");
            return;
        }
    };
    let t = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{t}{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let want_origin = format!("Origin = ({:.15},{:.15})", g.x0 - 2.5, g.y0 + 2.5);
    let n_valid = g.z.iter().filter(|v| v.is_finite()).count();
    let valid = format!(
        "STATISTICS_VALID_PERCENT={:.2}",
        100.0 * n_valid as f64 / g.z.len() as f64
    );
    for want in [
        "Driver: GTiff/GeoTIFF",
        &format!("Size is {}, {}", g.cols, g.rows),
        "Type=Float32",
        "NoData Value=-9999",
        "Pixel Size = (5.000000000000000,-5.000000000000000)",
        "UTM zone 17N",
        "ID[\"EPSG\",32617]]",
        "COMPRESSION=DEFLATE",
        &want_origin,
        &valid,
    ] {
        assert!(t.contains(want), "gdalinfo lacks `{want}`:\n{t}");
    }
}

/// A model GDAL rewrote as pixel-is-point (the tie point then names a cell's centre) reads back
/// onto the same nodes: GDAL is the independent writer here.
#[test]
fn a_pixel_is_point_model_reads_onto_the_same_nodes() {
    if !gdal() {
        return;
    }
    let d = tempfile::tempdir().unwrap();
    let mut g = ElevationGrid::covering([1000.0, 2000.0, 1100.0, 2050.0], 10.0, 64).unwrap();
    g.z = (0..g.z.len()).map(|i| 300.0 + i as f32).collect();
    let area = d.path().join("area.tif");
    write_geotiff(&area, &g, Crs::Epsg(26915)).unwrap();
    let point = d.path().join("point.tif");
    let out = Command::new("gdal_translate")
        .args(["-q", "-mo", "AREA_OR_POINT=Point"])
        .arg(&area)
        .arg(&point)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let info = Command::new("gdalinfo").arg(&point).output().unwrap();
    let info = String::from_utf8_lossy(&info.stdout);
    assert!(info.contains("AREA_OR_POINT=Point"), "{info}");
    let back = read_geotiff(&point).unwrap();
    assert_eq!((back.cols, back.rows), (g.cols, g.rows));
    assert!(
        (back.x0 - g.x0).abs() < 1e-6 && (back.y0 - g.y0).abs() < 1e-6,
        "node (0, 0) at ({}, {}), written at ({}, {})",
        back.x0,
        back.y0,
        g.x0,
        g.y0
    );
    assert_eq!(back.z, g.z);
}
