//! `rig sim scene`: a stereo pair rendered straight from the simulator's terrain (no film, no
//! scanning), with control and check points and the true elevation model, as a ready
//! matching project.

use crate::cli::usage::{usage_bail, OrUsage};
use clap::Args;
use rig::coords::{PhotoMm, PixelXY};
use rig::matching::grid::ElevationGrid;
use rig::matching::StereoPoint;
use rig::scan::sidecar::{self, ScannedPhoto};
use rig::scan::PhotoGrid;
use rig_sim::scene::{jacksboro, AerialPhoto};
use serde_json::json;
use std::path::{Path, PathBuf};

#[derive(Debug, Args)]
pub struct SceneArgs {
    /// Directory to write the scene into (created; must be empty).
    #[arg(long, value_name = "DIR")]
    pub out: PathBuf,
    /// Random seed of the block (orientations, texture) — the same as a simulated film's.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// The area of photo 1 to render, photo mm: XMIN,YMIN,XMAX,YMAX (inside the overlap with
    /// photo 2, which lies about 92 mm along x).
    #[arg(
        long,
        value_name = "MM,MM,MM,MM",
        default_value = "36,-8,56,8",
        allow_hyphen_values = true
    )]
    pub area: String,
    /// Pixel size on the film, µm.
    #[arg(long, default_value_t = 25.0)]
    pub resolution_um: f64,
    /// Ground control points and check points to draw.
    #[arg(long, default_value_t = 20)]
    pub gcps: usize,
    #[arg(long, default_value_t = 30)]
    pub cps: usize,
    /// Measuring noise (σ) of the points' photo coordinates, µm, and of their ground
    /// coordinates, m.
    #[arg(long, default_value_t = 5.0)]
    pub photo_noise_um: f64,
    #[arg(long, default_value_t = 0.5)]
    pub ground_noise_m: f64,
    /// Photos of the block to render over the area: 2 (photos 1 and 2 of the strip), 3 (and
    /// photo 3 of the next strip), 4, 5 (photo 5 a base beyond photo 2 in strip 1) or 6 (and
    /// photo 6 beside it in strip 2). Photos 3 and 4 see only the part of photo 1 below
    /// y ≈ −46 mm (30 % side lap): give an --area there, e.g. 38,-70,50,-58; photos 5 and 6
    /// only beyond x ≈ 70 mm (the strip's triple overlap), e.g. 78,-68,88,-58.
    #[arg(long, default_value_t = 2, value_parser = clap::value_parser!(u32).range(2..=6))]
    pub photos: u32,
    /// White noise added to every pixel, grey values (σ; the photos span about 3 000 to
    /// 53 000).
    #[arg(long, default_value_t = 0.0)]
    pub noise_dn: f64,
    /// Cell of truth-dem.tif, m (the simulator's DEM resampled bilinearly; finer cells follow
    /// its 74 × 92 m facets more closely where a cell straddles their edges). Default 10 m;
    /// for --sensor rpc the lidar DEM's own 1 m.
    #[arg(long)]
    pub truth_cell_m: Option<f64>,
    /// Each photo's radiometric gain, in photo order (e.g. 1,1.2,0.85): its grey values are
    /// gain × 60 000 × transmittance + offset, as film developed and scanned differently
    /// (seed 001's linear radiometric model). Default 1 for every photo.
    #[arg(long, value_name = "G,G,…")]
    pub gains: Option<String>,
    /// What the ground looks like: "natural" (land cover with detail at 70, 14 and 4 m) or
    /// "fields" (fields of 50-150 m with sharp borders and a faint texture inside them: weak
    /// texture, where correlation windows see little but noise and edges carry the match).
    #[arg(long, value_enum, default_value_t = TextureArg::Natural)]
    pub texture: TextureArg,
    /// Each photo's radiometric offset, grey values, in photo order (e.g. 0,-3000,4000).
    /// Default 0 for every photo.
    #[arg(long, value_name = "DN,DN,…", allow_hyphen_values = true)]
    pub offsets: Option<String>,
    /// What takes the pictures: "frame" (the aerial block's photos), "pushbroom" (SPOT-like
    /// satellite views from 830 km: a line scanner whose every line has its own position and
    /// attitude) or "rpc" (crops of real satellite products through their real RPCs, given by
    /// --rpc, over a real 1 m lidar DEM). The pushbroom scene writes each view's rigorous model
    /// (view-N.json), its RPCs (view-N_RPC.TXT, as GDAL reads them) and the noise-free points
    /// (truth_points.csv); the rpc scene writes each crop as img_0N.tif with its RPCs in the
    /// TIFF tag only, as crop tools hand them out; --area, --resolution-um and --photos are the
    /// frame photos' only.
    #[arg(long, value_enum, default_value_t = SensorArg::Frame)]
    pub sensor: SensorArg,
    /// Pushbroom: views in the set, 2 (tilted −20° and +20°) or 3 (−20°, 0°, +20°).
    #[arg(long, default_value_t = 3, value_parser = clap::value_parser!(u32).range(2..=3))]
    pub views: u32,
    /// Pushbroom: "across" (the mirror tilted across the track on different passes, as SPOT
    /// 1-4: parallax along the columns) or "along" (one pass looking back, down and forward,
    /// as SPOT 5 HRS: parallax along the rows).
    #[arg(long, value_enum, default_value_t = StereoArg::Across)]
    pub stereo: StereoArg,
    /// Pushbroom: the ground pixel at nadir, m.
    #[arg(long, default_value_t = 5.0)]
    pub gsd_m: f64,
    /// Pushbroom and rpc: columns and lines of every view (default 1200 for pushbroom, 500
    /// for rpc).
    #[arg(long)]
    pub size: Option<usize>,
    /// Rpc: a real product's RPCs as GDAL's `_RPC.TXT`, once per view (2 to 5 views of the
    /// same area): each view is a --size crop of that product around the first product's
    /// centre, rendered over a real lidar DEM laid there.
    #[arg(long, value_name = "FILE_RPC.TXT")]
    pub rpc: Vec<PathBuf>,
}

