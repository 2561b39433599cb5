//! Project format 2 from plain files, as someone who never used the rig would hand them over:
//! three photos rendered by the simulator but given only as 16-bit TIFFs, their cameras and
//! orientations as numbers (one photo left to be resected from the control points), the
//! points as CSV with the README's pixel convention (integer values at pixel centres), a CRS.
//! `rig dtm PROJECT --out DIR` must sweep every overlapping pair, merge them and meet the
//! scan path's accuracy in pixels of parallax; `gdalinfo` must place the DEM.

mod common;

use common::rig;
use rig::geometry::Crs;
use rig::matching::grid::ElevationGrid;
use rig_sim::scene::{jacksboro, AerialPhoto};
use std::fmt::Write as _;
use std::path::Path;

/// Film pixel of the plain images, mm, and their size: 1000 × 1000 px over ±100 mm (a
/// 200 µm scan: coarse, so that the test is quick; the accuracy is held in pixels).
const PIXEL_MM: f64 = 0.2;
const N: usize = 1000;
/// Where each image's window lies along x from the centred one, mm: photo 2's is a crop 15 mm
/// toward photo 1 (its camera says so by pixel_to_photo).
const SHIFT: [f64; 3] = [0.0, -15.0, 0.0];

/// Writes photo `a` as a 16-bit TIFF of the film from `x_shift_mm` to the right of the centred
/// window (a crop off the centre: its pixel → photo relation is then a general affine).
fn write_photo(a: &AerialPhoto, path: &Path, x_shift_mm: f64) {
    let half = 0.5 * N as f64 * PIXEL_MM;
    let t = a.render([-half + x_shift_mm, half], PIXEL_MM, N, N, 2);
    let raw: Vec<u8> = t
        .iter()
        .flat_map(|v| ((v * 60_000.0).round().clamp(0.0, 65_535.0) as u16).to_ne_bytes())
        .collect();
    image::save_buffer(
        path,
        &raw,
        N as u32,
        N as u32,
        image::ExtendedColorType::L16,
    )
    .unwrap();
}

/// The README's pixel of photo point `p` (mm) in these images: centre of the top-left pixel
/// at (0, 0).
fn pixel_of(p: [f64; 2]) -> [f64; 2] {
    let c = (N as f64 - 1.0) / 2.0;
    [p[0] / PIXEL_MM + c, c - p[1] / PIXEL_MM]
}

