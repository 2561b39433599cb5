//! Airbus DIMAP `RPC_<id>.XML`: the RPC00B models of Pléiades, SPOT 6/7 (DIMAP v2) and
//! Pléiades Neo (DIMAP v3) products ("Pléiades Imagery User Guide", Appendix on the RPC
//! file; "SPOT 6 & SPOT 7 Imagery User Guide").
//!
//! `<Rational_Function_Model><Global_RFM>` holds two models: the direct one (image →
//! ground: `<Direct_Model>`, v3 `<ImagetoGround_Values>`) and the inverse one (ground →
//! image: `<Inverse_Model>`, v3 `<GroundtoImage_Values>`). RPC00B is ground → image, so the
//! inverse model's `LINE_NUM_COEFF_1` … `SAMP_DEN_COEFF_20` are read, with
//! `<RFM_Validity>`'s `LONG_OFF`, `LAT_SCALE`, … `LINE_OFF` (as GDAL's Pleiades metadata
//! reader does; the direct model, a second fit, is not needed: [`Rpc::locate`] inverts).
//!
//! Image coordinates: DIMAP v2 puts (1, 1) at the centre of the top-left pixel
//! (`<Direct_Model_Validity_Domain>` runs from `FIRST_ROW` 1 to `LAST_ROW` = the image's
//! rows), RPC00B (0, 0). GDAL subtracts `FIRST_COL` of DIMAP v3's
//! `<ImagetoGround_Validity_Domain>` from LINE_OFF and SAMP_OFF, and 1 where that element
//! is absent (all of v2); so does this reader, so that both agree to the last digit.
//! ERR_BIAS and ERR_RAND are unknown (−1): DIMAP's `ERR_BIAS_ROW`/`_COL` are not RPC00B's
//! metres per horizontal axis, and GDAL does not take them either.
//!
//! DIMAP v1 (SPOT 1–5 `METADATA.DIM`) carries a physical model and no RPCs; GDAL reads none
//! from it, and neither does the rig.

use super::read::Slots;
use super::{Rpc, RpcError, ARRAYS, SCALARS};
use roxmltree::{Document, Node};
use std::path::Path;

fn is(n: &Node, name: &str) -> bool {
    n.is_element() && n.tag_name().name().eq_ignore_ascii_case(name)
}

fn child<'a, 'i>(n: Node<'a, 'i>, name: &str) -> Option<Node<'a, 'i>> {
    n.children().find(|c| is(c, name))
}

fn descendant<'a, 'i>(n: Node<'a, 'i>, name: &str) -> Option<Node<'a, 'i>> {
    n.descendants().find(|c| is(c, name))
}

