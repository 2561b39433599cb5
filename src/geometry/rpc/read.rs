//! One entry point for RPC00B models as vendors and tools write them: [`Rpc::read`].
//!
//! | form | who writes it | reader |
//! |---|---|---|
//! | `_RPC.TXT` / `_rpc.txt` (`KEY: value`, units allowed after the number) | GDAL, GeoEye, IKONOS, Planet | [`Rpc::parse_txt`] |
//! | TIFF RPCCoefficientTag (50844) | GDAL, crop tools | [`Rpc::read_tiff_tag`] |
//! | `.RPB` (`BEGIN_GROUP = IMAGE … lineOffset = …;`) | DigitalGlobe/Maxar | [`Rpc::parse_rpb`] |
//! | `RPC_*.XML` (DIMAP v2 `<Global_RFM>`, v3 `<GroundtoImage_Values>`) | Airbus: Pléiades, SPOT 6/7, Pléiades Neo | [`Rpc::parse_dimap`] |
//!
//! Whatever the form, the [`Rpc`] read has RPC00B's image coordinates: (sample, line) =
//! (0, 0) at the centre of the top-left pixel (NITF STDI-0002 RPC00B; GDAL's RPC
//! documentation, RFC 22). DIMAP v2 counts from 1 at that centre, so its LINE_OFF and
//! SAMP_OFF come out one less, as GDAL reads them. GDAL's own pixel/line (what
//! `gdaltransform -rpc` prints and takes) put 0 at the top-left corner of the image: GDAL
//! pixel = RPC sample + 0.5, GDAL line = RPC line + 0.5, which is also the core's
//! continuous pixel ([`super::RpcSensor`]).

use super::{Rpc, RpcError, ARRAYS, SCALARS, TIFF_TAG};
use std::io::Read;
use std::path::{Path, PathBuf};

/// Larger than any RPC text file by far: a bigger file is not one.
const MAX_TEXT_BYTES: u64 = 16 << 20;

/// The 92 numbers of a model being read, each with where it was found, so that a number
/// [`Rpc::check`] refuses is named by its place in the file as well as by its key.
pub(super) struct Slots {
    values: Vec<Option<f64>>,
    places: Vec<String>,
}

impl Slots {
    pub(super) fn new() -> Slots {
        Slots {
            values: vec![None; 92],
            places: vec![String::new(); 92],
        }
    }

    /// Slot `i` of [`Rpc::to_values`]'s order, found at `place` ("line 7 (IMAGE.lineOffset)").
    pub(super) fn set(&mut self, i: usize, x: f64, place: String) {
        self.values[i] = Some(x);
        self.places[i] = place;
    }

    /// The model, checked: ERR_BIAS and ERR_RAND default to −1 (unknown); every other number
    /// must have been set; a number out of its range is named with its place.
    pub(super) fn finish(self, path: &Path) -> Result<Rpc, RpcError> {
        let fail = |message: String| RpcError::File {
            path: path.display().to_string(),
            message,
        };
        let mut v = Vec::with_capacity(92);
        for (i, x) in self.values.iter().enumerate() {
            match (x, i) {
                (Some(x), _) => v.push(*x),
                (None, 0 | 1) => v.push(-1.0),
                (None, _) => return Err(fail(format!("{} is missing", key_name(i)))),
            }
        }
        Rpc::from_values(&v).map_err(|e| {
            let msg = e.to_string();
            // Rpc::check's messages begin with the key (`LAT_OFF must be …`).
            let key = msg.split_whitespace().next().unwrap_or("");
            match (0..92).find(|i| key_name(*i) == key) {
                Some(i) if !self.places[i].is_empty() => fail(format!("{}: {msg}", self.places[i])),
                _ => fail(msg),
            }
        })
    }
}

/// GDAL's name of slot `i` (`LINE_OFF`, `SAMP_DEN_COEFF_20`).
fn key_name(i: usize) -> String {
    if i < 12 {
        SCALARS[i].to_string()
    } else {
        format!("{}_{}", ARRAYS[(i - 12) / 20], (i - 12) % 20 + 1)
    }
}

