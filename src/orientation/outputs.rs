//! What `rig orient` writes into its folder: `project.toml` (the same project with every photo
//! oriented: position, angles and their σ; every other key kept, paths relative to the
//! folder; `[dem] heights` from the tie points where it gave none; `[orientation] covariance`
//! naming the next file), `points.csv` (each adjusted point's ground and σ),
//! `covariance.csv` (the orientations' covariance, [`super::covariance`]), `report.json` and
//! `report.html` (σ̂₀, residuals by photo and point with a residual-vector plot per photo,
//! check points' errors, the object points' precision as seed 002 Table 9 gives it, the rays
//! data snooping removed). Each file is written atomically.

use super::bundle::{Block, RayStatus, Role};
use super::oriented::Oriented;
use crate::matching::products::html::escape;
use crate::relative::relative_to;
use serde::Serialize;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

pub const FILES: [&str; 5] = [
    "project.toml",
    "points.csv",
    super::covariance::FILE,
    "report.json",
    "report.html",
];

#[derive(Debug, Clone, Serialize)]
pub struct PhotoLine {
    pub id: String,
    pub position: [f64; 3],
    pub angles_deg: [f64; 3],
    pub sigma_position_m: [f64; 3],
    pub sigma_angles_deg: [f64; 3],
    /// How far the adjustment moved the centre from its approximation, m.
    pub moved_m: Option<f64>,
    pub rays: usize,
    /// RMS of its rays' residuals, px.
    pub rms_px: f64,
}

/// A self-calibrated camera ([`super::bundle::Calibrated`]): its interior and σ (0 where
/// held as given).
#[derive(Debug, Clone, Serialize)]
pub struct CameraLine {
    pub camera: String,
    pub focal_mm: f64,
    pub principal_point_mm: [f64; 2],
    /// k₁, k₂ ([`crate::geometry::lens`]).
    pub distortion: [f64; 2],
    pub sigma_focal_mm: f64,
    pub sigma_principal_point_mm: [f64; 2],
    pub sigma_distortion: [f64; 2],
}

#[derive(Debug, Clone, Serialize)]
pub struct CheckLine {
    pub id: String,
    /// Intersected − given, m.
    pub error_m: [f64; 3],
    pub rays: usize,
}

#[derive(Debug, Clone, Serialize)]
pub struct Blunder {
    pub point: String,
    pub photo: String,
    pub residual_px: [f64; 2],
    pub w: Option<[f64; 2]>,
}

/// Seed 002 Table 9's figures: the object points' theoretical precision (mean σ of X, Y, Z),
/// by the number of rays.
#[derive(Debug, Clone, Serialize)]
pub struct PrecisionRow {
    pub rays: String,
    pub points: usize,
    pub sigma_m: [f64; 3],
}

#[derive(Debug, Clone, Serialize)]
pub struct Report {
    pub photos: usize,
    pub control_points: usize,
    pub tie_points: usize,
    pub check_points: usize,
    pub rays_used: usize,
    pub rays_rejected: usize,
    pub sigma0: f64,
    /// The measured rays' σ after the variance-component step, px.
    pub image_sigma_px: f64,
    pub redundancy: f64,
    pub iterations: usize,
    pub per_photo: Vec<PhotoLine>,
    /// The self-calibrated cameras (none unless `[orientation] self_calibration`).
    pub cameras: Vec<CameraLine>,
    pub check: Vec<CheckLine>,
    /// RMSE of the check points, m: XY (horizontal distance) and Z.
    pub check_rmse_m: Option<[f64; 2]>,
    pub precision: Vec<PrecisionRow>,
    pub blunders: Vec<Blunder>,
}

fn rms(v: impl Iterator<Item = f64>) -> f64 {
    let (s, n) = v.fold((0.0, 0usize), |(s, n), x| (s + x * x, n + 1));
    if n == 0 {
        0.0
    } else {
        (s / n as f64).sqrt()
    }
}

