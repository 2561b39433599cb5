//! DigitalGlobe/Maxar `.RPB` files: RPC00B in the keyword form of DigitalGlobe's "Image
//! Support Data" (ISD) documentation, the form GDAL's `GDALLoadRPBFile` reads with its
//! `CPLKeywordParser`:
//!
//! ```text
//! satId = "WV03";
//! BEGIN_GROUP = IMAGE
//!     errBias = 1.49;
//!     lineOffset = 812;
//!     …
//!     lineNumCoef = (
//!         -6.181087E-03,
//!         …);
//! END_GROUP = IMAGE
//! END;
//! ```
//!
//! `name = value;` pairs, the `;` optional; a value is one word or a parenthesised list
//! (commas and line breaks between its numbers); `BEGIN_GROUP = X … END_GROUP = X` nests;
//! `/* … */` and `#` comments; keys compared without regard to case (all as GDAL does).
//! The numbers are the ones GDAL takes: `IMAGE.lineOffset` … `IMAGE.sampDenCoef`, with
//! `errBias` and `errRand` optional (unknown, −1, when absent). Image coordinates are
//! RPC00B's: (0, 0) at the centre of the top-left pixel.

use super::read::Slots;
use super::{Rpc, RpcError};
use std::path::Path;

/// The RPB keys of the 92 numbers, in the order of [`Rpc::to_values`] (the coefficient
/// lists stand for 20 slots each).
const KEYS: [&str; 16] = [
    "errBias",
    "errRand",
    "lineOffset",
    "sampOffset",
    "latOffset",
    "longOffset",
    "heightOffset",
    "lineScale",
    "sampScale",
    "latScale",
    "longScale",
    "heightScale",
    "lineNumCoef",
    "lineDenCoef",
    "sampNumCoef",
    "sampDenCoef",
];

/// A value as written: one word, or the words of a parenthesised list; each with its line.
#[derive(Debug)]
enum Value {
    Word(String, usize),
    List(Vec<(String, usize)>),
}

/// One `name = value` pair with its group path (`IMAGE.lineOffset`) and line.
#[derive(Debug)]
struct Pair {
    path: String,
    line: usize,
    value: Value,
}

/// The keyword grammar's reader: position and line in the text.
struct Reader<'a> {
    s: &'a [u8],
    i: usize,
    line: usize,
}

impl<'a> Reader<'a> {
    fn bump(&mut self) {
        if self.s[self.i] == b'\n' {
            self.line += 1;
        }
        self.i += 1;
    }

    fn peek(&self) -> Option<u8> {
        self.s.get(self.i).copied()
    }

    /// Skips white space and comments; an unterminated `/*` is an error.
    fn skip(&mut self) -> Result<(), String> {
        while let Some(c) = self.peek() {
            if c.is_ascii_whitespace() {
                self.bump();
            } else if c == b'/' && self.s.get(self.i + 1) == Some(&b'*') {
                let start = self.line;
                self.i += 2;
                loop {
                    match self.peek() {
                        None => return Err(format!("line {start}: a /* comment is never closed")),
                        Some(b'*') if self.s.get(self.i + 1) == Some(&b'/') => {
                            self.i += 2;
                            break;
                        }
                        Some(_) => self.bump(),
                    }
                }
            } else if c == b'#' {
                while self.peek().is_some_and(|c| c != b'\n' && c != b'\r') {
                    self.bump();
                }
            } else {
                break;
            }
        }
        Ok(())
    }

    /// A word: up to white space, `=`, `;`, `,`, `(` or `)`; quotes keep their content whole.
    fn word(&mut self) -> Result<String, String> {
        let start = self.i;
        while let Some(c) = self.peek() {
            match c {
                b'"' | b'\'' => {
                    let line = self.line;
                    self.bump();
                    while self.peek() != Some(c) {
                        if self.peek().is_none() {
                            return Err(format!("line {line}: a quoted string is never closed"));
                        }
                        self.bump();
                    }
                    self.bump();
                }
                b'=' | b';' | b',' | b'(' | b')' => break,
                c if c.is_ascii_whitespace() => break,
                _ => self.bump(),
            }
        }
        Ok(String::from_utf8_lossy(&self.s[start..self.i]).into_owned())
    }

    /// Skips one `;` after a value, if there.
    fn semicolon(&mut self) -> Result<(), String> {
        self.skip()?;
        if self.peek() == Some(b';') {
            self.bump();
        }
        Ok(())
    }