/// The text of an RPC file: UTF-8, or else ISO-8859-1 (which some DIMAP files declare), a
/// leading byte-order mark dropped.
pub(super) fn text_of(bytes: Vec<u8>) -> String {
    let text = match String::from_utf8(bytes) {
        Ok(s) => s,
        Err(e) => e.into_bytes().iter().map(|b| char::from(*b)).collect(),
    };
    match text.strip_prefix('\u{feff}') {
        Some(t) => t.to_string(),
        None => text,
    }
}

fn is_tiff(magic: &[u8]) -> bool {
    matches!(magic, [b'I', b'I', 42 | 43, 0] | [b'M', b'M', 0, 42 | 43])
}

fn ext_is(path: &Path, ext: &str) -> bool {
    path.extension()
        .is_some_and(|e| e.to_string_lossy().eq_ignore_ascii_case(ext))
}

/// `path`'s name, with `suffix` in place of its extension (`a.tif`, `_RPC.TXT` →
/// `a_RPC.TXT`).
fn sibling(path: &Path, suffix: &str) -> PathBuf {
    let stem = path
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_default();
    path.with_file_name(format!("{stem}{suffix}"))
}

/// The RPC files GDAL looks for beside an image, in its order: the DigitalGlobe `.RPB`, the
/// `_RPC.TXT`, and for an Airbus tile `IMG_<id>_R1C1.TIF` the product's `RPC_<id>.XML`.
fn beside(image: &Path) -> Vec<PathBuf> {
    let mut out = vec![
        sibling(image, ".RPB"),
        sibling(image, ".rpb"),
        sibling(image, "_RPC.TXT"),
        sibling(image, "_rpc.txt"),
    ];
    let stem = image
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_default();
    if stem.len() > 4 && stem[..4].eq_ignore_ascii_case("IMG_") {
        let rest = &stem[4..];
        out.push(image.with_file_name(format!("RPC_{rest}.XML")));
        if let Some((id, _tile)) = rest.rsplit_once('_') {
            out.push(image.with_file_name(format!("RPC_{id}.XML")));
        }
    }
    out
}

/// The Airbus tile an image name stands for (`IMG_<id>_R2C1.TIF` → (2, 1)).
fn dimap_tile(image: &Path) -> Option<(u32, u32)> {
    let stem = image.file_stem()?.to_string_lossy().to_ascii_uppercase();
    let (_, tile) = stem.strip_prefix("IMG_")?.rsplit_once('_')?;
    let (r, c) = tile.strip_prefix('R')?.split_once('C')?;
    Some((r.parse().ok()?, c.parse().ok()?))
}

impl Rpc {
    /// Reads an RPC00B model from any of the forms in the module's table, chosen by the
    /// file's content (and its name where the content leaves it open); every number is
    /// checked with the file, its line or element, and its allowed range named. A TIFF is
    /// read for its RPC tag, or else for the RPC file GDAL would take beside it.
    pub fn read(path: &Path) -> Result<Rpc, RpcError> {
        let fail = |message: String| RpcError::File {
            path: path.display().to_string(),
            message,
        };
        let mut f = std::fs::File::open(path).map_err(|e| {
            fail(format!(
                "cannot read it: {e} (give an _RPC.TXT, .RPB, RPC_*.XML or a TIFF with the RPC tag)"
            ))
        })?;
        let mut magic = [0u8; 4];
        let n = f
            .read(&mut magic)
            .map_err(|e| fail(format!("cannot read it: {e}")))?;
        if is_tiff(&magic[..n]) {
            return Rpc::read_tiff(path);
        }
        let size = f.metadata().map(|m| m.len()).unwrap_or(0);
        if size > MAX_TEXT_BYTES {
            return Err(fail(format!(
                "{size} bytes is no RPC file (an _RPC.TXT, .RPB or RPC_*.XML is a few kilobytes): is it the image? Give its RPC file"
            )));
        }
        let mut bytes = magic[..n].to_vec();
        f.read_to_end(&mut bytes)
            .map_err(|e| fail(format!("cannot read it: {e}")))?;
        let text = text_of(bytes);
        let head = text.trim_start();
        if head.starts_with('<') || ext_is(path, "xml") {
            let name = path
                .file_name()
                .map(|n| n.to_string_lossy().into_owned())
                .unwrap_or_default();
            // A DIMAP product's DIM_<id>.XML: its RPCs are in RPC_<id>.XML beside it.
            if name.len() > 4 && name[..4].eq_ignore_ascii_case("DIM_") {
                let rpc = path.with_file_name(format!("RPC_{}", &name[4..]));
                if rpc.exists() && !head.contains("Global_RFM") {
                    return Rpc::read(&rpc);
                }
            }
            return Rpc::parse_dimap(&text, path);
        }
        let words = |w: &str| head.contains(w);
        if words("BEGIN_GROUP") || words("lineOffset") || ext_is(path, "rpb") {
            return Rpc::parse_rpb(&text, path);
        }
        if words("LINE_OFF") || words("LINE_NUM_COEFF") || ext_is(path, "txt") {
            return Rpc::parse_txt(&text, path);
        }
        Err(fail(
            "not an RPC file: give GDAL's _RPC.TXT (LINE_OFF: …), a DigitalGlobe .RPB (BEGIN_GROUP = IMAGE …), an Airbus DIMAP RPC_*.XML, or a TIFF with the RPC tag (50844)".into(),
        ))
    }