#[test]
fn three_plain_photos_give_a_dem_a_gis_can_place() {
    let d = tempfile::tempdir().unwrap();
    let dem = jacksboro();
    let photos: Vec<AerialPhoto> = (1..=3)
        .map(|k| AerialPhoto::new(dem.clone(), 5, k, 105.0))
        .collect();
    for (k, a) in photos.iter().enumerate() {
        write_photo(a, &d.path().join(format!("photo_{}.tif", k + 1)), SHIFT[k]);
    }
    // Control and check points where all three photos see the ground (photo 1's quadrant
    // toward 2 and 3), read off the truth; pixels in the README's convention.
    let mut csv = String::from("id,kind,x,y,z,photo,col,row\n");
    let mut zs = Vec::new();
    let mut k = 0;
    for u in [10.0, 35.0, 60.0, 85.0] {
        for v in [-85.0, -70.0, -55.0] {
            k += 1;
            let g0 = photos[0].ground_point([u, v]);
            let g = [g0[0], g0[1], dem.height(g0[0], g0[1])];
            zs.push(g[2]);
            let kind = if k % 3 == 0 { "cp" } else { "gcp" };
            // In the world's CRS (UTM 16N), as a surveyor would give them.
            let w = rig::sim_scene::to_crs(g);
            for (i, a) in photos.iter().enumerate() {
                let mut q = pixel_of(a.project(g));
                q[0] -= SHIFT[i] / PIXEL_MM;
                if q.iter().all(|v| (0.0..N as f64 - 1.0).contains(v)) {
                    writeln!(
                        csv,
                        "p{k},{kind},{:.3},{:.3},{:.3},{},{:.3},{:.3}",
                        w.x,
                        w.y,
                        w.z,
                        i + 1,
                        q[0],
                        q[1]
                    )
                    .unwrap();
                }
            }
        }
    }
    std::fs::write(d.path().join("points.csv"), &csv).unwrap();
    // The true terrain as the reference, in the same CRS.
    let area = [-100.0, -100.0, 100.0, 100.0];
    let truth = {
        let (mut lo, mut hi) = ([f64::MAX; 2], [f64::MIN; 2]);
        for a in &photos {
            for x in [area[0], area[2]] {
                for y in [area[1], area[3]] {
                    let g = a.ground_point([x, y]);
                    lo = [lo[0].min(g[0]), lo[1].min(g[1])];
                    hi = [hi[0].max(g[0]), hi[1].max(g[1])];
                }
            }
        }
        let mut t = ElevationGrid::covering([lo[0], lo[1], hi[0], hi[1]], 10.0, 4096).unwrap();
        for r in 0..t.rows {
            for c in 0..t.cols {
                let [x, y] = t.node(c, r);
                t.z[r * t.cols + c] = dem.height(x, y) as f32;
            }
        }
        rig::sim_scene::grid_to_crs(t)
    };
    rig::matching::products::files::write_geotiff(
        &d.path().join("truth.tif"),
        &truth,
        Crs::Epsg(32616),
    )
    .unwrap();
    let mut project = format!("format = 2\ncrs = \"EPSG:32616\"\n\n[camera.rc10]\nfocal_mm = 153.0\npixel_mm = {PIXEL_MM}\n");
    // Photo 2's image is a crop shifted along x: x = SHIFT − (N−1)/2·p + col·p.
    let c = (N as f64 - 1.0) / 2.0 * PIXEL_MM;
    writeln!(
        project,
        "\n[camera.cropped]\nfocal_mm = 153.0\npixel_to_photo = [{}, {PIXEL_MM}, 0.0, {c}, 0.0, {}]",
        SHIFT[1] - c,
        -PIXEL_MM
    )
    .unwrap();
    for (k, a) in photos.iter().enumerate() {
        let e = a.exterior;
        write!(
            project,
            "\n[[photo]]\nid = \"{}\"\nimage = \"photo_{}.tif\"\ncamera = \"{}\"\n",
            k + 1,
            k + 1,
            if k == 1 { "cropped" } else { "rc10" }
        )
        .unwrap();
        // Photo 3 has no orientation: resected from its control points.
        if k < 2 {
            let c = rig::sim_scene::to_crs([e.x0_m, e.y0_m, e.z0_m]);
            writeln!(
                project,
                "position = [{}, {}, {}]\nangles_deg = [{}, {}, {}]",
                c.x, c.y, c.z, e.omega_deg, e.phi_deg, e.kappa_deg
            )
            .unwrap();
        }
    }
    project.push_str(
        "\n[points]\nfile = \"points.csv\"\n\n[dem]\ncell_m = 20.0\n\n[matching]\nstride = 2\n\n[check]\nreference = \"truth.tif\"\n",
    );
    let pf = d.path().join("project.toml");
    std::fs::write(&pf, &project).unwrap();
    let out = d.path().join("dem");
    let o = rig()
        .args(["dtm"])
        .arg(&pf)
        .arg("--out")
        .arg(&out)
        .arg("--json")
        .output()
        .unwrap();
    assert!(
        o.status.success(),
        "{}\n{}",
        String::from_utf8_lossy(&o.stderr),
        String::from_utf8_lossy(&o.stdout)
    );
    let r: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    for p in r["pairs"].as_array().unwrap() {
        eprintln!(
            "pair {} × {}: step {:.2} m, {:.1} % matched, {} points",
            p["left"], p["right"], p["h_step_m"], p["dtm"]["matched_percent"], p["points"]
        );
    }
    eprintln!(
        "{}",
        serde_json::to_string_pretty(&r["comparison"]).unwrap()
    );
    assert_eq!(
        r["pairs"].as_array().unwrap().len(),
        3,
        "all three pairs overlap"
    );
    // Every pair contributes (a photo whose pixel → photo relation were misread would match
    // nothing, and the others would hide it in the merged model).
    for p in r["pairs"].as_array().unwrap() {
        assert!(p["points"].as_u64().unwrap() > 10_000, "{p}");
    }
    assert_eq!(r["resected"][0][0], "3");
    let rmse = r["comparison"]["rmse_m"].as_f64().unwrap();
    // One pixel of parallax here: 0.2 mm on the film × 42 500 (8.5 m on the ground) over a
    // base-to-height ratio of about 0.6 along the strip: about 14 m of height. The scan path
    // reaches 0.35 px (0.61 m at 25 µm in `rig demo`); allow 0.5 px.
    let px_m = PIXEL_MM * 1e-3 * 42_500.0 / 0.6;
    eprintln!("RMSE {rmse:.2} m = {:.3} px of parallax", rmse / px_m);
    assert!(rmse < 0.5 * px_m, "RMSE {rmse} m ({:.3} px)", rmse / px_m);
    assert!(r["grid_filled"].as_u64().unwrap() > 1000);
    let _ = zs;
    check_quality_and_ortho(&out, &r, &photos[0]);
    check_las_against_ply(&out);
    check_tiles_and_merge(&pf, &out, d.path());
    // A GIS places it: the CRS is in the GeoTIFF (checked when GDAL is installed).
    if let Ok(o) = std::process::Command::new("gdalinfo")
        .arg(out.join("dem.tif"))
        .output()
    {
        let t = String::from_utf8_lossy(&o.stdout);
        assert!(
            t.contains("UTM zone 16N") && t.contains("NoData Value=-9999"),
            "{t}"
        );
    }
}

