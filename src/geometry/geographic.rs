//! The project's ground CRS against WGS 84 longitude, latitude and height (EPSG:4979), as
//! RPCs are written (RPC00B: geodetic longitude and latitude in degrees, height above the
//! ellipsoid in metres). The project's Z is taken as the ellipsoidal height: the rig applies
//! no geoid (a project in orthometric heights gets RPCs offset by the geoid's undulation,
//! a constant over a scene, which a bias correction absorbs).
//!
//! Map projections are not our field: `proj4rs` (a Rust port of proj4js) with the EPSG
//! definitions of `crs-definitions`; checked against GDAL's `gdaltransform` in the tests.

use super::Crs;
use crate::coords::GroundM;
use proj4rs::Proj;

#[derive(Debug, thiserror::Error)]
pub enum GeographicError {
    #[error("the project's CRS is `local`: RPCs need longitude and latitude; give the project an EPSG projected CRS (crs = \"EPSG:N\")")]
    Local,
    #[error("EPSG:{0} is not in the rig's table of projections")]
    Unknown(u16),
    #[error("EPSG:{code}: {message}")]
    Projection { code: u16, message: String },
    #[error("({x}, {y}) cannot be converted between EPSG:{code} and WGS 84: {message}")]
    Point {
        code: u16,
        x: f64,
        y: f64,
        message: String,
    },
}

/// WGS 84 longitude and latitude in degrees, ellipsoidal height in metres.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LonLatH {
    pub lon: f64,
    pub lat: f64,
    pub h: f64,
}

/// Converts between one projected CRS and WGS 84 geographic coordinates.
#[derive(Clone)]
pub struct Geographic {
    code: u16,
    projected: Proj,
    wgs84: Proj,
}

impl std::fmt::Debug for Geographic {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "Geographic(EPSG:{})", self.code)
    }
}

impl Geographic {
    pub fn new(crs: Crs) -> Result<Geographic, GeographicError> {
        let Crs::Epsg(code) = crs else {
            return Err(GeographicError::Local);
        };
        let projected = Proj::from_epsg_code(code).map_err(|e| match e {
            proj4rs::errors::Error::ProjectionNotFound => GeographicError::Unknown(code),
            e => GeographicError::Projection {
                code,
                message: e.to_string(),
            },
        })?;
        let wgs84 = Proj::from_proj_string("+proj=longlat +datum=WGS84 +no_defs").map_err(|e| {
            GeographicError::Projection {
                code,
                message: e.to_string(),
            }
        })?;
        Ok(Geographic {
            code,
            projected,
            wgs84,
        })
    }

    pub fn crs(&self) -> Crs {
        Crs::Epsg(self.code)
    }

    pub fn to_lonlat(&self, g: GroundM) -> Result<LonLatH, GeographicError> {
        let mut p = (g.x, g.y, g.z);
        proj4rs::transform::transform(&self.projected, &self.wgs84, &mut p)
            .map_err(|e| self.fail(g.x, g.y, e))?;
        // The height is carried through as it is (see the module's note): a datum shift
        // through geocentric coordinates would otherwise change it by metres.
        let out = LonLatH {
            lon: p.0.to_degrees(),
            lat: p.1.to_degrees(),
            h: g.z,
        };
        if [out.lon, out.lat, out.h].iter().all(|v| v.is_finite()) {
            Ok(out)
        } else {
            Err(self.fail(g.x, g.y, "not finite"))
        }
    }

    pub fn to_ground(&self, l: LonLatH) -> Result<GroundM, GeographicError> {
        let mut p = (l.lon.to_radians(), l.lat.to_radians(), l.h);
        proj4rs::transform::transform(&self.wgs84, &self.projected, &mut p)
            .map_err(|e| self.fail(l.lon, l.lat, e))?;
        if [p.0, p.1, l.h].iter().all(|v| v.is_finite()) {
            Ok(GroundM::new(p.0, p.1, l.h))
        } else {
            Err(self.fail(l.lon, l.lat, "not finite"))
        }
    }

    fn fail(&self, x: f64, y: f64, e: impl std::fmt::Display) -> GeographicError {
        GeographicError::Point {
            code: self.code,
            x,
            y,
            message: e.to_string(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Against GDAL 3 (`echo 746800 4055840 500 | gdaltransform -s_srs EPSG:32616
    /// -t_srs EPSG:4979`: −84.2403420802905 36.6161621133881 500), and back.
    #[test]
    fn utm_to_wgs84_agrees_with_gdal_and_round_trips() {
        let g = Geographic::new(Crs::Epsg(32616)).unwrap();
        let l = g
            .to_lonlat(GroundM::new(746_800.0, 4_055_840.0, 500.0))
            .unwrap();
        assert!((l.lon - -84.240_342_080_290_5).abs() < 1e-10, "{l:?}");
        assert!((l.lat - 36.616_162_113_388_1).abs() < 1e-10, "{l:?}");
        assert_eq!(l.h, 500.0);
        let back = g.to_ground(l).unwrap();
        assert!((back.x - 746_800.0).abs() < 1e-6 && (back.y - 4_055_840.0).abs() < 1e-6);
    }

    #[test]
    fn a_local_crs_is_refused_with_what_to_do() {
        let e = Geographic::new(Crs::Local).unwrap_err().to_string();
        assert!(e.contains("EPSG"), "{e}");
    }
}
