//! Images as big as real products: a full Pléiades or WorldView scene is 40 000 × 40 000 px
//! (3.2 GB at 16 bits). A DEM of a small `[dem] extent` reads only the window of each image that
//! sees it, so two such scenes run in well under 1 GB.
//!
//! The two views of a simulated pushbroom pair are set into two 40 000 × 40 000 px tiled TIFFs
//! (sparse files: only the tiles under the view are written) at different places, each with
//! the line-scanner model of the whole scene (the view's, its detector array and line times
//! moved). `rig dtm` on the large scenes must give the DEM the small views give, within a peak
//! resident memory of 1 GB.

mod common;

use rig::coords::PixelXY;
use rig::geometry::{Pushbroom, Sensor};

use std::io::{Seek, SeekFrom, Write};
use std::path::Path;
use std::process::{Command, Stdio};

const SIDE: usize = 40_000;
const TILE: usize = 512;

/// A little-endian, uncompressed, 16-bit grey TIFF of `SIDE × SIDE` in `TILE × TILE` tiles
/// (TIFF 6.0 §15), zero everywhere but `view` (`w × h`) set at (`c0`, `r0`): only the tiles
/// that meet the view are written, the rest of the file is a hole.
fn write_sparse(path: &Path, view: &[u16], w: usize, h: usize, c0: usize, r0: usize) {
    let across = SIDE.div_ceil(TILE);
    let n = across * across;
    let tile_bytes = TILE * TILE * 2;
    // Tags: (tag, type, count, value); 3 SHORT, 4 LONG, 16 LONG8 in a BigTIFF-free file (the
    // data stays below 4 GiB: 6 241 tiles of 512 KiB = 3.27 GB).
    let entries: [(u16, u16, u32, u32); 10] = [
        (256, 4, 1, SIDE as u32),
        (257, 4, 1, SIDE as u32),
        (258, 3, 1, 16),
        (259, 3, 1, 1),
        (262, 3, 1, 1),
        (277, 3, 1, 1),
        (322, 3, 1, TILE as u32),
        (323, 3, 1, TILE as u32),
        (324, 4, n as u32, 0),
        (325, 4, n as u32, 0),
    ];
    let ifd_len = 2 + 12 * entries.len() + 4;
    let offsets_at = 8 + ifd_len;
    let counts_at = offsets_at + 4 * n;
    let data_at = (counts_at + 4 * n).next_multiple_of(4096);
    assert!(data_at + n * tile_bytes < u32::MAX as usize);
    let mut head = Vec::new();
    head.extend_from_slice(b"II*\0");
    head.extend_from_slice(&8u32.to_le_bytes());
    head.extend_from_slice(&(entries.len() as u16).to_le_bytes());
    for (tag, ty, count, value) in entries {
        head.extend_from_slice(&tag.to_le_bytes());
        head.extend_from_slice(&ty.to_le_bytes());
        head.extend_from_slice(&count.to_le_bytes());
        let v = match tag {
            324 => offsets_at as u32,
            325 => counts_at as u32,
            _ => value,
        };
        if ty == 3 {
            head.extend_from_slice(&(v as u16).to_le_bytes());
            head.extend_from_slice(&[0, 0]);
        } else {
            head.extend_from_slice(&v.to_le_bytes());
        }
    }
    head.extend_from_slice(&0u32.to_le_bytes());
    for k in 0..n {
        head.extend_from_slice(&((data_at + k * tile_bytes) as u32).to_le_bytes());
    }
    for _ in 0..n {
        head.extend_from_slice(&(tile_bytes as u32).to_le_bytes());
    }
    let mut f = std::fs::File::create(path).unwrap();
    f.write_all(&head).unwrap();
    f.set_len((data_at + n * tile_bytes) as u64).unwrap();
    let mut tile = vec![0u8; tile_bytes];
    for ty in r0 / TILE..=(r0 + h - 1) / TILE {
        for tx in c0 / TILE..=(c0 + w - 1) / TILE {
            tile.fill(0);
            for r in 0..TILE {
                for c in 0..TILE {
                    let (x, y) = (tx * TILE + c, ty * TILE + r);
                    if (c0..c0 + w).contains(&x) && (r0..r0 + h).contains(&y) {
                        let v = view[(y - r0) * w + (x - c0)];
                        tile[2 * (r * TILE + c)..][..2].copy_from_slice(&v.to_le_bytes());
                    }
                }
            }
            f.seek(SeekFrom::Start(
                (data_at + (ty * across + tx) * tile_bytes) as u64,
            ))
            .unwrap();
            f.write_all(&tile).unwrap();
        }
    }
}