    /// A parenthesised list (the `(` already read): its words, each with its line.
    fn list(&mut self, open: usize) -> Result<Vec<(String, usize)>, String> {
        let mut out = Vec::new();
        loop {
            self.skip()?;
            match self.peek() {
                None => return Err(format!("line {open}: a ( list is never closed with )")),
                Some(b')') => {
                    self.bump();
                    return Ok(out);
                }
                Some(b',') => self.bump(),
                Some(b'(') => return Err(format!("line {}: a list inside a list", self.line)),
                Some(b'=' | b';') => {
                    return Err(format!(
                        "line {}: `{}` inside a ( list: is a ) missing?",
                        self.line,
                        self.peek().map(char::from).unwrap_or(' ')
                    ))
                }
                Some(_) => {
                    let line = self.line;
                    out.push((self.word()?, line));
                }
            }
        }
    }

    /// All pairs, with group paths; stops at `END` outside any group or at the text's end.
    fn pairs(&mut self) -> Result<Vec<Pair>, String> {
        let mut groups: Vec<String> = Vec::new();
        let mut out = Vec::new();
        loop {
            self.skip()?;
            if self.peek().is_none() {
                break;
            }
            let line = self.line;
            let name = self.word()?;
            if name.is_empty() {
                return Err(format!(
                    "line {line}: expected a name, found `{}`",
                    self.peek().map(char::from).unwrap_or(' ')
                ));
            }
            self.skip()?;
            if name.eq_ignore_ascii_case("END") && self.peek() != Some(b'=') {
                // `END;` closes the file.
                break;
            }
            if self.peek() != Some(b'=') {
                return Err(format!("line {line}: `{name}` must be followed by `=`"));
            }
            self.bump();
            self.skip()?;
            let value = if self.peek() == Some(b'(') {
                self.bump();
                Value::List(self.list(line)?)
            } else {
                let vline = self.line;
                let w = self.word()?;
                if w.is_empty() {
                    return Err(format!("line {line}: `{name} =` has no value"));
                }
                Value::Word(w, vline)
            };
            self.semicolon()?;
            let upper = name.to_ascii_uppercase();
            if upper == "BEGIN_GROUP" || upper == "BEGIN_OBJECT" {
                let Value::Word(g, _) = value else {
                    return Err(format!("line {line}: {name} names a group with one word"));
                };
                groups.push(g);
            } else if upper.starts_with("END_") {
                // At the top level, GDAL takes it for the end of the file.
                if groups.pop().is_none() {
                    break;
                }
            } else {
                let mut path: String = groups.iter().map(|g| format!("{g}.")).collect();
                path.push_str(&name);
                out.push(Pair { path, line, value });
            }
        }
        if let Some(g) = groups.last() {
            return Err(format!(
                "BEGIN_GROUP = {g} is never closed by END_GROUP = {g}"
            ));
        }
        Ok(out)
    }
}