/// The run split in four shares (swept in reverse order, one across two pairs) and merged
/// gives the single run's files byte for byte; a missing share, a share given twice or a
/// changed project are refused with what to do.
fn check_tiles_and_merge(pf: &Path, single: &Path, dir: &Path) {
    let n = 4;
    for i in (1..=n).rev() {
        let o = rig()
            .arg("dtm")
            .arg(pf)
            .args(["--tile", &format!("{i}/{n}"), "--json", "--out"])
            .arg(dir.join(format!("tile-{i}")))
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let m: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
        assert_eq!(m["tile"], i);
        if i == 2 {
            assert_eq!(m["parts"].as_array().unwrap().len(), 2, "{m}");
        }
    }
    let tile = |i: usize| dir.join(format!("tile-{i}"));
    let merged = dir.join("merged");
    let o = rig()
        .args(["dtm", "merge"])
        .args([tile(3), tile(1), tile(4), tile(2)])
        .arg("--out")
        .arg(&merged)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    for f in [
        "dem.tif",
        "quality.tif",
        "ortho.tif",
        "points.ply",
        "points.las",
        "hillshade.png",
        "quality.png",
        "error.png",
        "report.html",
    ] {
        let (a, b) = (
            std::fs::read(single.join(f)).unwrap(),
            std::fs::read(merged.join(f)).unwrap(),
        );
        assert!(a == b, "{f} differs between the single run and the merge");
    }
    // The reports agree but for the sweep's timings.
    let strip = |p: &Path| {
        let mut v: serde_json::Value =
            serde_json::from_slice(&std::fs::read(p.join("report.json")).unwrap()).unwrap();
        for pair in v["pairs"].as_array_mut().unwrap() {
            pair["dtm"]["matching_seconds"] = 0.into();
            pair["dtm"]["pixels_per_second"] = 0.into();
        }
        v
    };
    assert_eq!(strip(single), strip(&merged));
    // A merge that must be refused: its exit code, and what it said.
    let refused = |tiles: &[std::path::PathBuf]| -> String {
        let o = rig()
            .args(["dtm", "merge"])
            .args(tiles)
            .arg("--out")
            .arg(dir.join("x"))
            .output()
            .unwrap();
        let e = String::from_utf8_lossy(&o.stderr).into_owned();
        assert!(!o.status.success(), "{e}");
        e
    };
    // A missing share, a share given twice.
    let e = refused(&[tile(1), tile(2), tile(4)]);
    assert!(e.contains("missing 3/4"), "{e}");
    let e = refused(&[tile(1), tile(2), tile(2), tile(3), tile(4)]);
    assert!(e.contains("given twice"), "{e}");
    // A damaged part file.
    let m: serde_json::Value =
        serde_json::from_slice(&std::fs::read(tile(1).join("tile.json")).unwrap()).unwrap();
    let part = tile(1).join(m["parts"][0]["file"].as_str().unwrap());
    let bytes = std::fs::read(&part).unwrap();
    std::fs::write(&part, &bytes[..bytes.len() - 4]).unwrap();
    let e = refused(&[tile(1), tile(2), tile(3), tile(4)]);
    assert!(e.contains("cut short"), "{e}");
    std::fs::write(&part, &bytes).unwrap();
    // A manifest naming a file outside its directory.
    let manifest = tile(1).join("tile.json");
    let good = std::fs::read(&manifest).unwrap();
    let mut m: serde_json::Value = serde_json::from_slice(&good).unwrap();
    m["parts"][0]["file"] = "../tile-2/tile.json".into();
    std::fs::write(&manifest, serde_json::to_vec(&m).unwrap()).unwrap();
    let e = refused(&[tile(1), tile(2), tile(3), tile(4)]);
    assert!(e.contains("a part named"), "{e}");
    std::fs::write(&manifest, &good).unwrap();
    // A photo replaced after the sweep (same size, other pixels), the project untouched.
    let photo = dir.join("photo_3.tif");
    let original = std::fs::read(&photo).unwrap();
    std::fs::copy(dir.join("photo_1.tif"), &photo).unwrap();
    let e = refused(&[tile(1), tile(2), tile(3), tile(4)]);
    assert!(e.contains("changed since the tiles were swept"), "{e}");
    std::fs::write(&photo, &original).unwrap();
    // The project edited after the sweep.
    let text = std::fs::read_to_string(pf).unwrap();
    std::fs::write(pf, text.replace("cell_m = 20.0", "cell_m = 25.0")).unwrap();
    let e = refused(&[tile(1), tile(2), tile(3), tile(4)]);
    assert!(e.contains("sweep the tiles again"), "{e}");
    std::fs::write(pf, text).unwrap();
    assert!(!dir.join("x").join("dem.tif").exists());
}

