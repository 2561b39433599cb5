//! The README and the pages under docs/ lead somewhere: every relative link names a file or
//! directory of the repository (and a heading of it, when it names one), every page under docs/
//! is linked from the README, and the README stays short enough to read (the reference lives in
//! docs/), and the docs' table of a run's files is the list the rig writes from.

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};

const ROOT: &str = env!("CARGO_MANIFEST_DIR");

/// The README and every Markdown page under docs/.
fn pages() -> Vec<PathBuf> {
    let mut v = vec![Path::new(ROOT).join("README.md")];
    let mut docs: Vec<PathBuf> = std::fs::read_dir(Path::new(ROOT).join("docs"))
        .expect("docs/")
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "md"))
        .collect();
    docs.sort();
    v.extend(docs);
    v
}

/// The targets of the inline links `[text](target)` outside code (fenced blocks and `spans`).
fn links(text: &str) -> Vec<String> {
    let mut out = Vec::new();
    let mut fenced = false;
    for line in text.lines() {
        if line.trim_start().starts_with("```") {
            fenced = !fenced;
            continue;
        }
        if fenced {
            continue;
        }
        // Code spans removed, so that `a[i](x)` in code is no link.
        let mut plain = String::new();
        for (k, part) in line.split('`').enumerate() {
            if k % 2 == 0 {
                plain.push_str(part);
            }
        }
        let mut rest = plain.as_str();
        while let Some(i) = rest.find("](") {
            let after = &rest[i + 2..];
            let Some(j) = after.find(')') else { break };
            out.push(after[..j].trim().to_string());
            rest = &after[j + 1..];
        }
    }
    out
}

/// GitHub's anchor of a heading: lower case, spaces to hyphens, punctuation dropped.
fn slug(heading: &str) -> String {
    heading
        .trim()
        .to_lowercase()
        .chars()
        .filter_map(|c| match c {
            ' ' => Some('-'),
            c if c.is_alphanumeric() || c == '-' || c == '_' => Some(c),
            _ => None,
        })
        .collect()
}

/// The anchors of a page's headings (outside fenced code).
fn anchors(text: &str) -> BTreeSet<String> {
    let mut fenced = false;
    let mut out = BTreeSet::new();
    for line in text.lines() {
        if line.trim_start().starts_with("```") {
            fenced = !fenced;
        } else if !fenced && line.starts_with('#') {
            out.insert(slug(line.trim_start_matches('#')));
        }
    }
    out
}

#[test]
fn every_link_leads_somewhere() {
    let mut bad = Vec::new();
    let mut checked = 0;
    for page in pages() {
        let text = std::fs::read_to_string(&page).unwrap();
        for target in links(&text) {
            if target.contains("://") || target.starts_with("mailto:") {
                continue;
            }
            checked += 1;
            let (file, anchor) = match target.split_once('#') {
                Some((f, a)) => (f, Some(a)),
                None => (target.as_str(), None),
            };
            let dest = if file.is_empty() {
                page.clone()
            } else {
                page.parent().unwrap().join(file)
            };
            if !dest.exists() {
                bad.push(format!("{}: `{target}`: no such file", page.display()));
                continue;
            }
            if let Some(a) = anchor {
                let t = std::fs::read_to_string(&dest).unwrap_or_default();
                if !anchors(&t).contains(a) {
                    bad.push(format!(
                        "{}: `{target}`: {} has no heading #{a}",
                        page.display(),
                        dest.display()
                    ));
                }
            }
        }
    }
    assert!(
        bad.is_empty(),
        "links that lead nowhere:\n{}",
        bad.join("\n")
    );
    assert!(checked >= 15, "only {checked} links checked");
}

#[test]
fn every_page_is_linked_from_the_readme_and_the_readme_is_short() {
    let readme = std::fs::read_to_string(Path::new(ROOT).join("README.md")).unwrap();
    let linked: BTreeSet<String> = links(&readme).into_iter().collect();
    for page in pages().iter().skip(1) {
        let name = format!("docs/{}", page.file_name().unwrap().to_str().unwrap());
        assert!(
            linked.contains(&name),
            "{name} is not linked from the README's list of pages"
        );
    }
    let lines = readme.lines().count();
    assert!(
        lines <= 250,
        "the README has {lines} lines: the reference belongs under docs/"
    );
}

/// The checker itself: links in code are not links, headings give GitHub's anchors.
#[test]
fn links_and_anchors_are_read_as_github_does() {
    let t =
        "See [a](docs/a.md#the-sweep) and `x[i](j)`.\n```sh\n[no](link)\n```\n# The sweep (both)\n";
    assert_eq!(links(t), vec!["docs/a.md#the-sweep".to_string()]);
    assert!(anchors(t).contains("the-sweep-both"));
    assert_eq!(
        slug(" How the MGCM's σ was made honest"),
        "how-the-mgcms-σ-was-made-honest"
    );
}

/// docs/elevation-models.md's table of a run's files is the list the rig writes from: every
/// file, in order, with what it holds and which runs write it.
#[test]
fn the_docs_list_every_output_file_as_the_rig_writes_them() {
    use rig::matching::products::outputs::OUTPUTS;
    let text = std::fs::read_to_string(Path::new(ROOT).join("docs/elevation-models.md")).unwrap();
    let rows: Vec<&str> = text
        .lines()
        .filter(|l| l.starts_with("| `"))
        .filter(|l| {
            OUTPUTS
                .iter()
                .any(|f| l.starts_with(&format!("| `{}` |", f.name)))
        })
        .collect();
    let want: Vec<String> = OUTPUTS
        .iter()
        .map(|f| format!("| `{}` | {} | {} |", f.name, f.holds, f.writer.said()))
        .collect();
    assert_eq!(
        rows, want,
        "docs/elevation-models.md's table of output files"
    );
}
