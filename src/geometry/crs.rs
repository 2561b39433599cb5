//! The ground coordinate system of a project, as written into every output: an EPSG projected
//! CRS (metres; a DEM grid's cells are square metres, so geographic systems do not apply), or
//! `local` for a project's own metric system that no GIS can place.

use serde::{Deserialize, Serialize};

#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(try_from = "String", into = "String")]
pub enum Crs {
    /// A local metric system (GeoTIFF: user-defined projected system in metres).
    #[default]
    Local,
    /// An EPSG projected system, e.g. 32617 (WGS 84 / UTM zone 17N).
    Epsg(u16),
}

/// EPSG codes a GeoTIFF ProjectedCSTypeGeoKey can carry (32767 means user-defined).
pub const EPSG_RANGE: std::ops::RangeInclusive<u16> = 1024..=32766;
/// EPSG's geographic systems (degrees), refused: 4000–4999.
const GEOGRAPHIC: std::ops::RangeInclusive<u16> = 4000..=4999;

impl std::str::FromStr for Crs {
    type Err = String;
    fn from_str(s: &str) -> Result<Crs, String> {
        let t = s.trim();
        if t.eq_ignore_ascii_case("local") {
            return Ok(Crs::Local);
        }
        let code = t
            .strip_prefix("EPSG:")
            .or_else(|| t.strip_prefix("epsg:"))
            .and_then(|c| c.parse::<u16>().ok())
            .filter(|c| EPSG_RANGE.contains(c) && !GEOGRAPHIC.contains(c));
        code.map(Crs::Epsg).ok_or_else(|| {
            format!(
                "`{s}`: give \"EPSG:N\" for a projected system in metres (N from {} to {}, not a geographic one in degrees), or \"local\"",
                EPSG_RANGE.start(),
                EPSG_RANGE.end()
            )
        })
    }
}

impl TryFrom<String> for Crs {
    type Error = String;
    fn try_from(s: String) -> Result<Crs, String> {
        s.parse()
    }
}

impl From<Crs> for String {
    fn from(c: Crs) -> String {
        c.to_string()
    }
}

impl std::fmt::Display for Crs {
    fn fmt(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
        match self {
            Crs::Local => write!(f, "local"),
            Crs::Epsg(c) => write!(f, "EPSG:{c}"),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::Crs;

    #[test]
    fn parses_epsg_and_local_and_refuses_the_rest() {
        assert_eq!("EPSG:26915".parse::<Crs>(), Ok(Crs::Epsg(26915)));
        assert_eq!(" local ".parse::<Crs>(), Ok(Crs::Local));
        for bad in [
            "EPSG:4326x",
            "EPSG:4326",
            "EPSG:99999",
            "EPSG:0",
            "UTM 17",
            "",
        ] {
            assert!(bad.parse::<Crs>().is_err(), "{bad}");
        }
        assert_eq!(Crs::Epsg(32617).to_string(), "EPSG:32617");
    }
}
