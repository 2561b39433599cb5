//! `rig orient`: a block of frame photos oriented by one bundle adjustment.

use super::shared_args::JsonOutput;
use clap::Args;
use rig::matching::project::Project;
use rig::orientation::run::{load, orient_block};
use rig::orientation::OrientOptions;
use std::path::PathBuf;

/// Options of `rig orient` (its help text is on `Command::Orient`).
#[derive(Debug, Args)]
pub struct OrientArgs {
    /// The project file (TOML, format 2): frame photos with approximate orientations
    /// (`position`, `angles_deg` with `position_sigma_m`, `angles_sigma_deg`) or none, and
    /// a points file with gcp, tie and cp lines.
    #[arg(value_name = "PROJECT.toml")]
    pub project: PathBuf,
    /// Output directory (created): project.toml, points.csv, report.json, report.html.
    #[arg(long, value_name = "DIR")]
    pub out: PathBuf,
    /// σ of a measured image point of the points file, px: its weight against the
    /// approximations and the control (σ̂₀ then rescales it once).
    #[arg(long, value_name = "PX", default_value_t = 0.5, value_parser = sigma_px)]
    pub image_sigma: f64,
    #[command(flatten)]
    pub output: JsonOutput,
}

fn sigma_px(s: &str) -> Result<f64, String> {
    let v: f64 = s
        .parse()
        .map_err(|_| format!("`{s}`: a number of pixels"))?;
    if v.is_finite() && (0.001..=100.0).contains(&v) {
        Ok(v)
    } else {
        Err(format!("{v}: 0.001 to 100 px"))
    }
}

fn scan_photo(sidecar: &std::path::Path) -> Result<rig::matching::block::photo::ScanImage, String> {
    rig::scan::ScannedPhoto::hand_over(sidecar).map_err(|e| e.to_string())
}

pub fn run(a: OrientArgs) -> anyhow::Result<i32> {
    let p = Project::load(&a.project)?;
    let photos = load(&p, &scan_photo)?;
    let o = orient_block(
        &p,
        &photos,
        OrientOptions {
            image_sigma_px: a.image_sigma,
            ..OrientOptions::default()
        },
    )?;
    let r = rig::orientation::outputs::write(&a.project, &a.out, &o).map_err(anyhow::Error::msg)?;
    if a.output.json {
        println!("{}", serde_json::to_string(&r)?);
        return Ok(rig::exit::OK);
    }
    println!(
        "{} photos oriented from {} control and {} tie points ({} rays, {} rejected): σ̂₀ {:.3}, rays' σ {:.3} px, {} iterations",
        r.photos, r.control_points, r.tie_points, r.rays_used, r.rays_rejected, r.sigma0, r.image_sigma_px, r.iterations
    );
    for l in &r.per_photo {
        println!(
            "photo {}: X {:.2} Y {:.2} Z {:.2} (σ {:.2} {:.2} {:.2} m), ω {:.4}° φ {:.4}° κ {:.4}°, moved {}, {} rays, RMS {:.3} px",
            l.id, l.position[0], l.position[1], l.position[2], l.sigma_position_m[0], l.sigma_position_m[1], l.sigma_position_m[2],
            l.angles_deg[0], l.angles_deg[1], l.angles_deg[2],
            l.moved_m.map_or("—".into(), |m| format!("{m:.1} m")), l.rays, l.rms_px
        );
    }
    for c in &r.cameras {
        println!(
            "camera {} self-calibrated: c {:.4} ± {:.4} mm, x₀ {:.4} ± {:.4}, y₀ {:.4} ± {:.4} mm, k₁ {:.3e} ± {:.1e}, k₂ {:.3e} ± {:.1e} (± 0: held)",
            c.camera, c.focal_mm, c.sigma_focal_mm, c.principal_point_mm[0], c.sigma_principal_point_mm[0],
            c.principal_point_mm[1], c.sigma_principal_point_mm[1], c.distortion[0], c.sigma_distortion[0],
            c.distortion[1], c.sigma_distortion[1]
        );
    }
    for p in &r.precision {
        println!(
            "tie points with {} rays: {} points, σ X {:.3} Y {:.3} Z {:.3} m",
            p.rays, p.points, p.sigma_m[0], p.sigma_m[1], p.sigma_m[2]
        );
    }
    if let Some([xy, z]) = r.check_rmse_m {
        println!(
            "check points ({}): RMSE XY {xy:.3} m, Z {z:.3} m",
            r.check.len()
        );
    }
    println!(
        "outputs in {}: {}",
        a.out.display(),
        rig::orientation::outputs::FILES.join(", ")
    );
    Ok(rig::exit::OK)
}