/// quality.tif and ortho.tif, checked against what the simulator knows: the standard deviations
/// are scaled by the pairs' redundancy and within a factor of a few of the true errors; the
/// orthophoto shows the ground's reflectance where it lies (it correlates with the simulator's
/// texture at the nodes, and less so one cell off).
fn check_quality_and_ortho(out: &Path, r: &serde_json::Value, a: &AerialPhoto) {
    let f = &r["variance_factor"];
    assert!(f["comparisons"].as_u64().unwrap() >= 50, "{f}");
    let s0 = f["s0"].as_f64().unwrap();
    assert!(s0 > 0.3 && s0 < 30.0, "{f}");
    let c = &r["sigma_vs_reference"];
    eprintln!("σ against the reference: {c}; variance factor {f}");
    let ratio = c["ratio"].as_f64().unwrap();
    assert!(ratio > 0.3 && ratio < 5.0, "σ off by {ratio}: {c}");
    // The orthophoto against the ground's reflectance at each node (simulator coordinates).
    let o = rig::matching::products::files::read_geotiff(&out.join("ortho.tif")).unwrap();
    let terrain = jacksboro();
    let corr_at = |dc: i64| {
        let (mut v, mut t) = (Vec::new(), Vec::new());
        for r in 0..o.rows {
            for c in 0..o.cols {
                let g = o.z[r * o.cols + c];
                if !g.is_finite() {
                    continue;
                }
                let [x, y] = o.node(c, r);
                let x = x - rig::sim_scene::ORIGIN_M[0] + dc as f64 * o.cell_m;
                let y = y - rig::sim_scene::ORIGIN_M[1];
                v.push(g as f64);
                t.push(rig_sim::scene::reflectance(a.texture_seed, &terrain, x, y));
            }
        }
        let n = v.len() as f64;
        let (mv, mt) = (v.iter().sum::<f64>() / n, t.iter().sum::<f64>() / n);
        let (mut svt, mut svv, mut stt) = (0.0, 0.0, 0.0);
        for (a, b) in v.iter().zip(&t) {
            svt += (a - mv) * (b - mt);
            svv += (a - mv) * (a - mv);
            stt += (b - mt) * (b - mt);
        }
        (svt / (svv * stt).sqrt(), v.len())
    };
    let (here, n) = corr_at(0);
    let (off, _) = corr_at(1);
    eprintln!("ortho vs the ground's reflectance: correlation {here:.3} over {n} nodes, {off:.3} one cell east");
    // (A cell is 2.4 of the photos' 8.5 m ground pixels: one cell off still correlates
    // 0.89, the placed ortho 0.97.)
    assert!(n > 1000 && here > 0.8 && here > off + 0.05, "{here} {off}");
    // quality.tif: two float bands per pixel (σ ≥ 0, correlation within the threshold … 1) on
    // the DEM's grid, nodata where the DEM has none — read by the TIFF layout, not our reader.
    let dem = rig::matching::products::files::read_geotiff(&out.join("dem.tif")).unwrap();
    let mut d = tiff::decoder::Decoder::new(std::io::BufReader::new(
        std::fs::File::open(out.join("quality.tif")).unwrap(),
    ))
    .unwrap();
    assert_eq!(d.dimensions().unwrap(), (dem.cols as u32, dem.rows as u32));
    let tiff::decoder::DecodingResult::F32(q) = d.read_image().unwrap() else {
        panic!("quality.tif is not float32");
    };
    assert_eq!(q.len(), 2 * dem.cols * dem.rows, "two samples per pixel");
    let mut both = 0;
    for (i, z) in dem.z.iter().enumerate() {
        let (s, c) = (q[2 * i], q[2 * i + 1]);
        if z.is_finite() && s != -9999.0 {
            assert!(
                s > 0.0 && s < 50.0 && (0.5..=1.0).contains(&c),
                "node {i}: σ {s}, ρ {c}"
            );
            both += 1;
        } else if !z.is_finite() {
            assert!(
                s == -9999.0 && c == -9999.0,
                "node {i} has no height but σ {s}"
            );
        }
    }
    assert!(both > 1000, "{both} nodes with σ");
    // quality.tif: two bands, σ and correlation, as GDAL reads them (when installed).
    if let Ok(g) = std::process::Command::new("gdalinfo")
        .args(["-stats"])
        .arg(out.join("quality.tif"))
        .output()
    {
        let t = String::from_utf8_lossy(&g.stdout);
        assert!(
            t.contains("Band 2")
                && t.contains("height standard deviation (m)")
                && t.contains("UTM zone 16N"),
            "{t}"
        );
    }
}

