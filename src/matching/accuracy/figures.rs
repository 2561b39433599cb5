//! A model's figures against independent truth, whichever matcher made it: the reference
//! DEM node by node (seed 000 Table 5), σ against the check points and the reference.

use crate::matching::accuracy::precision::{check_sigma, sigma_vs_reference, SigmaCheck};
use crate::matching::error::MatchingError;
use crate::matching::grid::{Comparison, ElevationGrid};
use crate::matching::products::files::read_geotiff;
use crate::matching::project::{Kind, Observation, Project};
use serde::{Deserialize, Serialize};

/// A format-2 model, whichever matcher made it, and its checks (in report.json at the top
/// level).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ModelFigures {
    pub grid: ElevationGrid,
    pub grid_filled: usize,
    /// The model against the project's reference DEM, node by node (seed 000 Table 5).
    pub comparison: Option<Comparison>,
    /// The model's heights at the check points against theirs, with quality.tif's σ there
    /// (each check point once, however many photos observe it).
    pub check_points: Option<SigmaCheck>,
    /// quality.tif's σ against the reference model's differences, node by node.
    pub sigma_vs_reference: Option<SigmaCheck>,
}

impl ModelFigures {
    /// Project `p`'s reference DEM, read once before the matching (so a bad path fails
    /// before the long work, not after it).
    pub fn read_reference(p: &Project) -> Result<Option<ElevationGrid>, MatchingError> {
        Ok(match &p.reference {
            Some(r) => Some(read_geotiff(r).map_err(|source| MatchingError::Reference {
                path: r.clone(),
                cause: source,
            })?),
            None => None,
        })
    }

    /// The model `grid` with its σ's `sigma_m` (per node) against project `p`'s reference
    /// DEM (from [`ModelFigures::read_reference`]) and check points `obs`
    /// (their survey error, `[points] ground_sigma_m`, adds to the model's).
    pub fn check(
        p: &Project,
        reference: Option<&ElevationGrid>,
        obs: &[Observation],
        grid: ElevationGrid,
        sigma_m: &[f32],
    ) -> ModelFigures {
        let survey_sigma_z_m = p.control_sigma_m.map_or(0.0, |[_, z]| z);
        let comparison = reference.map(|g| grid.compare(|x, y| g.interpolate(x, y)));
        let sigma_vs_reference = reference.and_then(|g| sigma_vs_reference(&grid, sigma_m, g));
        let mut seen = std::collections::HashSet::new();
        let cps = obs
            .iter()
            .filter(|o| o.kind == Kind::Cp && seen.insert(o.id.as_str()));
        let check_points = check_sigma(cps.filter_map(|o| {
            let g = o.ground?;
            let s = grid
                .node_index(g.x, g.y)
                .map_or(f64::NAN, |i| sigma_m[i] as f64);
            Some((grid.interpolate(g.x, g.y) - g.z, s.hypot(survey_sigma_z_m)))
        }));
        ModelFigures {
            grid_filled: grid.filled(),
            grid,
            comparison,
            check_points,
            sigma_vs_reference,
        }
    }

    /// The summary lines: the grid, the comparison, σ against the check points and the
    /// reference.
    pub fn lines(&self) -> Vec<(String, String)> {
        let mut v = vec![(
            "grid".to_string(),
            format!(
                "{} × {} nodes, {} with a height",
                self.grid.cols, self.grid.rows, self.grid_filled
            ),
        )];
        if let Some(c) = &self.comparison {
            v.push(("against the reference".into(), c.summary()));
        }
        for (what, c) in [
            ("check points", &self.check_points),
            ("the reference", &self.sigma_vs_reference),
        ] {
            if let Some(c) = c {
                v.push((
                    format!("σ against {what}"),
                    format!(
                        "RMSE {:.2} m, RMS σ {:.2} m, errors {:.1} × σ, {:.0} % within 2σ over {}",
                        c.rmse_m, c.rms_sigma_m, c.ratio, c.within_2_sigma_percent, c.points
                    ),
                ));
            }
        }
        v
    }
}