impl Rpc {
    /// Reads a DigitalGlobe/Maxar `.RPB` (see the module's documentation): every number
    /// required once in `BEGIN_GROUP = IMAGE` (`errBias`, `errRand` optional), each checked
    /// with its line and key named and, through [`Rpc::check`], its allowed range.
    pub fn parse_rpb(text: &str, path: &Path) -> Result<Rpc, RpcError> {
        let fail = |message: String| RpcError::File {
            path: path.display().to_string(),
            message,
        };
        let pairs = Reader {
            s: text.as_bytes(),
            i: 0,
            line: 1,
        }
        .pairs()
        .map_err(fail)?;
        let mut slots = Slots::new();
        let mut seen: Vec<Option<usize>> = vec![None; KEYS.len()];
        for p in &pairs {
            let Some(k) = KEYS
                .iter()
                .position(|k| p.path.eq_ignore_ascii_case(&format!("IMAGE.{k}")))
            else {
                continue;
            };
            if let Some(first) = seen[k].replace(p.line) {
                return Err(fail(format!(
                    "line {}: IMAGE.{} is given twice (first on line {first})",
                    p.line, KEYS[k]
                )));
            }
            let number = |w: &str, line: usize, what: &str| -> Result<f64, RpcError> {
                w.parse::<f64>()
                    .ok()
                    .filter(|x| x.is_finite())
                    .ok_or_else(|| {
                        fail(format!("line {line}: {what}: `{w}` is not a finite number"))
                    })
            };
            match (&p.value, k) {
                (Value::Word(w, line), 0..=11) => {
                    let x = number(w, *line, &format!("IMAGE.{}", KEYS[k]))?;
                    slots.set(k, x, format!("line {line} (IMAGE.{})", KEYS[k]));
                }
                (Value::List(items), 12..=15) => {
                    if items.len() != 20 {
                        return Err(fail(format!(
                            "line {}: IMAGE.{} must be a list of 20 numbers (got {})",
                            p.line,
                            KEYS[k],
                            items.len()
                        )));
                    }
                    for (i, (w, line)) in items.iter().enumerate() {
                        let what = format!("IMAGE.{} number {}", KEYS[k], i + 1);
                        let x = number(w, *line, &what)?;
                        slots.set(12 + 20 * (k - 12) + i, x, format!("line {line} ({what})"));
                    }
                }
                (Value::Word(..), _) => {
                    return Err(fail(format!(
                        "line {}: IMAGE.{} must be a ( list ) of 20 numbers",
                        p.line, KEYS[k]
                    )))
                }
                (Value::List(_), _) => {
                    return Err(fail(format!(
                        "line {}: IMAGE.{} must be one number, not a list",
                        p.line, KEYS[k]
                    )))
                }
            }
        }
        for (k, key) in KEYS.iter().enumerate().skip(2) {
            if seen[k].is_none() {
                return Err(fail(format!(
                    "IMAGE.{key} is missing (an RPB holds its numbers between BEGIN_GROUP = IMAGE and END_GROUP = IMAGE)"
                )));
            }
        }
        slots.finish(path)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const RPB: &str = include_str!("../../../tests/data/rpc/md_dg.RPB");

    fn parse(t: &str) -> Result<Rpc, String> {
        Rpc::parse_rpb(t, Path::new("x.RPB")).map_err(|e| e.to_string())
    }

    #[test]
    fn a_worldview_rpb_is_read() {
        let r = parse(RPB).unwrap();
        assert_eq!((r.err_bias, r.err_rand), (1.49, 0.58));
        assert_eq!((r.line_off, r.samp_off), (812.0, 850.0));
        assert_eq!(
            (r.lat_off, r.long_off, r.height_off),
            (41.8791, 12.5798, 95.0)
        );
        assert_eq!((r.line_scale, r.samp_scale), (938.0, 1152.0));
        assert_eq!(
            (r.lat_scale, r.long_scale, r.height_scale),
            (0.015, 0.0225, 501.0)
        );
        assert_eq!(r.line_num[0], -6.181087E-03);
        assert_eq!(r.line_num[19], -9.876127E-08);
        assert_eq!(r.samp_den[3], -4.371442E-04);
        assert_eq!(r.line_den[0], 1.0);
    }

    #[test]
    fn the_variants_gdal_reads_are_read() {
        let want = parse(RPB).unwrap();
        // CRLF line ends, a list on one line, no `;`, lower-case keys, comments, no errors.
        let variant = RPB
            .replace('\n', "\r\n")
            .replace(";\r\n", "\r\n")
            .replace("lineOffset", "LINEOFFSET")
            .replace(
                "\terrBias =    1.49\r\n\terrRand =    0.58\r\n",
                "/* no errors */\r\n# given\r\n",
            );
        let one_line = {
            let start = variant.find("sampDenCoef = (").unwrap();
            let end = start + variant[start..].find(')').unwrap();
            let list = variant[start..end].replace("\r\n", " ");
            format!("{}{}{}", &variant[..start], list, &variant[end..])
        };
        let r = parse(&one_line).unwrap();
        assert_eq!((r.err_bias, r.err_rand), (-1.0, -1.0));
        assert_eq!(r.to_values()[2..], want.to_values()[2..]);
    }

    #[test]
    fn bad_rpbs_are_refused_with_the_line_and_key_named() {
        let cases = [
            // A missing key.
            (
                RPB.replace("\tlatScale =    0.0150;\n", ""),
                "IMAGE.latScale is missing",
            ),
            // A non-number.
            (
                RPB.replace("heightOffset = 95", "heightOffset = 9x5"),
                "line 11: IMAGE.heightOffset: `9x5` is not a finite number",
            ),
            (
                RPB.replace("+1.557476E-05", "+1.557476F-05"),
                "line 27: IMAGE.lineNumCoef number 10: `+1.557476F-05` is not a finite number",
            ),
            // A number out of range, with the allowed range.
            (
                RPB.replace("latOffset =   41.8791", "latOffset =   141.8791"),
                "line 9 (IMAGE.latOffset): LAT_OFF must be -90 … 90 (got 141.8791)",
            ),
            (
                RPB.replace("longScale =    0.0225", "longScale =    0"),
                "line 15 (IMAGE.longScale): LONG_SCALE must be",
            ),
            // Wrong counts and structure.
            (
                RPB.replace("\t\t\t-9.876127E-08);", "\t\t\t);"),
                "line 17: IMAGE.lineNumCoef must be a list of 20 numbers (got 19)",
            ),
            (
                RPB.replace("lineScale = 938", "lineScale = (938)"),
                "IMAGE.lineScale must be one number",
            ),
            (
                RPB.replace(
                    "heightScale = 501",
                    "heightScale = 501;\n\theightScale = 502",
                ),
                "given twice",
            ),
            (RPB.replace("END_GROUP = IMAGE\n", ""), "never closed"),
            (RPB.replace("BEGIN_GROUP = IMAGE", ""), "is missing"),
        ];
        for (text, want) in cases {
            let e = parse(&text).unwrap_err();
            assert!(
                e.starts_with("x.RPB: ") && e.contains(want),
                "{e}\nwanted: {want}"
            );
        }
    }
}