/// Each photo's rays (indices into the block's), in one pass over them.
fn rays_by_photo(b: &Block) -> Vec<Vec<usize>> {
    let mut v = vec![Vec::new(); b.photos.len()];
    for (k, r) in b.rays.iter().enumerate() {
        v[r.photo].push(k);
    }
    v
}

impl Report {
    pub fn of(o: &Oriented, image_sigma_px: f64) -> Report {
        let (b, a) = (&o.block, &o.adjusted);
        let by_photo = rays_by_photo(b);
        let per_photo = b
            .photos
            .iter()
            .enumerate()
            .map(|(i, ph)| {
                let e = a.exteriors[i];
                let s = a.sigma(i);
                let used: Vec<f64> = by_photo[i]
                    .iter()
                    .map(|&k| &a.rays[k])
                    .filter(|x| x.status == RayStatus::Used)
                    .map(|x| x.residual_mm[0].hypot(x.residual_mm[1]) / ph.pixel_mm)
                    .collect();
                PhotoLine {
                    id: ph.id.clone(),
                    position: [e.centre.x, e.centre.y, e.centre.z],
                    angles_deg: [
                        e.omega.to_degrees(),
                        e.phi.to_degrees(),
                        e.kappa.to_degrees(),
                    ],
                    sigma_position_m: [s[3], s[4], s[5]],
                    sigma_angles_deg: [s[0].to_degrees(), s[1].to_degrees(), s[2].to_degrees()],
                    moved_m: ph.approx.map(|p| {
                        let d = [
                            p.centre.x - e.centre.x,
                            p.centre.y - e.centre.y,
                            p.centre.z - e.centre.z,
                        ];
                        (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt()
                    }),
                    rays: used.len(),
                    rms_px: rms(used.into_iter()),
                }
            })
            .collect();
        let mut check = Vec::new();
        let mut precision: Vec<(usize, [f64; 3], usize)> = Vec::new();
        for (j, pt) in b.points.iter().enumerate() {
            let Some(ap) = &a.points[j] else { continue };
            match pt.role {
                Role::Check { ground } => check.push(CheckLine {
                    id: pt.id.clone(),
                    error_m: [
                        ap.ground.x - ground.x,
                        ap.ground.y - ground.y,
                        ap.ground.z - ground.z,
                    ],
                    rays: ap.rays,
                }),
                Role::Tie => {
                    let k = ap.rays.min(5);
                    let s = [ap.cov[(0, 0)], ap.cov[(1, 1)], ap.cov[(2, 2)]];
                    match precision.iter_mut().find(|p| p.0 == k) {
                        Some(p) => {
                            (0..3).for_each(|c| p.1[c] += s[c]);
                            p.2 += 1;
                        }
                        None => precision.push((k, s, 1)),
                    }
                }
                Role::Control { .. } => {}
            }
        }
        precision.sort_by_key(|p| p.0);
        let precision = precision
            .into_iter()
            .map(|(k, s, n)| PrecisionRow {
                rays: if k == 5 { "5+".into() } else { k.to_string() },
                points: n,
                sigma_m: std::array::from_fn(|c| (s[c] / n as f64).sqrt()),
            })
            .collect();
        let check_rmse_m = (!check.is_empty()).then(|| {
            [
                rms(check.iter().map(|c| c.error_m[0].hypot(c.error_m[1]))),
                rms(check.iter().map(|c| c.error_m[2])),
            ]
        });
        let blunders = b
            .rays
            .iter()
            .zip(&a.rays)
            .filter(|(_, x)| x.status == RayStatus::Rejected)
            .map(|(r, x)| {
                let p = b.photos[r.photo].pixel_mm;
                Blunder {
                    point: b.points[r.point].id.clone(),
                    photo: b.photos[r.photo].id.clone(),
                    residual_px: [x.residual_mm[0] / p, x.residual_mm[1] / p],
                    w: x.w,
                }
            })
            .collect();
        let count = |f: &dyn Fn(&Role) -> bool| b.points.iter().filter(|p| f(&p.role)).count();
        Report {
            photos: b.photos.len(),
            control_points: count(&|r| matches!(r, Role::Control { .. })),
            tie_points: count(&|r| matches!(r, Role::Tie)),
            check_points: count(&|r| matches!(r, Role::Check { .. })),
            rays_used: a
                .rays
                .iter()
                .filter(|r| r.status == RayStatus::Used)
                .count(),
            rays_rejected: a.rejected,
            sigma0: a.sigma0,
            image_sigma_px,
            redundancy: a.redundancy,
            iterations: a.iterations,
            per_photo,
            cameras: a
                .calibrated
                .iter()
                .map(|c| CameraLine {
                    camera: c.camera.clone(),
                    focal_mm: c.interior.focal_mm,
                    principal_point_mm: [
                        c.interior.principal_point.x,
                        c.interior.principal_point.y,
                    ],
                    distortion: [c.interior.lens.k1, c.interior.lens.k2],
                    sigma_focal_mm: c.sigma[0],
                    sigma_principal_point_mm: [c.sigma[1], c.sigma[2]],
                    sigma_distortion: [c.sigma[3], c.sigma[4]],
                })
                .collect(),
            check,
            check_rmse_m,
            precision,
            blunders,
        }
    }
}

/// The oriented project's TOML: the source project's text with each photo's position and
/// angles replaced, its approximations' σ keys replaced by `sigma`, and every path made
/// relative to `out`.
pub fn oriented_project(
    source: &Path,
    text: &str,
    out: &Path,
    report: &Report,
    heights: [f64; 2],
) -> Result<String, String> {
    let mut t: toml::Table = text
        .parse()
        .map_err(|e| format!("{}: {e}", source.display()))?;
    let base = source.parent().unwrap_or(Path::new(".")).to_path_buf();
    let rel = |v: &mut toml::Value| {
        if let Some(s) = v.as_str() {
            let abs: PathBuf = base.join(s);
            *v = toml::Value::String(relative_to(out, &abs).to_string_lossy().into_owned());
        }
    };
    let round = |x: f64, d: i32| {
        let m = 10f64.powi(d);
        (x * m).round() / m
    };
    let arr = |v: &[f64], d: i32| {
        toml::Value::Array(v.iter().map(|x| toml::Value::Float(round(*x, d))).collect())
    };
    // Values of some 10⁻⁴ (k₁, k₂ and σ) with 10 significant digits.
    let digits = |x: f64| toml::Value::Float(format!("{x:.9e}").parse().unwrap_or(x));
    let sig = |v: &[f64]| toml::Value::Array(v.iter().map(|x| digits(*x)).collect());
    if let Some(photos) = t.get_mut("photo").and_then(|v| v.as_array_mut()) {
        for ph in photos.iter_mut() {
            let Some(tab) = ph.as_table_mut() else {
                continue;
            };
            for k in ["image", "scan", "pushbroom", "rpc"] {
                if let Some(v) = tab.get_mut(k) {
                    rel(v);
                }
            }
            let id = tab
                .get("id")
                .and_then(|v| v.as_str())
                .unwrap_or_default()
                .to_string();
            let Some(line) = report.per_photo.iter().find(|l| l.id == id) else {
                continue;
            };
            tab.remove("position_sigma_m");
            tab.remove("angles_sigma_deg");
            tab.insert("position".into(), arr(&line.position, 4));
            tab.insert("angles_deg".into(), arr(&line.angles_deg, 7));
            let mut s = toml::Table::new();
            s.insert("position_m".into(), arr(&line.sigma_position_m, 4));
            s.insert("angles_deg".into(), arr(&line.sigma_angles_deg, 7));
            tab.insert("sigma".into(), toml::Value::Table(s));
        }
    }
    // Self-calibrated cameras: their interior as adjusted, with its σ.
    for c in &report.cameras {
        let Some(tab) = t
            .get_mut("camera")
            .and_then(|v| v.as_table_mut())
            .and_then(|v| v.get_mut(&c.camera))
            .and_then(|v| v.as_table_mut())
        else {
            continue;
        };
        tab.insert("focal_mm".into(), toml::Value::Float(round(c.focal_mm, 6)));
        tab.insert("principal_point_mm".into(), arr(&c.principal_point_mm, 6));
        tab.insert("distortion".into(), sig(&c.distortion));
        let mut s = toml::Table::new();
        s.insert("focal_mm".into(), digits(c.sigma_focal_mm));
        s.insert(
            "principal_point_mm".into(),
            sig(&c.sigma_principal_point_mm),
        );
        s.insert("distortion".into(), sig(&c.sigma_distortion));
        tab.insert("sigma".into(), toml::Value::Table(s));
    }
    for (table, key) in [
        ("points", "file"),
        ("check", "reference"),
        ("matching", "mappings_file"),
    ] {
        if let Some(v) = t
            .get_mut(table)
            .and_then(|v| v.as_table_mut())
            .and_then(|t| t.get_mut(key))
        {
            rel(v);
        }
    }
    // The terrain's heights from the adjusted tie points, where the project gave none: a
    // matcher's range from the few control points alone misses what lies beyond them.
    if let Some(dem) = t.get_mut("dem").and_then(|v| v.as_table_mut()) {
        if !dem.contains_key("heights") {
            dem.insert(
                "heights".into(),
                toml::Value::Array(
                    heights
                        .iter()
                        .map(|z| toml::Value::Float(round(*z, 1)))
                        .collect(),
                ),
            );
        }
    }
    // [orientation]: the project's (refraction, curvature) with the covariance added.
    let o = t
        .entry("orientation")
        .or_insert_with(|| toml::Value::Table(toml::Table::new()));
    if let Some(o) = o.as_table_mut() {
        o.insert(
            "covariance".into(),
            toml::Value::String(super::covariance::FILE.into()),
        );
    }
    let body = toml::to_string(&t).map_err(|e| e.to_string())?;
    Ok(format!(
        "# oriented by `rig orient` from {} (σ̂₀ {:.3}, {} rays, check points in report.json)\n{body}",
        relative_to(out, source).display(),
        report.sigma0,
        report.rays_used
    ))
}

/// `points.csv`: every adjusted point (control, tie) and intersected check point.
pub fn points_csv(o: &Oriented) -> String {
    let mut s = String::from("id,kind,x,y,z,sigma_x,sigma_y,sigma_z,rays\n");
    for (pt, ap) in o.block.points.iter().zip(&o.adjusted.points) {
        let Some(ap) = ap else { continue };
        let kind = match pt.role {
            Role::Control { .. } => "gcp",
            Role::Tie => "tie",
            Role::Check { .. } => "cp",
        };
        let sd = |k: usize| ap.cov[(k, k)].max(0.0).sqrt();
        let _ = writeln!(
            s,
            "{},{kind},{:.4},{:.4},{:.4},{:.4},{:.4},{:.4},{}",
            pt.id,
            ap.ground.x,
            ap.ground.y,
            ap.ground.z,
            sd(0),
            sd(1),
            sd(2),
            ap.rays
        );
    }
    s
}

/// `report.html`: the figures as tables and each photo's residual vectors (SVG), for a person.
pub fn html(o: &Oriented, r: &Report) -> String {
    let mut h = String::new();
    let _ = write!(
        h,
        "<!doctype html><meta charset=utf-8><title>rig orient</title><style>body{{font-family:sans-serif;max-width:70em;margin:1em auto}}table{{border-collapse:collapse}}td,th{{border:1px solid #ccc;padding:2px 6px;text-align:right}}svg{{border:1px solid #999;margin:4px}}figure{{display:inline-block;margin:4px}}</style>\
         <h1>Block orientation</h1><p>{} photos, {} control, {} tie and {} check points; {} rays used, {} rejected by data snooping; σ̂₀ {:.3} (rays' σ {:.3} px), redundancy {:.0}, {} iterations.</p>",
        r.photos, r.control_points, r.tie_points, r.check_points, r.rays_used, r.rays_rejected, r.sigma0, r.image_sigma_px, r.redundancy, r.iterations
    );
    if let Some([xy, z]) = r.check_rmse_m {
        let _ = write!(h, "<p><b>Check points</b> (never in the adjustment): RMSE XY {xy:.3} m, Z {z:.3} m over {}.</p>", r.check.len());
    }
    h.push_str("<h2>Photos</h2><table><tr><th>photo<th>X<th>Y<th>Z<th>ω°<th>φ°<th>κ°<th>σX<th>σY<th>σZ<th>σω°<th>σφ°<th>σκ°<th>moved m<th>rays<th>RMS px</tr>");
    for p in &r.per_photo {
        let _ = write!(
            h,
            "<tr><td>{}<td>{:.2}<td>{:.2}<td>{:.2}<td>{:.4}<td>{:.4}<td>{:.4}<td>{:.2}<td>{:.2}<td>{:.2}<td>{:.4}<td>{:.4}<td>{:.4}<td>{}<td>{}<td>{:.3}</tr>",
            escape(&p.id), p.position[0], p.position[1], p.position[2], p.angles_deg[0], p.angles_deg[1], p.angles_deg[2],
            p.sigma_position_m[0], p.sigma_position_m[1], p.sigma_position_m[2],
            p.sigma_angles_deg[0], p.sigma_angles_deg[1], p.sigma_angles_deg[2],
            p.moved_m.map_or("—".into(), |m| format!("{m:.1}")), p.rays, p.rms_px
        );
    }
    if !r.cameras.is_empty() {
        h.push_str("</table><h2>Self-calibrated cameras</h2><table><tr><th>camera<th>c mm<th>x₀ mm<th>y₀ mm<th>k₁<th>k₂<th>σc<th>σx₀<th>σy₀<th>σk₁<th>σk₂</tr>");
        for c in &r.cameras {
            let _ = write!(
                h,
                "<tr><td>{}<td>{:.4}<td>{:.4}<td>{:.4}<td>{:.3e}<td>{:.3e}<td>{:.4}<td>{:.4}<td>{:.4}<td>{:.1e}<td>{:.1e}</tr>",
                escape(&c.camera), c.focal_mm, c.principal_point_mm[0], c.principal_point_mm[1],
                c.distortion[0], c.distortion[1], c.sigma_focal_mm, c.sigma_principal_point_mm[0],
                c.sigma_principal_point_mm[1], c.sigma_distortion[0], c.sigma_distortion[1]
            );
        }
    }
    h.push_str("</table><h2>Object points' precision (seed 002 Table 9)</h2><table><tr><th>rays<th>points<th>σX m<th>σY m<th>σZ m</tr>");
    for p in &r.precision {
        let _ = write!(
            h,
            "<tr><td>{}<td>{}<td>{:.3}<td>{:.3}<td>{:.3}</tr>",
            p.rays, p.points, p.sigma_m[0], p.sigma_m[1], p.sigma_m[2]
        );
    }
    h.push_str("</table>");
    // Residual vectors: each photo's used rays, the largest drawn 30 px long.
    let b = &o.block;
    let a = &o.adjusted;
    let max_res = a
        .rays
        .iter()
        .filter(|x| x.status == RayStatus::Used)
        .map(|x| x.residual_mm[0].hypot(x.residual_mm[1]))
        .fold(0.0, f64::max)
        .max(1e-12);
    let _ = write!(h, "<h2>Residual vectors</h2><p>Blue: rays used; red: rejected. The longest used vector ({:.3} px) is drawn 30 px long.</p>", max_res / b.photos.first().map_or(1.0, |p| p.pixel_mm));
    for (ph, ks) in b.photos.iter().zip(rays_by_photo(b)) {
        let rays: Vec<_> = ks.iter().map(|&k| (&b.rays[k], &a.rays[k])).collect();
        let (mut x0, mut x1, mut y0, mut y1) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
        for (r, _) in &rays {
            x0 = x0.min(r.xy.x);
            x1 = x1.max(r.xy.x);
            y0 = y0.min(r.xy.y);
            y1 = y1.max(r.xy.y);
        }
        let span = (x1 - x0).max(y1 - y0).max(1e-9);
        let size = 240.0;
        let _ = write!(
            h,
            "<figure><svg width={size} height={size} viewBox='-15 -15 {} {}'>",
            size + 30.0,
            size + 30.0
        );
        for (r, x) in &rays {
            let px = (r.xy.x - x0) / span * size;
            let py = (y1 - r.xy.y) / span * size;
            let k = 30.0 / max_res;
            let (dx, dy) = (x.residual_mm[0] * k, -x.residual_mm[1] * k);
            let colour = match x.status {
                RayStatus::Used => "#1565c0",
                RayStatus::Rejected => "#c62828",
                _ => "#888",
            };
            let _ = write!(h, "<circle cx='{px:.1}' cy='{py:.1}' r='1.5' fill='{colour}'/><line x1='{px:.1}' y1='{py:.1}' x2='{:.1}' y2='{:.1}' stroke='{colour}'/>", px + dx, py + dy);
        }
        let _ = write!(
            h,
            "</svg><figcaption>photo {}</figcaption></figure>",
            escape(&ph.id)
        );
    }
    if !r.blunders.is_empty() {
        h.push_str("<h2>Rejected rays</h2><table><tr><th>point<th>photo<th>residual px<th>w</tr>");
        for bl in &r.blunders {
            let _ = write!(
                h,
                "<tr><td>{}<td>{}<td>{:.2}, {:.2}<td>{}</tr>",
                escape(&bl.point),
                escape(&bl.photo),
                bl.residual_px[0],
                bl.residual_px[1],
                bl.w.map_or("—".into(), |w| format!("{:.1}, {:.1}", w[0], w[1]))
            );
        }
        h.push_str("</table>");
    }
    if !r.check.is_empty() {
        h.push_str(
            "<h2>Check points</h2><table><tr><th>point<th>dX m<th>dY m<th>dZ m<th>rays</tr>",
        );
        for c in &r.check {
            let _ = write!(
                h,
                "<tr><td>{}<td>{:.3}<td>{:.3}<td>{:.3}<td>{}</tr>",
                escape(&c.id),
                c.error_m[0],
                c.error_m[1],
                c.error_m[2],
                c.rays
            );
        }
        h.push_str("</table>");
    }
    h
}

/// Writes [`FILES`] into `out` (created), each atomically, the project last.
pub fn write(source: &Path, out: &Path, o: &Oriented) -> Result<Report, String> {
    std::fs::create_dir_all(out).map_err(|e| format!("cannot create {}: {e}", out.display()))?;
    let text = std::fs::read_to_string(source)
        .map_err(|e| format!("cannot read {}: {e}", source.display()))?;
    let report = Report::of(o, o.image_sigma_px);
    let project = oriented_project(source, &text, out, &report, o.heights)?;
    let io = |e: std::io::Error| e.to_string();
    crate::atomic::write(&out.join("points.csv"), points_csv(o).as_bytes()).map_err(io)?;
    let ids: Vec<String> = o.block.photos.iter().map(|ph| ph.id.clone()).collect();
    let cov = super::covariance::text(&ids, &o.pairs, &|i, j| o.adjusted.between(i, j));
    crate::atomic::write(&out.join(super::covariance::FILE), cov.as_bytes()).map_err(io)?;
    crate::atomic::write_json(&out.join("report.json"), &report).map_err(io)?;
    crate::atomic::write(&out.join("report.html"), html(o, &report).as_bytes()).map_err(io)?;
    // Last: the project names the files above, which are then all there.
    crate::atomic::write(&out.join("project.toml"), project.as_bytes()).map_err(io)?;
    Ok(report)
}