/// points.las read by the LAS 1.2 specification's layout (not by the crate that wrote it) and
/// compared with points.ply: the same points to the millimetre, and the CRS in the
/// LASF_Projection record.
fn check_las_against_ply(out: &Path) {
    let las = std::fs::read(out.join("points.las")).unwrap();
    let u16_at = |o: usize| u16::from_le_bytes([las[o], las[o + 1]]);
    let u32_at = |o: usize| u32::from_le_bytes(las[o..o + 4].try_into().unwrap());
    let f64_at = |o: usize| f64::from_le_bytes(las[o..o + 8].try_into().unwrap());
    assert_eq!(&las[0..4], b"LASF");
    assert_eq!((las[24], las[25]), (1, 2));
    let (data_at, vlrs, format, len, count) = (
        u32_at(96) as usize,
        u32_at(100),
        las[104],
        u16_at(105) as usize,
        u32_at(107) as usize,
    );
    assert_eq!((format, len), (0, 20));
    let scale = [f64_at(131), f64_at(139), f64_at(147)];
    let offset = [f64_at(155), f64_at(163), f64_at(171)];
    // The VLRs follow the header: 54-byte header each, then the record.
    let mut at = u16_at(94) as usize;
    let mut epsg = None;
    for _ in 0..vlrs {
        let user = String::from_utf8_lossy(&las[at + 2..at + 18])
            .trim_end_matches('\0')
            .to_string();
        let (id, n) = (u16_at(at + 18), u16_at(at + 20) as usize);
        if user == "LASF_Projection" && id == 34735 {
            let keys: Vec<u16> = (0..n / 2).map(|k| u16_at(at + 54 + 2 * k)).collect();
            epsg = keys[4..].chunks(4).find(|k| k[0] == 3072).map(|k| k[3]);
        }
        at += 54 + n;
    }
    assert_eq!(epsg, Some(32616));
    let ply = std::fs::read(out.join("points.ply")).unwrap();
    let head = ply.windows(11).position(|w| w == b"end_header\n").unwrap() + 11;
    let text = String::from_utf8_lossy(&ply[..head]);
    assert!(text.contains("comment crs EPSG:32616"), "{text}");
    let n: usize = text
        .lines()
        .find_map(|l| l.strip_prefix("element vertex "))
        .unwrap()
        .parse()
        .unwrap();
    assert_eq!(count, n);
    for k in (0..n).step_by(n / 97 + 1) {
        let p = head + k * 32;
        let q = data_at + k * len;
        for i in 0..3 {
            let want = f64::from_le_bytes(ply[p + 8 * i..p + 8 * i + 8].try_into().unwrap());
            let raw = i32::from_le_bytes(las[q + 4 * i..q + 4 * i + 4].try_into().unwrap());
            let got = raw as f64 * scale[i] + offset[i];
            assert!(
                (got - want).abs() <= 0.0005 + 1e-9,
                "point {k} axis {i}: {got} vs {want}"
            );
        }
    }
}