/// The line scanner of the whole `SIDE × SIDE` scene of which `m`'s image is the part at
/// (`c0`, `r0`): the array's principal column moves by `c0`; a row's time is
/// (row − lines/2)·period, so the view's time is the scene's less s = (r0 + L/2 − SIDE/2)·period,
/// and each quadratic c₀ + c₁t + c₂t² in the view's time is re-expanded in the scene's.
fn whole_scene(m: &Pushbroom, c0: usize, r0: usize) -> Pushbroom {
    let s = (r0 as f64 + m.lines as f64 / 2.0 - SIDE as f64 / 2.0) * m.line_period_s;
    let shift = |c: [f64; 3]| [c[0] - c[1] * s + c[2] * s * s, c[1] - 2.0 * c[2] * s, c[2]];
    let mut b = *m;
    b.columns = SIDE;
    b.lines = SIDE;
    b.principal_col += c0 as f64;
    b.position = m.position.map(shift);
    b.attitude = m.attitude.map(shift);
    b.check().unwrap();
    // The view's pixel and the scene's see the same ground.
    let g = m
        .try_image_to_ground(PixelXY::new(123.0, 321.0), 500.0)
        .unwrap();
    let q = b.try_ground_to_image(g).unwrap();
    assert!(
        (q.col - 123.0 - c0 as f64).abs() < 1e-6 && (q.row - 321.0 - r0 as f64).abs() < 1e-6,
        "{q:?}"
    );
    b
}

/// Runs `cmd` with its standard output into `out`; its exit code and peak resident memory
/// (bytes), from wait4's resource usage of that process alone.
// wait4 reaps the child (std's `wait` would not give its resource usage).
#[allow(clippy::zombie_processes)]
fn run_measured(cmd: &mut Command, out: &Path) -> (i32, u64, String) {
    let child = cmd
        .stdout(std::fs::File::create(out).unwrap())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let pid = child.id() as libc::pid_t;
    let mut stderr = child.stderr.unwrap();
    let err = std::thread::spawn(move || {
        let mut s = String::new();
        std::io::Read::read_to_string(&mut stderr, &mut s).unwrap();
        s
    });
    let mut status = 0;
    // SAFETY: a zeroed rusage is a valid value; wait4 fills it for this child.
    let mut usage: libc::rusage = unsafe { std::mem::zeroed() };
    let r = unsafe { libc::wait4(pid, &mut status, 0, &mut usage) };
    assert_eq!(r, pid);
    let code = if libc::WIFEXITED(status) {
        libc::WEXITSTATUS(status)
    } else {
        -1
    };
    (code, usage.ru_maxrss as u64 * 1024, err.join().unwrap())
}

