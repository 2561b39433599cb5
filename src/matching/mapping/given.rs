//! Mapping functions given in a file (`[matching] mappings = "file"`): each pair's six
//! mappings as a sweep wrote them (its `mappings.json`), to run a project again without
//! fitting them, or with coefficients from elsewhere. Pixels are the core's (corner origin,
//! docs/conventions.md) of the whole images; the sweep moves them into the windows it reads.

use crate::matching::mapping::pmf_set::PmfSet;
use serde::{Deserialize, Serialize};
use std::path::Path;

/// One pair's mappings: `left` is the photo the sweep runs over, `right` the one it searches.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PairMappings {
    pub left: String,
    pub right: String,
    pub mappings: PmfSet,
}

/// `mappings.json`: every pair a run swept.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MappingsFile {
    pub pairs: Vec<PairMappings>,
}

#[derive(Deserialize)]
#[serde(untagged)]
enum Form {
    Pairs(MappingsFile),
    /// Format 1's `pmfs.json`: one pair's set, for a project of two photos.
    One(Box<PmfSet>),
}

impl MappingsFile {
    /// Reads `path`: a `mappings.json`, or format 1's `pmfs.json` (one set) where the project
    /// has two photos (`ids`, the first the left one).
    pub fn read(path: &Path, ids: &[&str]) -> Result<MappingsFile, String> {
        let text = std::fs::read_to_string(path)
            .map_err(|e| format!("cannot read {}: {e}", path.display()))?;
        let shown = || path.display().to_string();
        let form: Form = serde_json::from_str(&text).map_err(|e| {
            format!(
                "{}: neither a mappings.json ({{\"pairs\": [{{\"left\", \"right\", \"mappings\"}}]}}) nor one pair's set of mapping functions (format 1's pmfs.json): {e}",
                shown()
            )
        })?;
        let file = match (form, ids) {
            (Form::Pairs(f), _) => f,
            (Form::One(m), [l, r]) => MappingsFile {
                pairs: vec![PairMappings {
                    left: (*l).to_string(),
                    right: (*r).to_string(),
                    mappings: *m,
                }],
            },
            (Form::One(_), _) => {
                return Err(format!(
                    "{}: one pair's mapping functions, for a project of {} photos: give a mappings.json with every pair (a sweep of the project with mappings = \"points\" or \"sensors\" writes one)",
                    shown(),
                    ids.len()
                ))
            }
        };
        for p in &file.pairs {
            for id in [&p.left, &p.right] {
                if !ids.contains(&id.as_str()) {
                    return Err(format!(
                        "{}: the pair {} × {} names photo {id:?}, which the project does not have",
                        shown(),
                        p.left,
                        p.right
                    ));
                }
            }
        }
        Ok(file)
    }

    /// The mappings of photos `left` × `right`, or why there are none.
    pub fn pair(&self, left: &str, right: &str) -> Result<&PmfSet, String> {
        if let Some(p) = self
            .pairs
            .iter()
            .find(|p| p.left == left && p.right == right)
        {
            return Ok(&p.mappings);
        }
        let listed: Vec<String> = self
            .pairs
            .iter()
            .map(|p| format!("{} × {}", p.left, p.right))
            .collect();
        Err(format!(
            "the mappings file has no pair {left} × {right} (the photo listed first in the project is the left one); it has: {}",
            if listed.is_empty() { "none".into() } else { listed.join(", ") }
        ))
    }
}
