//! A one-page HTML report of a run for a person: the figures that matter in a table, the maps
//! and plots shown at their size (links, so the page stays small and the PNGs stay the data),
//! the data files linked. Plain HTML with no script or external resource, so it opens from a
//! file share or an archive as it is.

use std::fmt::Write as _;
use std::path::Path;

/// A part of the page: a heading, figures, pictures and links (paths relative to the page).
#[derive(Debug, Clone, Default)]
pub struct Section {
    pub heading: String,
    pub rows: Vec<(String, String)>,
    /// (picture, caption)
    pub pictures: Vec<(String, String)>,
    /// (file, what it is)
    pub links: Vec<(String, String)>,
}

#[derive(Debug, Clone, Default)]
pub struct Page {
    pub title: String,
    pub intro: String,
    pub sections: Vec<Section>,
}

/// `s` with HTML's special characters escaped.
pub fn escape(s: &str) -> String {
    let mut o = String::with_capacity(s.len());
    for c in s.chars() {
        match c {
            '&' => o.push_str("&amp;"),
            '<' => o.push_str("&lt;"),
            '>' => o.push_str("&gt;"),
            '"' => o.push_str("&quot;"),
            '\'' => o.push_str("&#39;"),
            c => o.push(c),
        }
    }
    o
}

/// A relative path as a link target: each segment percent-encoded where HTML or URLs need it.
fn href(p: &str) -> String {
    let mut o = String::new();
    for b in p.bytes() {
        match b {
            b'A'..=b'Z' | b'a'..=b'z' | b'0'..=b'9' | b'-' | b'_' | b'.' | b'/' | b'~' => {
                o.push(b as char)
            }
            b => {
                let _ = write!(o, "%{b:02X}");
            }
        }
    }
    o
}

impl Page {
    pub fn render(&self) -> String {
        let mut h = String::new();
        let _ = write!(
            h,
            "<!DOCTYPE html>\n<html lang=\"en\">\n<head>\n<meta charset=\"utf-8\">\n<title>{t}</title>\n\
             <style>body{{font-family:sans-serif;max-width:1100px;margin:2em auto;padding:0 1em;color:#222}}\
             table{{border-collapse:collapse;margin:0.5em 0}}td{{padding:0.2em 1em 0.2em 0;vertical-align:top}}\
             td:first-child{{color:#555}}img{{max-width:100%;border:1px solid #ccc;margin:0.5em 0}}\
             figure{{margin:1em 0}}figcaption{{color:#555}}</style>\n</head>\n<body>\n<h1>{t}</h1>\n",
            t = escape(&self.title)
        );
        if !self.intro.is_empty() {
            let _ = writeln!(h, "<p>{}</p>", escape(&self.intro));
        }
        for s in &self.sections {
            let _ = writeln!(h, "<h2>{}</h2>", escape(&s.heading));
            if !s.rows.is_empty() {
                h.push_str("<table>\n");
                for (k, v) in &s.rows {
                    let _ = writeln!(h, "<tr><td>{}</td><td>{}</td></tr>", escape(k), escape(v));
                }
                h.push_str("</table>\n");
            }
            for (p, c) in &s.pictures {
                let _ = writeln!(
                    h,
                    "<figure><a href=\"{p}\"><img src=\"{p}\" alt=\"{c}\"></a><figcaption>{c}</figcaption></figure>",
                    p = href(p),
                    c = escape(c)
                );
            }
            if !s.links.is_empty() {
                h.push_str("<ul>\n");
                for (p, what) in &s.links {
                    let _ = writeln!(
                        h,
                        "<li><a href=\"{}\">{}</a>: {}</li>",
                        href(p),
                        escape(p),
                        escape(what)
                    );
                }
                h.push_str("</ul>\n");
            }
        }
        h.push_str("</body>\n</html>\n");
        h
    }

    /// Writes the page to `path`, atomically.
    pub fn write(&self, path: &Path) -> std::io::Result<()> {
        crate::atomic::write(path, self.render().as_bytes())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn text_is_escaped_and_links_are_encoded() {
        let p = Page {
            title: "a <b> & \"c\"".into(),
            intro: String::new(),
            sections: vec![Section {
                heading: "x".into(),
                rows: vec![("RMSE".into(), "<1 m".into())],
                pictures: vec![("maps/hill shade.png".into(), "it's".into())],
                links: vec![("dem.tif".into(), "heights".into())],
            }],
        };
        let h = p.render();
        assert!(h.contains("<title>a &lt;b&gt; &amp; &quot;c&quot;</title>"));
        assert!(h.contains("<td>&lt;1 m</td>"));
        assert!(h.contains("src=\"maps/hill%20shade.png\""));
        assert!(h.contains("alt=\"it&#39;s\""));
        assert!(!h.contains("<b>"));
    }
}