    /// A TIFF's RPCs: its tag, or else the first RPC file GDAL would find beside it.
    fn read_tiff(image: &Path) -> Result<Rpc, RpcError> {
        let tagged = Rpc::read_tiff_tag(image);
        let missing = match &tagged {
            Err(RpcError::File { message, .. }) => message.contains("has no RPC tag"),
            _ => false,
        };
        if !missing {
            return tagged;
        }
        let candidates = beside(image);
        let Some(found) = candidates.iter().find(|p| p.is_file()) else {
            let names: Vec<String> = candidates
                .iter()
                .map(|p| {
                    p.file_name()
                        .map(|n| n.to_string_lossy().into_owned())
                        .unwrap_or_default()
                })
                .collect();
            return Err(RpcError::File {
                path: image.display().to_string(),
                message: format!(
                    "it has no RPC tag ({TIFF_TAG}, RPCCoefficientTag) and no RPC file beside it (looked for {}): give its RPC file as rpc = \"…\"",
                    names.join(", ")
                ),
            });
        };
        let is_dimap = found
            .extension()
            .is_some_and(|e| e.eq_ignore_ascii_case("xml"));
        if let (true, Some((r, c))) = (is_dimap, dimap_tile(image)) {
            if (r, c) != (1, 1) {
                return Err(RpcError::File {
                    path: image.display().to_string(),
                    message: format!(
                        "tile R{r}C{c} of a tiled DIMAP product: {} describes the whole product from tile R1C1's corner; open the product as one image (its DIM_*.XML through gdal_translate or gdalbuildvrt) and give that",
                        found.display()
                    ),
                });
            }
        }
        Rpc::read(found)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn data(name: &str) -> PathBuf {
        Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("tests/data/rpc")
            .join(name)
    }

    #[test]
    fn each_form_is_read_from_its_content() {
        for (name, lat_off) in [
            ("md_dg.RPB", 41.8791),
            ("md_ge_rgb_0010000_rpc.txt", 48.8772),
            ("rpc_IKONOS.txt", -34.903),
            (
                "RPC_PHR1B_P_201709281038393_SEN_PRG_FC_178609-001.XML",
                43.67726387230638,
            ),
            ("rpc_SPOT6.xml", 18.57519833),
        ] {
            let r = Rpc::read(&data(name)).unwrap_or_else(|e| panic!("{name}: {e}"));
            assert_eq!(r.lat_off, lat_off, "{name}");
        }
        // The same content under names that say nothing.
        let d = tempfile::tempdir().unwrap();
        for name in ["md_dg.RPB", "rpc_IKONOS.txt", "rpc_SPOT6.xml"] {
            let p = d.path().join(format!("{name}.model"));
            std::fs::copy(data(name), &p).unwrap();
            assert_eq!(Rpc::read(&p).unwrap(), Rpc::read(&data(name)).unwrap());
        }
    }

    /// A 4 × 4 grey TIFF, with the RPC tag when given (the core's tests write their own: the
    /// scans' writer belongs to the hardware side).
    fn write_tiff(path: &std::path::Path, px: &[u16], rpc: Option<&[f64]>) {
        use tiff::encoder::{colortype, TiffEncoder};
        let mut enc = TiffEncoder::new(std::fs::File::create(path).unwrap()).unwrap();
        let mut image = enc.new_image::<colortype::Gray16>(4, 4).unwrap();
        if let Some(v) = rpc {
            image
                .encoder()
                .write_tag(tiff::tags::Tag::Unknown(TIFF_TAG), v)
                .unwrap();
        }
        image.write_data(px).unwrap();
    }

    #[test]
    fn a_tiff_is_read_for_its_tag_or_the_rpc_file_gdal_finds_beside_it() {
        let d = tempfile::tempdir().unwrap();
        let px = vec![0u16; 4 * 4];
        let want = Rpc::read(&data("md_dg.RPB")).unwrap();
        // The tag.
        let tagged = d.path().join("tagged.tif");
        write_tiff(&tagged, &px, Some(&want.to_values()));
        assert_eq!(Rpc::read(&tagged).unwrap(), want);
        // Nothing: the tag and the files looked for are named.
        let plain = d.path().join("IMG_P_R1C1.tif");
        write_tiff(&plain, &px, None);
        let e = Rpc::read(&plain).unwrap_err().to_string();
        assert!(
            e.contains("no RPC tag (50844")
                && e.contains("IMG_P_R1C1.RPB")
                && e.contains("IMG_P_R1C1_RPC.TXT")
                && e.contains("RPC_P.XML"),
            "{e}"
        );
        // An RPB, an _rpc.txt and an Airbus RPC_<id>.XML beside the image.
        std::fs::copy(data("rpc_SPOT6.xml"), d.path().join("RPC_P.XML")).unwrap();
        assert_eq!(
            Rpc::read(&plain).unwrap(),
            Rpc::read(&data("rpc_SPOT6.xml")).unwrap()
        );
        std::fs::copy(data("rpc_IKONOS.txt"), d.path().join("IMG_P_R1C1_rpc.txt")).unwrap();
        assert_eq!(
            Rpc::read(&plain).unwrap(),
            Rpc::read(&data("rpc_IKONOS.txt")).unwrap()
        );
        std::fs::copy(data("md_dg.RPB"), d.path().join("IMG_P_R1C1.RPB")).unwrap();
        assert_eq!(Rpc::read(&plain).unwrap(), want);
        // Another tile of a tiled product is refused: its offsets would be the product's.
        let tile = d.path().join("IMG_P_R2C1.tif");
        write_tiff(&tile, &px, None);
        let e = Rpc::read(&tile).unwrap_err().to_string();
        assert!(e.contains("tile R2C1") && e.contains("RPC_P.XML"), "{e}");
    }

    #[test]
    fn a_dimap_product_document_leads_to_its_rpc_file() {
        let d = tempfile::tempdir().unwrap();
        let dim = d.path().join("DIM_X.XML");
        std::fs::write(
            &dim,
            "<Dimap_Document><Metadata_Identification><METADATA_FORMAT version=\"2.0\">DIMAP</METADATA_FORMAT></Metadata_Identification><Raster_Data/></Dimap_Document>",
        )
        .unwrap();
        let e = Rpc::read(&dim).unwrap_err().to_string();
        assert!(e.contains("DIM_X.XML") && e.contains("RPC_"), "{e}");
        std::fs::copy(data("rpc_SPOT6.xml"), d.path().join("RPC_X.XML")).unwrap();
        assert_eq!(
            Rpc::read(&dim).unwrap(),
            Rpc::read(&data("rpc_SPOT6.xml")).unwrap()
        );
    }

    #[test]
    fn what_is_no_rpc_file_is_refused_with_what_to_give() {
        let d = tempfile::tempdir().unwrap();
        let p = d.path().join("notes.dat");
        std::fs::write(&p, "hello\n").unwrap();
        let e = Rpc::read(&p).unwrap_err().to_string();
        assert!(
            e.contains("notes.dat") && e.contains(".RPB") && e.contains("_RPC.TXT"),
            "{e}"
        );
        let e = Rpc::read(&d.path().join("absent.RPB"))
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("absent.RPB") && e.contains("cannot read it"),
            "{e}"
        );
    }

    #[test]
    fn latin1_text_is_read() {
        assert_eq!(text_of(vec![b'a', 0xe9, b'b']), "aéb");
        assert_eq!(text_of("\u{feff}x".as_bytes().to_vec()), "x");
    }
}
