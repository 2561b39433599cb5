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

impl MappingsFile {
    /// Reads `path`: a `mappings.json`, or format 1's `pmfs.json` (one set) where the project
    /// has two photos (`ids`, the first the left one).
    pub fn read(path: &Path, ids: &[&str]) -> Result<MappingsFile, String> {
        let text = std::fs::read_to_string(path).map_err(|e| format!("cannot read it: {e}"))?;
        let value: serde_json::Value =
            serde_json::from_str(&text).map_err(|e| format!("not JSON: {e}"))?;
        // A document with "pairs" is a mappings.json; anything else is taken for one set, so
        // that each form's own error is the one said.
        let file = if value.get("pairs").is_some() {
            serde_json::from_value::<MappingsFile>(value).map_err(|e| {
                format!("not a mappings.json ({{\"pairs\": [{{\"left\", \"right\", \"mappings\"}}]}}): {e}")
            })?
        } else {
            let one = serde_json::from_value::<PmfSet>(value).map_err(|e| {
                format!("neither a mappings.json (no \"pairs\") nor one pair's set of mapping functions (format 1's pmfs.json): {e}")
            })?;
            let [l, r] = ids else {
                return Err(format!(
                    "one pair's mapping functions, for a project of {} photos: give a mappings.json with every pair (a sweep of the project with mappings = \"points\" or \"sensors\" writes one)",
                    ids.len()
                ));
            };
            MappingsFile {
                pairs: vec![PairMappings {
                    left: (*l).to_string(),
                    right: (*r).to_string(),
                    mappings: one,
                }],
            }
        };
        for p in &file.pairs {
            for id in [&p.left, &p.right] {
                if !ids.contains(&id.as_str()) {
                    return Err(format!(
                        "the pair {} × {} names photo {id:?}, which the project does not have",
                        p.left, p.right
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::pushbroom::fixtures::spot_like;

    /// Both forms read; each refusal names its cause; a pair is found by its order.
    #[test]
    fn both_forms_read_and_what_is_wrong_is_named() {
        let set =
            PmfSet::from_sensors(&spot_like(-20.0), &spot_like(20.0), [0.0, 2000.0], 2).unwrap();
        let d = tempfile::tempdir().unwrap();
        let write = |name: &str, v: &serde_json::Value| {
            let f = d.path().join(name);
            std::fs::write(&f, v.to_string()).unwrap();
            f
        };
        let pairs = write(
            "mappings.json",
            &serde_json::json!({"pairs": [{"left": "a", "right": "b", "mappings": set}]}),
        );
        let f = MappingsFile::read(&pairs, &["a", "b", "c"]).unwrap();
        assert_eq!(f.pair("a", "b").unwrap(), &set);
        let e = f.pair("b", "a").unwrap_err();
        assert!(
            e.contains("no pair b × a") && e.contains("it has: a × b"),
            "{e}"
        );
        let e = MappingsFile::read(&pairs, &["a", "c"]).unwrap_err();
        assert!(e.contains("names photo \"b\""), "{e}");
        // Format 1's one set: the project's two photos, the first the left.
        let one = write("pmfs.json", &serde_json::to_value(&set).unwrap());
        let f = MappingsFile::read(&one, &["left", "right"]).unwrap();
        assert_eq!(f.pair("left", "right").unwrap(), &set);
        let e = MappingsFile::read(&one, &["a", "b", "c"]).unwrap_err();
        assert!(e.contains("project of 3 photos"), "{e}");
        // Each form's own error.
        let bad = write("bad.json", &serde_json::json!({"pairs": 3}));
        let e = MappingsFile::read(&bad, &["a", "b"]).unwrap_err();
        assert!(e.contains("not a mappings.json"), "{e}");
        let bad = write("bad1.json", &serde_json::json!({"left_to_right": 1}));
        let e = MappingsFile::read(&bad, &["a", "b"]).unwrap_err();
        assert!(e.contains("nor one pair's set"), "{e}");
        let e = MappingsFile::read(&d.path().join("none.json"), &["a", "b"]).unwrap_err();
        assert!(e.contains("cannot read"), "{e}");
    }
}