/// Pushbroom views' --size by default, px.
pub const PUSHBROOM_SIZE: usize = 1200;
/// truth-dem.tif's cell by default (frame and pushbroom scenes), m.
pub const TRUTH_CELL_M: f64 = 10.0;

#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum SensorArg {
    Frame,
    Pushbroom,
    Rpc,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum StereoArg {
    Across,
    Along,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum TextureArg {
    Natural,
    Fields,
}

impl From<TextureArg> for rig_sim::scene::Texture {
    fn from(t: TextureArg) -> Self {
        match t {
            TextureArg::Natural => rig_sim::scene::Texture::Natural,
            TextureArg::Fields => rig_sim::scene::Texture::Fields,
        }
    }
}

/// A per-photo list of `photos` numbers from flag `name`, each within `range` (the default
/// `fill` for every photo when the flag is not given).
fn per_photo(
    list: Option<&str>,
    name: &str,
    photos: u32,
    range: std::ops::RangeInclusive<f64>,
    fill: f64,
) -> anyhow::Result<Vec<f64>> {
    let Some(s) = list else {
        return Ok(vec![fill; photos as usize]);
    };
    let v: Vec<f64> = s
        .split(',')
        .map(|x| x.trim().parse::<f64>())
        .collect::<Result<_, _>>()
        .or_usage(|| format!("--{name} `{s}`: numbers separated by commas"))?;
    if v.len() != photos as usize {
        usage_bail!(
            "--{name} `{s}`: {} values for {photos} photos (one per photo, in photo order)",
            v.len()
        );
    }
    if let Some(bad) = v.iter().find(|x| !range.contains(x)) {
        usage_bail!(
            "--{name} `{s}`: {bad} is outside {} … {}",
            range.start(),
            range.end()
        );
    }
    Ok(v)
}

fn parse_area(s: &str) -> anyhow::Result<[f64; 4]> {
    let v: Vec<f64> = s
        .split(',')
        .map(|x| x.trim().parse::<f64>())
        .collect::<Result<_, _>>()
        .or_usage(|| format!("--area `{s}`: four numbers XMIN,YMIN,XMAX,YMAX"))?;
    if v.len() != 4 || v[2] <= v[0] || v[3] <= v[1] || v.iter().any(|x| x.abs() > 100.0) {
        usage_bail!(
            "--area `{s}`: XMIN,YMIN,XMAX,YMAX with the maxima above the minima, inside ±100 mm"
        );
    }
    Ok([v[0], v[1], v[2], v[3]])
}

/// Grey values per unit of transmittance at gain 1.
const GREY_PER_TRANSMITTANCE: f64 = 60_000.0;

/// A rendered picture's grey values: offset + gain × 60 000 × signal, plus `noise_dn` of white
/// noise (seeded), rounded to 16 bits; refused if more than 0.1 % of the pixels would clip at
/// 1 or 65 535 (`span`: the signal's range, for the message).
pub fn to_grey(
    img: &[f32],
    noise_dn: f64,
    [offset, gain]: [f64; 2],
    seed: u64,
    what: &str,
    span: [f64; 2],
) -> anyhow::Result<Vec<u16>> {
    let mut rng = rig_sim::rng::Rng::new(seed);
    let mut clipped = 0usize;
    let px: Vec<u16> = img
        .iter()
        .map(|v| {
            let n = if noise_dn > 0.0 {
                noise_dn * rng.normal()
            } else {
                0.0
            };
            let g = (offset + gain * *v as f64 * GREY_PER_TRANSMITTANCE + n).round();
            clipped += usize::from(!(1.0..=65535.0).contains(&g));
            g.clamp(1.0, 65535.0) as u16
        })
        .collect();
    if clipped * 1000 > px.len() {
        anyhow::bail!(
            "{what}: {clipped} of {} pixels clip at 1 or 65535 with gain {gain} and offset {offset} (its grey values span about {:.0} … {:.0}): lower the gain or move the offset",
            px.len(),
            offset + gain * span[0] * GREY_PER_TRANSMITTANCE,
            offset + gain * span[1] * GREY_PER_TRANSMITTANCE
        );
    }
    Ok(px)
}

/// The rendered photo as a scanned-photo sidecar and TIFF (grey = `radiometry` offset + gain
/// × transmittance × 60 000, plus `noise_dn` of white noise); refused if more than 0.1 % of
/// its pixels would clip at 1 or 65 535.
fn write_photo(
    dir: &Path,
    name: &str,
    photo: &AerialPhoto,
    grid: &PhotoGrid,
    noise_dn: f64,
    [offset, gain]: [f64; 2],
) -> anyhow::Result<PathBuf> {
    let img = photo.render(grid.corner_mm, grid.step_mm, grid.width, grid.height, 3);
    let px = to_grey(
        &img,
        noise_dn,
        [offset, gain],
        0x9015E ^ photo.number as u64 ^ photo.texture_seed,
        &format!("photo {}", photo.number),
        [photo.t_min, photo.t_max],
    )?;
    let tiff = dir.join(format!("{name}.tiff"));
    rig::digitise::output::write_tiff16(&tiff, grid.width, grid.height, &px)?;
    let side = ScannedPhoto {
        format: sidecar::FORMAT.into(),
        image: format!("{name}.tiff"),
        film: format!(
            "simulated block, photo {} (rendered, not scanned)",
            photo.number
        ),
        region: name.into(),
        grid: *grid,
        grey: sidecar::Grey {
            counts_per_dn: 1.0,
            camera_bit_depth: 16,
            nodata: 0,
            flat_fielded: false,
        },
        interior_orientation: sidecar::InteriorRecord {
            session: PathBuf::new(),
            version: "none: rendered in photo coordinates".into(),
            carriage_to_photo: [0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
            rms_um: 0.0,
            fiducials: vec![],
        },
        camera_certificate: sidecar::CertificateRecord {
            path: PathBuf::new(),
            name: "simulated RC10".into(),
            focal_length_mm: photo.focal_mm,
            fiducials: vec![],
        },
        pixel_to_carriage: sidecar::PixelRecord {
            session: PathBuf::new(),
            params: [0.0; 6],
        },
        scan: sidecar::ScanRecord {
            script: PathBuf::new(),
            tiles: 0,
            frames_per_tile: 0,
            filter: rig::scan::script::Filter::None,
            overlap: 0.0,
            resolution_um: grid.step_mm * 1000.0,
            interpolation: "rendered: mean of 3×3 samples per pixel".into(),
            antialias_sigma_px: 0.0,
            feather_px: 0.0,
        },
    };
    let p = dir.join(format!("{name}.json"));
    rig::digitise::output::write_json(&p, &serde_json::to_value(&side)?)?;
    Ok(p)
}

/// Ground control and check points of photo 1's area, their ground and their place in
/// photo 2, all with measuring noise. Control points lie on a jittered grid that reaches the
/// area's edges (seed 000: "a suitable number of the GCPs must be located near the
/// perimeter", since polynomials extrapolate badly); check points anywhere inside.
pub fn draw_points(
    (a, ga): (&AerialPhoto, &PhotoGrid),
    (b, gb): (&AerialPhoto, &PhotoGrid),
    n: usize,
    prefix: &str,
    noise: (f64, f64),
    rng: &mut rig_sim::rng::Rng,
) -> Vec<StereoPoint> {
    let (photo_mm, ground_m) = noise;
    let control = prefix == "gcp";
    let aspect = ga.width as f64 / ga.height as f64;
    let cols = ((n as f64 * aspect).sqrt().ceil() as usize).max(2);
    let rows = n.div_ceil(cols).max(2);
    let mut v = Vec::new();
    let mut k = 0;
    while v.len() < n && k < 100 * n {
        k += 1;
        let (u, w) = if control {
            // Cell (i, j) of the grid, nodes from 2 % to 98 %, jittered by a quarter cell.
            let (i, j) = ((k - 1) % cols, ((k - 1) / cols) % rows);
            let f = |t: usize, m: usize, r: f64| {
                (0.02 + 0.96 * (t as f64 + 0.25 * (r - 0.5)) / (m - 1) as f64).clamp(0.01, 0.99)
            };
            (f(i, cols, rng.uniform()), f(j, rows, rng.uniform()))
        } else {
            (0.03 + 0.94 * rng.uniform(), 0.03 + 0.94 * rng.uniform())
        };
        let q = PixelXY::new(u * ga.width as f64, w * ga.height as f64);
        let p = ga.photo(q);
        let g = a.ground_point([p.x, p.y]);
        let pb = b.project(g);
        let qb = gb.pixel(PhotoMm::new(pb[0], pb[1]));
        if qb.col < 0.0 || qb.row < 0.0 || qb.col > gb.width as f64 || qb.row > gb.height as f64 {
            continue;
        }
        let px = |rng: &mut rig_sim::rng::Rng| photo_mm / ga.step_mm * rng.normal();
        v.push(StereoPoint {
            id: format!("{prefix}{}", v.len() + 1),
            left: [q.col + px(rng), q.row + px(rng)],
            right: [qb.col + px(rng), qb.row + px(rng)],
            ground: rig::sim_scene::to_crs([
                g[0] + ground_m * rng.normal(),
                g[1] + ground_m * rng.normal(),
                g[2] + ground_m * rng.normal(),
            ]),
        });
    }
    v
}

/// The area of photo 2 that sees photo 1's `area` at heights `lo..hi`, with a 1 mm margin.
pub fn matching_area(a: &AerialPhoto, b: &AerialPhoto, area: [f64; 4], hs: [f64; 2]) -> [f64; 4] {
    let (mut lo, mut hi) = ([f64::MAX; 2], [f64::MIN; 2]);
    let (ca, cb) = (
        rig::sim_scene::frame_camera(a),
        rig::sim_scene::frame_camera(b),
    );
    for x in [area[0], area[2]] {
        for y in [area[1], area[3]] {
            for z in hs {
                // Photo 1's ray through the corner, at height z, seen by photo 2.
                let g = ca.at_height(PhotoMm::new(x, y), z);
                if let Some(q) = cb.project(g) {
                    lo = [lo[0].min(q.x), lo[1].min(q.y)];
                    hi = [hi[0].max(q.x), hi[1].max(q.y)];
                }
            }
        }
    }
    [lo[0] - 1.0, lo[1] - 1.0, hi[0] + 1.0, hi[1] + 1.0]
}

/// Lowest and highest terrain under photo 1's `area` (sampled every half millimetre).
pub fn terrain_range(a: &AerialPhoto, area: [f64; 4]) -> [f64; 2] {
    let (mut lo, mut hi) = (f64::MAX, f64::MIN);
    let n = (((area[2] - area[0]).max(area[3] - area[1])) / 0.5).ceil() as usize;
    for j in 0..=n {
        for i in 0..=n {
            let x = area[0] + (area[2] - area[0]) * i as f64 / n as f64;
            let y = area[1] + (area[3] - area[1]) * j as f64 / n as f64;
            let z = a.ground_point([x, y])[2];
            lo = lo.min(z);
            hi = hi.max(z);
        }
    }
    [lo, hi]
}

/// The true DEM resampled (bilinearly) to a square grid over the ground under `area`, in the
/// simulated world's CRS.
pub fn truth_grid(
    a: &AerialPhoto,
    area: [f64; 4],
    cell_m: f64,
) -> Result<ElevationGrid, rig::matching::grid::GridError> {
    let (mut lo, mut hi) = ([f64::MAX; 2], [f64::MIN; 2]);
    for x in [area[0], area[2]] {
        for y in [area[1], area[3]] {
            let g = a.ground_point([x, y]);
            lo = [lo[0].min(g[0]), lo[1].min(g[1])];
            hi = [hi[0].max(g[0]), hi[1].max(g[1])];
        }
    }
    truth_grid_over(&a.dem, [lo[0], lo[1], hi[0], hi[1]], cell_m)
}

/// The true DEM resampled (bilinearly) to a square grid over the simulator's ground
/// rectangle `ground` (xmin, ymin, xmax, ymax, local m) and a margin of 5 cells, in the
/// world's CRS.
pub fn truth_grid_over(
    dem: &rig_sim::scene::Dem,
    ground: [f64; 4],
    cell_m: f64,
) -> Result<ElevationGrid, rig::matching::grid::GridError> {
    let m = 5.0 * cell_m;
    let mut grid = ElevationGrid::covering(
        [ground[0] - m, ground[1] - m, ground[2] + m, ground[3] + m],
        cell_m,
        rig::matching::project::pair::default_memory_mb(),
    )?;
    for r in 0..grid.rows {
        for c in 0..grid.cols {
            let [x, y] = grid.node(c, r);
            grid.z[r * grid.cols + c] = dem.height(x, y) as f32;
        }
    }
    // Computed on the simulator's ground, handed over in the world's CRS.
    Ok(rig::sim_scene::grid_to_crs(grid))
}

/// The terrain's range over the views' common ground (the sample points `zs` and the true
/// DEM's nodes there: a peak between samples must not fall outside), and the heights a scene's
/// project searches: that range with `margin_m` below and above, on whole metres.
pub fn scene_heights(
    zs: impl Iterator<Item = f64>,
    truth: &rig::matching::grid::ElevationGrid,
    margin_m: f64,
) -> ([f64; 2], [f64; 2]) {
    let all = zs.chain(truth.z.iter().filter(|z| z.is_finite()).map(|&z| z as f64));
    let (zmin, zmax) = all.fold((f64::MAX, f64::MIN), |(a, b), z| (a.min(z), b.max(z)));
    (
        [zmin, zmax],
        [(zmin - margin_m).floor(), (zmax + margin_m).ceil()],
    )
}

/// truth-dem.tif and truth-reflectance.tif in `dir`, in the world's CRS.
pub fn write_truth_grids(
    dir: &Path,
    truth: &ElevationGrid,
    reflectance: &ElevationGrid,
) -> anyhow::Result<()> {
    let crs = rig::sim_scene::CRS;
    rig::matching::products::files::write_geotiff(&dir.join("truth-dem.tif"), truth, crs)?;
    rig::matching::products::files::write_ortho(
        &dir.join("truth-reflectance.tif"),
        reflectance,
        crs,
        &reflectance.z,
    )?;
    Ok(())
}

/// Finest cell of truth-reflectance.tif, m (finer than a ground pixel of about 1 m). It is
/// doubled while it stays within a quarter of the photos' ground pixel (a 10 m satellite
/// pixel is checked on 2 m cells, not on 400 times as many), and for large areas until the
/// grid is at most [`REFLECTANCE_MAX_NODES`].
const REFLECTANCE_CELL_M: f64 = 0.5;

/// Nodes of truth-reflectance.tif at the most (25 million: 4 km × 5 km at 1 m).
const REFLECTANCE_MAX_NODES: f64 = 25e6;

/// The terrain's true reflectance (0 … 1, as the simulator shades it: what every photo's
/// grey values are a linear function of) over `dem`'s extent, in the world's CRS, and its
/// cell ([`REFLECTANCE_CELL_M`], or coarser as the photos' ground pixel `pixel_m` allows when
/// it is given).
pub fn truth_reflectance(
    reflectance_at: &(dyn Fn(f64, f64) -> f64 + Sync),
    dem: &ElevationGrid,
    pixel_m: Option<f64>,
) -> Result<(ElevationGrid, f64), rig::matching::grid::GridError> {
    let [ox, oy] = rig::sim_scene::ORIGIN_M;
    let half = 0.5 * dem.cell_m;
    let extent = [
        dem.x0 - half - ox,
        dem.y0 - (dem.rows as f64 - 0.5) * dem.cell_m - oy,
        dem.x0 + (dem.cols as f64 - 0.5) * dem.cell_m - ox,
        dem.y0 + half - oy,
    ];
    let area_m2 = (extent[2] - extent[0]) * (extent[3] - extent[1]);
    let mut cell_m = REFLECTANCE_CELL_M;
    while pixel_m.is_some_and(|p| 2.0 * cell_m <= 0.25 * p) && cell_m < 1e4 {
        cell_m *= 2.0;
    }
    while area_m2 / (cell_m * cell_m) > REFLECTANCE_MAX_NODES && cell_m < 1e4 {
        cell_m *= 2.0;
    }
    let mut grid = ElevationGrid::covering(
        extent,
        cell_m,
        rig::matching::project::pair::default_memory_mb(),
    )?;
    let cols = grid.cols;
    let nodes: Vec<[f64; 2]> = (0..grid.z.len())
        .map(|k| grid.node(k % cols, k / cols))
        .collect();
    use rayon::prelude::*;
    grid.z.par_iter_mut().zip(&nodes).for_each(|(z, [x, y])| {
        *z = reflectance_at(*x, *y) as f32;
    });
    Ok((rig::sim_scene::grid_to_crs(grid), cell_m))
}

/// A format-2 project of the rendered photos with their true orientations (the simulator's
/// truth, in the world's CRS), the heights of the terrain ± 30 m and the true DEM as the
/// reference: for the matchers alone, with no orientation error.
fn block_toml(seed: u64, photos: &[&AerialPhoto], hs: [f64; 2]) -> String {
    let [ox, oy] = rig::sim_scene::ORIGIN_M;
    let mut t = format!(
        "# The photos of `rig sim scene --seed {seed}` with their true orientations: the matchers\n# alone, with no orientation error. Run it with\n#   rig dtm block.toml --out OUT\nformat = 2\ncrs = \"{}\"\n",
        rig::sim_scene::CRS
    );
    for p in photos {
        let e = p.exterior;
        t += &format!(
            "\n[[photo]]\nid = \"{n}\"\nscan = \"photo-{n}.json\"\nposition = [{:.4}, {:.4}, {:.4}]\nangles_deg = [{:.8}, {:.8}, {:.8}]\n",
            e.x0_m + ox,
            e.y0_m + oy,
            e.z0_m,
            e.omega_deg,
            e.phi_deg,
            e.kappa_deg,
            n = p.number
        );
    }
    t += &format!(
        "\n[dem]\ncell_m = 10.0\nheights = [{:.0}, {:.0}]\n\n[matching]\nmethod = \"sweep\"   # or \"mgcm\" (seed 002's multiphoto matching) or \"oslsm\" (seed 001's object-space matching); see docs/matchers.md\n\n[check]\nreference = \"truth-dem.tif\"\n",
        hs[0] - 30.0,
        hs[1] + 30.0
    );
    t
}

/// A project for `left`/`right` (sidecars) with seed 000's parameters over the terrain range
/// `hs` (± 30 m), the points in points.json and the true DEM in truth-dem.tif.
pub fn project_toml(header: &str, [left, right]: [&Path; 2], hs: [f64; 2]) -> String {
    format!(
        r#"{header}
crs = "{crs}"              # the simulated world: WGS 84 / UTM zone 16N (see docs/conventions.md)

[photos]
left = "{l}"
right = "{r}"

[points]
file = "points.json"

[pmf]
order = 2            # terms chosen from the full second order (seed 000)
from = "points"      # or "rigorous": resect both photos from the control points, derive (seed 004)

[matching]
h_min = {lo:.0}
h_max = {hi:.0}
# h_step = 2.0      # m; default: half a pixel of parallax where it is largest
window = 9
threshold = 0.5
stride = 1

[regions]
search_distance = 2
# height_threshold = 3.0   # m; default: 1.5 × the step
population_threshold = 200

[grid]
cell_m = 10.0
reference = "truth-dem.tif"
flying_height_m = 6500.0
"#,
        crs = rig::sim_scene::CRS,
        l = left.display(),
        r = right.display(),
        lo = hs[0] - 30.0,
        hi = hs[1] + 30.0,
    )
}

/// The flags frame and pushbroom scenes share, checked (noise, truth cell, the `pictures`'
/// gains and offsets, an empty --out): the gains and offsets.
pub(super) fn check_shared(a: &SceneArgs, pictures: u32) -> anyhow::Result<(Vec<f64>, Vec<f64>)> {
    if !(a.noise_dn.is_finite() && (0.0..=10_000.0).contains(&a.noise_dn)) {
        usage_bail!("--noise-dn {}: 0 to 10000 grey values", a.noise_dn);
    }
    if let Some(c) = a.truth_cell_m {
        if !(c.is_finite() && (0.5..=100.0).contains(&c)) {
            usage_bail!("--truth-cell-m {c}: 0.5 to 100 m");
        }
    }
    let gains = per_photo(a.gains.as_deref(), "gains", pictures, 0.2..=5.0, 1.0)?;
    let offsets = per_photo(
        a.offsets.as_deref(),
        "offsets",
        pictures,
        -30_000.0..=30_000.0,
        0.0,
    )?;
    if a.out.exists() && std::fs::read_dir(&a.out)?.next().is_some() {
        anyhow::bail!("{} is not empty: give a new directory", a.out.display());
    }
    Ok((gains, offsets))
}

/// The frame camera's scene (`--sensor frame`; the dispatcher is `crate::cli::run`).
pub fn run(a: &SceneArgs) -> anyhow::Result<i32> {
    let truth_cell_m = a.truth_cell_m.unwrap_or(TRUTH_CELL_M);
    let area = parse_area(&a.area)?;
    if !(1.0..=200.0).contains(&a.resolution_um) {
        usage_bail!("--resolution-um {}: 1 to 200", a.resolution_um);
    }
    let (gains, offsets) = check_shared(a, a.photos)?;
    let radiometry: Vec<[f64; 2]> = offsets.iter().zip(&gains).map(|(&o, &g)| [o, g]).collect();
    let dem = jacksboro();
    let photo = |n: u32| {
        let mut p = AerialPhoto::new(dem.clone(), a.seed, n, 110.0);
        p.texture = a.texture.into();
        p
    };
    let (p1, p2) = (photo(1), photo(2));
    let hs = terrain_range(&p1, area);
    let area2 = matching_area(&p1, &p2, area, [hs[0] - 30.0, hs[1] + 30.0]);
    let step = a.resolution_um / 1000.0;
    let (g1, g2) = (
        PhotoGrid::covering(area, step),
        PhotoGrid::covering(area2, step),
    );
    // Photos 3 to 6 of the block, over where they see photo 1's area: each checked before
    // anything is written.
    let mut more = Vec::new();
    for n in 3..=a.photos {
        let pn = photo(n);
        let an = matching_area(&p1, &pn, area, [hs[0] - 30.0, hs[1] + 30.0]);
        if an.iter().any(|v| v.abs() > 114.0) {
            usage_bail!(
                "--area {:?}: photo {n} does not see all of it (it needs photo {n}'s {:.0},{:.0} … {:.0},{:.0} mm, beyond the 230 mm format); photos 3 and 4 see photo 1 below y ≈ −46 mm, e.g. --area 38,-70,50,-58, and all six photos see it beyond x ≈ 70 mm, e.g. --area 78,-68,88,-58",
                area, an[0], an[1], an[2], an[3]
            );
        }
        more.push((pn, an));
    }
    // The truth grids before the photos: a large area is refused (or its reflectance
    // coarsened) at once, not after the rendering.
    let truth = truth_grid(&p1, area, truth_cell_m)?;
    let (reflectance, reflectance_cell_m) =
        truth_reflectance(&|x, y| p1.reflectance_at(x, y), &truth, None)?;
    std::fs::create_dir_all(&a.out)?;
    eprintln!(
        "rendering photo 1 ({}×{} px) and photo 2 ({}×{} px)…",
        g1.width, g1.height, g2.width, g2.height
    );
    let s1 = write_photo(&a.out, "photo-1", &p1, &g1, a.noise_dn, radiometry[0])?;
    let s2 = write_photo(&a.out, "photo-2", &p2, &g2, a.noise_dn, radiometry[1])?;
    for (pn, an) in &more {
        let n = pn.number;
        let gn = PhotoGrid::covering(*an, step);
        eprintln!("rendering photo {n} ({}×{} px)…", gn.width, gn.height);
        write_photo(
            &a.out,
            &format!("photo-{n}"),
            pn,
            &gn,
            a.noise_dn,
            radiometry[n as usize - 1],
        )?;
    }
    let mut rng = rig_sim::rng::Rng::new(a.seed ^ 0x6C9);
    let noise = (a.photo_noise_um / 1000.0, a.ground_noise_m);
    let gcps = draw_points((&p1, &g1), (&p2, &g2), a.gcps, "gcp", noise, &mut rng);
    let cps = draw_points((&p1, &g1), (&p2, &g2), a.cps, "cp", noise, &mut rng);
    rig::digitise::output::write_json(
        &a.out.join("points.json"),
        &json!({"gcps": gcps, "cps": cps}),
    )?;
    write_truth_grids(&a.out, &truth, &reflectance)?;
    rig::digitise::output::write_json(
        &a.out.join("truth.json"),
        &json!({"seed": a.seed,
                "photos": std::iter::once(&p1).chain([&p2]).chain(more.iter().map(|m| &m.0)).collect::<Vec<_>>(),
                "area_mm": std::iter::once(area).chain([area2]).chain(more.iter().map(|m| m.1)).collect::<Vec<_>>(),
                "terrain_m": hs,
                "dem": format!("tests/data/jacksboro_fault_dem.asc (bilinear, {} m grid in truth-dem.tif)", truth_cell_m),
                "photo_noise_um": a.photo_noise_um, "ground_noise_m": a.ground_noise_m,
                "noise_dn": a.noise_dn,
                "radiometry": {"gains": gains, "offsets_dn": offsets,
                    "grey": "offset + gain × 60000 × (t_min + (t_max − t_min) × reflectance) + noise",
                    "t_min": p1.t_min, "t_max": p1.t_max,
                    "reflectance": format!("truth-reflectance.tif: the terrain's reflectance (0 … 1, shaded), {reflectance_cell_m} m cells")}}),
    )?;
    let all: Vec<&AerialPhoto> = std::iter::once(&p1)
        .chain([&p2])
        .chain(more.iter().map(|m| &m.0))
        .collect();
    std::fs::write(a.out.join("block.toml"), block_toml(a.seed, &all, hs))?;
    let project = project_toml(
        &format!(
            "# A matching project made by `rig sim scene` (seed {}); run it with\n#   rig dtm {}/project.toml --out OUT",
            a.seed,
            a.out.display()
        ),
        [Path::new("photo-1.json"), Path::new("photo-2.json")],
        hs,
    );
    std::fs::write(a.out.join("project.toml"), project)?;
    println!(
        "scene in {}: {} and {}{}, {} control and {} check points, truth-dem.tif, truth-reflectance.tif, project.toml (format 1, photos 1 and 2), block.toml (format 2, all {} photos with their true orientations)",
        a.out.display(),
        s1.display(),
        s2.display(),
        match more.len() { 0 => String::new(), 1 => " and photo 3".into(), n => format!(" and photos 3-{}", n + 2) },
        gcps.len(),
        cps.len(),
        all.len()
    );
    Ok(0)
}
