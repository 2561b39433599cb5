//! Drift between calibration sessions (seed 002, Tables 2 and 3): the scales, shears and RMS of
//! each pixel session and the measuring mark's pixel, the newest compared with every earlier
//! one, and changes beyond the thresholds flagged.

use serde::Serialize;
use std::path::{Path, PathBuf};

/// How much change is drift.
#[derive(Debug, Clone, Copy, Serialize, serde::Deserialize)]
pub struct DriftThresholds {
    /// µm per px.
    pub scale_um: f64,
    /// µm per px.
    pub shear_um: f64,
    /// px.
    pub mark_px: f64,
}

impl Default for DriftThresholds {
    fn default() -> Self {
        // A few times what one session measures to (scales ~0.0005 µm, mark ~0.01 px): the
        // seed saw 0.014 µm in x-scale and 2.9 px of mark shift over 2.5 months.
        DriftThresholds {
            scale_um: 0.005,
            shear_um: 0.01,
            mark_px: 0.3,
        }
    }
}

/// One pixel session's figures (a row of seed Tables 2 and 3).
#[derive(Debug, Clone, Serialize, serde::Deserialize)]
pub struct SessionFigures {
    pub session: PathBuf,
    pub x_scale: f64,
    pub y_scale: f64,
    pub x_shear: f64,
    pub y_shear: f64,
    pub rms_um: f64,
    /// Measuring mark (col, row) and its σ over the crosses, when the session located it.
    pub mark: Option<[f64; 4]>,
}

#[derive(Debug, Clone, Serialize, serde::Deserialize)]
pub struct Comparison {
    pub earlier: PathBuf,
    pub d_x_scale: f64,
    pub d_y_scale: f64,
    pub d_x_shear: f64,
    pub d_y_shear: f64,
    /// Mark shift, px (col, row), when both located it.
    pub d_mark_px: Option<[f64; 2]>,
    /// What moved beyond the thresholds.
    pub drift: Vec<String>,
}

#[derive(Debug, Clone, Serialize, serde::Deserialize)]
pub struct History {
    pub sessions: Vec<SessionFigures>,
    pub thresholds: DriftThresholds,
    pub newest_vs: Vec<Comparison>,
}

/// Reads one pixel session's results.
pub fn figures(dir: &Path) -> Result<SessionFigures, String> {
    let p = dir.join(super::session::RESULTS);
    let text = std::fs::read_to_string(&p).map_err(|e| format!("{}: {e}", p.display()))?;
    let v: serde_json::Value =
        serde_json::from_str(&text).map_err(|e| format!("{}: {e}", p.display()))?;
    let c = &v["calibration"];
    let num = |k: &str| {
        c[k].as_f64()
            .ok_or_else(|| format!("{}: `{k}` missing (not a pixel session?)", p.display()))
    };
    let mark = c["mark"].as_object().and_then(|m| {
        Some([
            m.get("mean")?["col"].as_f64()?,
            m.get("mean")?["row"].as_f64()?,
            m.get("std")?[0].as_f64()?,
            m.get("std")?[1].as_f64()?,
        ])
    });
    Ok(SessionFigures {
        session: dir.to_path_buf(),
        x_scale: num("x_scale")?,
        y_scale: num("y_scale")?,
        x_shear: num("x_shear")?,
        y_shear: num("y_shear")?,
        rms_um: num("rms_um")?,
        mark,
    })
}

/// The history of the pixel sessions in `dirs` (oldest first).
pub fn history(dirs: &[PathBuf], th: DriftThresholds) -> Result<History, String> {
    let sessions = dirs
        .iter()
        .map(|d| figures(d))
        .collect::<Result<Vec<_>, _>>()?;
    let mut newest_vs = Vec::new();
    if let Some((newest, earlier)) = sessions.split_last() {
        for e in earlier.iter().rev() {
            let mut drift = Vec::new();
            let d = [
                ("x-scale", newest.x_scale - e.x_scale, th.scale_um, "µm"),
                ("y-scale", newest.y_scale - e.y_scale, th.scale_um, "µm"),
                ("x-shear", newest.x_shear - e.x_shear, th.shear_um, "µm"),
                ("y-shear", newest.y_shear - e.y_shear, th.shear_um, "µm"),
            ];
            for (name, v, lim, unit) in d {
                if v.abs() > lim {
                    drift.push(format!(
                        "{name} changed by {v:+.4} {unit} (threshold {lim})"
                    ));
                }
            }
            let d_mark = match (newest.mark, e.mark) {
                (Some(n), Some(o)) => {
                    let dm = [n[0] - o[0], n[1] - o[1]];
                    if dm[0].hypot(dm[1]) > th.mark_px {
                        drift.push(format!(
                            "measuring mark moved by ({:+.3}, {:+.3}) px (threshold {})",
                            dm[0], dm[1], th.mark_px
                        ));
                    }
                    Some(dm)
                }
                _ => None,
            };
            newest_vs.push(Comparison {
                earlier: e.session.clone(),
                d_x_scale: d[0].1,
                d_y_scale: d[1].1,
                d_x_shear: d[2].1,
                d_y_shear: d[3].1,
                d_mark_px: d_mark,
                drift,
            });
        }
    }
    Ok(History {
        sessions,
        thresholds: th,
        newest_vs,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn session(dir: &Path, name: &str, xs: f64, mark_col: f64) -> PathBuf {
        let d = dir.join(name);
        std::fs::create_dir_all(&d).unwrap();
        let doc = serde_json::json!({"calibration": {
            "x_scale": xs, "y_scale": 10.96, "x_shear": 0.09, "y_shear": 0.10, "rms_um": 0.8,
            "mark": {"mean": {"col": mark_col, "row": 229.9}, "std": [0.07, 0.1]}}});
        std::fs::write(d.join("results.json"), doc.to_string()).unwrap();
        d
    }

    #[test]
    fn the_seeds_two_sessions_show_drift() {
        // Seed 002, Tables 2 and 3: x-scale 10.1917 → 10.2053, mark x 238.543 → 235.600.
        let t = tempfile::tempdir().unwrap();
        let a = session(t.path(), "1-pixel", 10.1917, 238.543);
        let b = session(t.path(), "2-pixel", 10.2053, 235.600);
        let h = history(&[a.clone(), b], DriftThresholds::default()).unwrap();
        let c = &h.newest_vs[0];
        assert_eq!(c.earlier, a);
        assert!((c.d_x_scale - 0.0136).abs() < 1e-9);
        assert!((c.d_mark_px.unwrap()[0] + 2.943).abs() < 1e-9);
        assert_eq!(c.drift.len(), 2, "{:?}", c.drift);
        // Within the thresholds: no drift.
        let s = session(t.path(), "3-pixel", 10.2055, 235.65);
        let h = history(&[t.path().join("2-pixel"), s], DriftThresholds::default()).unwrap();
        assert!(h.newest_vs[0].drift.is_empty());
    }
}