impl Rpc {
    /// Reads an Airbus DIMAP `RPC_*.XML` (see the module's documentation): the inverse
    /// model's 80 coefficients and `<RFM_Validity>`'s ten offsets and scales, each required,
    /// each checked with its line and element named and, through [`Rpc::check`], its
    /// allowed range; LINE_OFF and SAMP_OFF shifted to RPC00B's 0-based pixel centres.
    pub fn parse_dimap(text: &str, path: &Path) -> Result<Rpc, RpcError> {
        let fail = |message: String| RpcError::File {
            path: path.display().to_string(),
            message,
        };
        let opts = roxmltree::ParsingOptions {
            allow_dtd: true,
            ..Default::default()
        };
        let doc = Document::parse_with_options(text, opts)
            .map_err(|e| fail(format!("not well-formed XML: {e}")))?;
        let root = doc.root_element();
        let line = |n: Node| doc.text_pos_at(n.range().start).row;
        let Some(rfm) =
            descendant(root, "Global_RFM").or_else(|| descendant(root, "Rational_Function_Model"))
        else {
            let version = descendant(root, "METADATA_FORMAT")
                .and_then(|n| n.attribute("version"))
                .unwrap_or("");
            let message = if root.tag_name().name() == "isd" {
                "a DigitalGlobe/Maxar XML: give the .RPB file of the same image".to_string()
            } else if version.starts_with('1') {
                format!(
                    "DIMAP v{version} (SPOT 1–5) carries a physical sensor model and no RPCs (GDAL reads none from it either): give RPCs fitted to it as an _RPC.TXT"
                )
            } else if is(&root, "Dimap_Document") || is(&root, "PHR_DIMAP_Document") {
                "no <Rational_Function_Model>: this is a DIMAP product document (DIM_*.XML); give the product's RPC_*.XML".to_string()
            } else {
                format!(
                    "<{}> is no Airbus DIMAP RPC file (no <Global_RFM>): give the product's RPC_*.XML",
                    root.tag_name().name()
                )
            };
            return Err(fail(message));
        };
        let number = |n: Node, what: &str| -> Result<f64, RpcError> {
            let t = n.text().unwrap_or("").trim();
            t.parse::<f64>()
                .ok()
                .filter(|x| x.is_finite())
                .ok_or_else(|| {
                    fail(format!(
                        "line {}: {what}: `{t}` is not a finite number",
                        line(n)
                    ))
                })
        };
        let (model, model_name) = match child(rfm, "Inverse_Model") {
            Some(m) => (m, "Inverse_Model"),
            None => match child(rfm, "GroundtoImage_Values") {
                Some(m) => (m, "GroundtoImage_Values"),
                None => {
                    return Err(fail(format!(
                        "line {}: <{}> has no <Inverse_Model> (DIMAP v2) or <GroundtoImage_Values> (DIMAP v3): the ground → image coefficients are missing",
                        line(rfm),
                        rfm.tag_name().name()
                    )))
                }
            },
        };
        let Some(validity) = child(rfm, "RFM_Validity") else {
            return Err(fail(format!(
                "line {}: <{}> has no <RFM_Validity> with the offsets and scales",
                line(rfm),
                rfm.tag_name().name()
            )));
        };
        // GDAL's shift to 0-based pixel centres: DIMAP v3 states its first pixel's number,
        // v2 counts from 1.
        let first = match descendant(root, "ImagetoGround_Validity_Domain")
            .and_then(|d| child(d, "FIRST_COL"))
        {
            Some(n) => number(n, "<ImagetoGround_Validity_Domain>/<FIRST_COL>")?,
            None => 1.0,
        };
        let mut slots = Slots::new();
        for (i, key) in SCALARS.iter().enumerate().skip(2) {
            let what = format!("<RFM_Validity>/<{key}>");
            let n = child(validity, key).ok_or_else(|| {
                fail(format!(
                    "line {}: <RFM_Validity> has no <{key}>",
                    line(validity)
                ))
            })?;
            let mut x = number(n, &what)?;
            let mut place = format!("line {} ({what}", line(n));
            if *key == "LINE_OFF" || *key == "SAMP_OFF" {
                x -= first;
                place.push_str(&format!(" less {first}, DIMAP's first pixel"));
            }
            place.push(')');
            slots.set(i, x, place);
        }
        for (a, array) in ARRAYS.iter().enumerate() {
            for k in 1..=20 {
                let key = format!("{array}_{k}");
                let what = format!("<{model_name}>/<{key}>");
                let n = child(model, &key).ok_or_else(|| {
                    fail(format!(
                        "line {}: <{model_name}> has no <{key}>",
                        line(model)
                    ))
                })?;
                let x = number(n, &what)?;
                slots.set(12 + 20 * a + k - 1, x, format!("line {} ({what})", line(n)));
            }
        }
        slots.finish(path)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const PHR: &str = include_str!(
        "../../../tests/data/rpc/RPC_PHR1B_P_201709281038393_SEN_PRG_FC_178609-001.XML"
    );
    const SPOT6: &str = include_str!("../../../tests/data/rpc/rpc_SPOT6.xml");

    fn parse(t: &str) -> Result<Rpc, String> {
        Rpc::parse_dimap(t, Path::new("RPC_x.XML")).map_err(|e| e.to_string())
    }

    #[test]
    fn a_pleiades_rpc_file_is_read_as_gdal_reads_it() {
        let r = parse(PHR).unwrap();
        // 1-based in the file (11470.5, 20000.5), GDAL's 11469.5 and 19999.5.
        assert_eq!((r.line_off, r.samp_off), (11469.5, 19999.5));
        assert_eq!((r.line_scale, r.samp_scale), (11469.5, 19999.5));
        assert_eq!(
            (r.lat_off, r.long_off),
            (43.67726387230638, 7.177448503675612)
        );
        assert_eq!((r.height_off, r.height_scale), (670.0, 630.0));
        assert_eq!((r.err_bias, r.err_rand), (-1.0, -1.0));
        // The inverse (ground → image) model, not the direct one.
        assert_eq!(r.line_num[0], -0.00185020904067451);
        assert_eq!(r.samp_num[1], 1.01161201549305);
        assert_eq!(r.samp_den[19], 5.92090135139572e-10);
        let s = parse(SPOT6).unwrap();
        assert_eq!((s.line_off, s.samp_off), (12387.5, 10975.5));
        assert_eq!(s.long_off, -72.26895693);
    }

    #[test]
    fn dimap_v3_takes_its_first_pixel_from_the_validity_domain() {
        let v3 = PHR
            .replace("Inverse_Model>", "GroundtoImage_Values>")
            .replace("Direct_Model>", "ImagetoGround_Values>")
            .replace(
                "<Direct_Model_Validity_Domain>\n          <FIRST_ROW>1</FIRST_ROW>\n          <FIRST_COL>1</FIRST_COL>",
                "<ImagetoGround_Validity_Domain>\n          <FIRST_ROW>0</FIRST_ROW>\n          <FIRST_COL>0</FIRST_COL>",
            )
            .replace("</Direct_Model_Validity_Domain>", "</ImagetoGround_Validity_Domain>");
        let r = parse(&v3).unwrap();
        assert_eq!((r.line_off, r.samp_off), (11470.5, 20000.5));
        assert_eq!(r.to_values()[12..], parse(PHR).unwrap().to_values()[12..]);
    }

    #[test]
    fn bad_dimap_files_are_refused_with_the_line_and_element_named() {
        let cases = [
            // A missing element.
            (
                PHR.replace("<LAT_SCALE>0.05909407003393596</LAT_SCALE>", ""),
                "<RFM_Validity> has no <LAT_SCALE>",
            ),
            (
                PHR.replace(
                    "<LINE_DEN_COEFF_7>2.87774922284592e-05</LINE_DEN_COEFF_7>",
                    "",
                ),
                "<Inverse_Model> has no <LINE_DEN_COEFF_7>",
            ),
            (
                PHR.replace("Inverse_Model>", "Other_Model>"),
                "no <Inverse_Model> (DIMAP v2) or <GroundtoImage_Values>",
            ),
            // A non-number.
            (
                PHR.replace("<HEIGHT_OFF>670</HEIGHT_OFF>", "<HEIGHT_OFF>670 m</HEIGHT_OFF>"),
                "line 201: <RFM_Validity>/<HEIGHT_OFF>: `670 m` is not a finite number",
            ),
            (
                PHR.replace(
                    "<SAMP_NUM_COEFF_2>1.01161201549305</SAMP_NUM_COEFF_2>",
                    "<SAMP_NUM_COEFF_2>NaN</SAMP_NUM_COEFF_2>",
                ),
                "line 101: <Inverse_Model>/<SAMP_NUM_COEFF_2>: `NaN` is not a finite number",
            ),
            // A number out of range, with the allowed range.
            (
                PHR.replace("<LONG_OFF>7.177448503675612</LONG_OFF>", "<LONG_OFF>717.7</LONG_OFF>"),
                "line 197 (<RFM_Validity>/<LONG_OFF>): LONG_OFF must be -180 … 360 (got 717.7)",
            ),
            (
                PHR.replace("<LINE_OFF>11470.5</LINE_OFF>", "<LINE_OFF>1e9</LINE_OFF>"),
                "(<RFM_Validity>/<LINE_OFF> less 1, DIMAP's first pixel): LINE_OFF must be -10000000 … 10000000",
            ),
            // Not the RPC file.
            (
                "<Dimap_Document><Metadata_Identification><METADATA_FORMAT version=\"2.0\">DIMAP</METADATA_FORMAT></Metadata_Identification></Dimap_Document>".into(),
                "DIMAP product document (DIM_*.XML); give the product's RPC_*.XML",
            ),
            (
                "<Dimap_Document><Metadata_Id><METADATA_FORMAT version=\"1.1\">DIMAP</METADATA_FORMAT></Metadata_Id></Dimap_Document>".into(),
                "DIMAP v1.1 (SPOT 1–5) carries a physical sensor model and no RPCs",
            ),
            ("<isd><RPB/></isd>".into(), "give the .RPB file"),
            (PHR.replace("</Dimap_Document>", ""), "not well-formed XML"),
        ];
        for (text, want) in cases {
            let e = parse(&text).unwrap_err();
            assert!(
                e.starts_with("RPC_x.XML: ") && e.contains(want),
                "{e}\nwanted: {want}"
            );
        }
    }
}