#[test]
fn a_small_extent_of_two_40000_px_scenes_runs_within_1_gb_and_gives_the_small_views_dem() {
    let d = tempfile::tempdir().unwrap();
    let scene = common::sim_scene(
        d.path(),
        &[
            "--sensor",
            "pushbroom",
            "--views",
            "2",
            "--size",
            "500",
            "--gsd-m",
            "5",
            "--noise-dn",
            "100",
            "--seed",
            "11",
        ],
    );
    // An extent in the middle of the views, far enough from their edges that the windows of
    // the small views are not cut by them (so both runs see the same pixels).
    let small = std::fs::read_to_string(scene.join("block.toml")).unwrap();
    // The views' common centre: the first view's centre at the middle height.
    let view1: Pushbroom =
        serde_json::from_str(&std::fs::read_to_string(scene.join("view-1.json")).unwrap()).unwrap();
    let centre = view1
        .try_image_to_ground(PixelXY::new(250.0, 250.0), 640.0)
        .expect("the view's centre");
    let half = 300.0;
    let extent = format!(
        "extent = [{:.1}, {:.1}, {:.1}, {:.1}]",
        centre.x - half,
        centre.y - half,
        centre.x + half,
        centre.y + half
    );
    let small = small.replace("cell_m = 10.0", &format!("cell_m = 10.0\n{extent}"));
    assert!(small.contains("extent = ["), "{small}");
    std::fs::write(scene.join("small.toml"), &small).unwrap();
    // The control and check points measured on the views, at their places in the scenes.
    let places = |photo: &str| match photo {
        "view-1" => (21_137.0, 17_409.0),
        _ => (3_301.0, 36_650.0),
    };
    // The large scenes: each view at its own place in a 40 000 px image, its line scanner's
    // model that of the whole scene (the detector array and the time of each line moved).
    let mut large = small.clone();
    for (v, (c0, r0)) in [(1, (21_137, 17_409)), (2, (3_301, 36_650))] {
        assert_eq!(places(&format!("view-{v}")), (c0 as f64, r0 as f64));
        let view = rig::image::load_grey(&scene.join(format!("view-{v}.tiff")), 1 << 30).unwrap();
        let px: Vec<u16> = view.data.iter().map(|&x| x as u16).collect();
        let big = scene.join(format!("big-{v}.tif"));
        write_sparse(&big, &px, view.width, view.height, c0, r0);
        let m: Pushbroom = serde_json::from_str(
            &std::fs::read_to_string(scene.join(format!("view-{v}.json"))).unwrap(),
        )
        .unwrap();
        std::fs::write(
            scene.join(format!("big-{v}.json")),
            serde_json::to_string(&whole_scene(&m, c0, r0)).unwrap(),
        )
        .unwrap();
        large = large
            .replace(&format!("\"view-{v}.tiff\""), &format!("\"big-{v}.tif\""))
            .replace(&format!("\"view-{v}.json\""), &format!("\"big-{v}.json\""));
        // Sparse: the file claims 3.2 GB but holds a few MB.
        let meta = std::fs::metadata(&big).unwrap();
        use std::os::unix::fs::MetadataExt;
        eprintln!(
            "big-{v}.tif: {:.2} GB long, {:.1} MB on disk",
            meta.len() as f64 / 1e9,
            meta.blocks() as f64 * 512.0 / 1e6
        );
    }
    let csv = std::fs::read_to_string(scene.join("truth_points.csv")).unwrap();
    let mut moved = String::new();
    for (i, line) in csv.lines().enumerate() {
        let f: Vec<&str> = line.split(',').collect();
        if i == 0 {
            moved.push_str(line);
        } else {
            let (c0, r0) = places(f[5]);
            let col: f64 = f[6].parse::<f64>().unwrap() + c0;
            let row: f64 = f[7].parse::<f64>().unwrap() + r0;
            moved.push_str(&format!("{},{col:.4},{row:.4}", f[..6].join(",")));
        }
        moved.push('\n');
    }
    std::fs::write(scene.join("large_points.csv"), moved).unwrap();
    let large = large.replace("\"truth_points.csv\"", "\"large_points.csv\"");
    std::fs::write(scene.join("large.toml"), &large).unwrap();
    let run = |project: &str| {
        let out = d.path().join(project.replace(".toml", ""));
        let json = d.path().join(project.replace(".toml", ".json"));
        let (code, peak, err) = run_measured(
            common::rig()
                .arg("dtm")
                .arg(scene.join(project))
                .arg("--json")
                .arg("--out")
                .arg(&out),
            &json,
        );
        assert_eq!(code, 0, "{project}: {err}");
        let r: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
        (r, peak, out)
    };
    let (rs, peak_small, out_small) = run("small.toml");
    let (rl, peak_large, out_large) = run("large.toml");
    eprintln!(
        "peak resident memory: {:.0} MB with the 500 px views, {:.0} MB with the 40 000 px scenes",
        peak_small as f64 / 1e6,
        peak_large as f64 / 1e6
    );
    assert!(peak_large < 1 << 30, "{peak_large} bytes");
    let (cs, cl) = (&rs["comparison"], &rl["comparison"]);
    eprintln!("small views: {cs}\nlarge scenes: {cl}");
    assert!(cl["nodes"].as_u64().unwrap() > 3000, "{cl}");
    assert!(cl["rmse_m"].as_f64().unwrap() < 2.0, "{cl}");
    // The same pixels through the same geometry: the same model, node by node (the scenes'
    // line times are counted from another origin, so the last bits of the geometry differ).
    let dem = |o: &Path| rig::matching::products::files::read_geotiff(&o.join("dem.tif")).unwrap();
    let (a, b) = (dem(&out_small), dem(&out_large));
    assert_eq!((a.x0, a.y0, a.cols, a.rows), (b.x0, b.y0, b.cols, b.rows));
    let mut worst: f32 = 0.0;
    for (u, v) in a.z.iter().zip(&b.z) {
        assert_eq!(
            u.is_nan(),
            v.is_nan(),
            "a node with a height in one DEM only"
        );
        if !u.is_nan() {
            worst = worst.max((u - v).abs());
        }
    }
    eprintln!("the two DEMs differ by {worst:.1e} m at most");
    assert!(worst < 1e-3, "{worst} m");
    // Without the extent the whole scenes would be read: refused before any is, saying how.
    let whole = large.replace(&extent, "");
    std::fs::write(scene.join("whole.toml"), whole).unwrap();
    let h = common::run_hostile(
        common::rig()
            .arg("dtm")
            .arg(scene.join("whole.toml"))
            .arg("--out")
            .arg(d.path().join("whole")),
        4,
        120,
    );
    assert_ne!(h.code, Some(0));
    assert!(
        h.stderr.contains("big-1.tif") && h.stderr.contains("[dem] extent"),
        "{}",
        h.stderr
    );
}
