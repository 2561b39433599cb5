use super::*;
use crate::geometry::pushbroom::fixtures::spot_like;
use crate::geometry::Crs;

fn geo() -> Geographic {
    Geographic::new(Crs::Epsg(32616)).unwrap()
}

/// Goal of the issue: RPCs fitted to the rigorous model within 0.01 px RMS and 0.05 px at
/// most, over the scene and the height range, at points that were not fitted (a pseudo-random
/// scatter, besides the fit's own check grid).
#[test]
fn rpcs_fitted_to_a_pushbroom_reproduce_it_to_a_hundredth_of_a_pixel() {
    for tilt in [0.0, 27.0, -27.0] {
        let s = spot_like(tilt);
        s.check().unwrap();
        let g = geo();
        let heights = [-50.0, 2500.0];
        let (rpc, report) = fit_rpc(&s, &g, heights, FitGrid::default()).unwrap();
        assert!(report.check_rms_px <= 0.01, "tilt {tilt}: {report:?}");
        assert!(report.check_max_px <= 0.05, "tilt {tilt}: {report:?}");
        let sensor = RpcSensor {
            rpc,
            geo: g,
            width: 3000,
            height: 3000,
        };
        let mut worst: f64 = 0.0;
        // A low-discrepancy scatter (the plastic number's additive recurrence).
        let frac = |v: f64| v - v.floor();
        for i in 0..500 {
            let i = i as f64;
            let q = PixelXY::new(
                frac(0.5 + i * 0.754_877_7) * 3000.0,
                frac(0.5 + i * 0.569_840_3) * 3000.0,
            );
            let z = heights[0] + frac(i * 0.618_034) * (heights[1] - heights[0]);
            let ground = s.image_to_ground(q, z).unwrap();
            worst = worst.max(sensor.ground_to_image(ground).unwrap().dist(q));
            // And the RPC's own inverse lands on the rigorous ground point.
            let back = sensor.image_to_ground(q, z).unwrap();
            let d = (back.x - ground.x).hypot(back.y - ground.y);
            assert!(d < 0.5, "tilt {tilt}: {q:?} at {z:.0} m: {d:.3} m off");
        }
        eprintln!("tilt {tilt}°: {report:?}; 500 scattered points: worst {worst:.2e} px");
        assert!(worst <= 0.05, "tilt {tilt}: worst {worst:.4} px");
    }
}

#[test]
fn the_text_form_round_trips_exactly_and_names_what_is_wrong() {
    let (rpc, _) = fit_rpc(
        &spot_like(10.0),
        &geo(),
        [0.0, 1000.0],
        FitGrid { n: 9, layers: 4 },
    )
    .unwrap();
    let p = Path::new("photo_RPC.TXT");
    let text = rpc.to_txt();
    assert_eq!(Rpc::parse_txt(&text, p).unwrap(), rpc);
    assert_eq!(Rpc::from_values(&rpc.to_values()).unwrap(), rpc);
    // Units after the numbers (as vendors write them) and the one-line coefficient form.
    let mut vendor = String::new();
    for line in text.lines() {
        if line.starts_with("LINE_OFF") || line.starts_with("SAMP_OFF") {
            vendor.push_str(&format!("{line} pixels\n"));
        } else if !line.starts_with("LINE_NUM_COEFF") {
            vendor.push_str(line);
            vendor.push('\n');
        }
    }
    let coeffs: Vec<String> = rpc.line_num.iter().map(|c| format!("{c:e}")).collect();
    vendor.push_str(&format!("LINE_NUM_COEFF: {}\n", coeffs.join(" ")));
    assert_eq!(Rpc::parse_txt(&vendor, p).unwrap(), rpc);
    let err = |t: String| Rpc::parse_txt(&t, p).unwrap_err().to_string();
    let e = err(text.replace("LAT_SCALE", "LAT_SCALEX"));
    assert!(
        e.contains("LAT_SCALE is missing") && e.contains("photo_RPC.TXT"),
        "{e}"
    );
    let off = text.lines().find(|l| l.starts_with("LINE_OFF")).unwrap();
    let e = err(text.replacen(off, "LINE_OFF: nan", 1));
    assert!(e.contains("line 3") && e.contains("LINE_OFF"), "{e}");
    let e = err(text.replacen(off, "LINE_OFF: inf", 1));
    assert!(e.contains("line 3") && e.contains("LINE_OFF"), "{e}");
    let e = err(format!("{text}LAT_OFF: 10\n"));
    assert!(e.contains("twice"), "{e}");
    let e = err(text.replace("SAMP_NUM_COEFF_20", "SAMP_NUM_COEFF_21"));
    assert!(e.contains("1 … 20"), "{e}");
    let mut bad = rpc.clone();
    bad.lat_off = 91.0;
    assert!(err(bad.to_txt()).contains("LAT_OFF must be"));
    let mut bad = rpc.clone();
    bad.err_bias = 1e150;
    assert!(err(bad.to_txt()).contains("ERR_BIAS must be"));
    let mut bad = rpc.clone();
    bad.samp_scale = 0.0;
    assert!(err(bad.to_txt()).contains("SAMP_SCALE must be"));
    assert!(Rpc::from_values(&[0.0; 91]).is_err());
    assert_eq!(
        Rpc::txt_path(Path::new("/a/b/photo-1.tif")),
        Path::new("/a/b/photo-1_RPC.TXT")
    );
}

/// A model with a closed form: line = P·scale + off, sample = L·scale + off; the core's
/// pixel is half a pixel further (corner origin), and the stated errors reach pixels
/// through the ground pixel.
#[test]
fn a_linear_rpc_has_its_closed_form_and_its_stated_error() {
    let mut num_l = [0.0; 20];
    num_l[2] = -1.0; // line grows southwards
    let mut num_s = [0.0; 20];
    num_s[1] = 1.0;
    let mut den = [0.0; 20];
    den[0] = 1.0;
    let rpc = Rpc {
        err_bias: 3.0,
        err_rand: 4.0,
        line_off: 500.0,
        samp_off: 400.0,
        lat_off: 36.6,
        long_off: -84.2,
        height_off: 0.0,
        line_scale: 500.0,
        samp_scale: 400.0,
        lat_scale: 0.05,
        long_scale: 0.04,
        height_scale: 1000.0,
        line_num: num_l,
        line_den: den,
        samp_num: num_s,
        samp_den: den,
    };
    rpc.check().unwrap();
    let (s, l) = rpc
        .project(LonLatH {
            lon: -84.19,
            lat: 36.61,
            h: 0.0,
        })
        .unwrap();
    assert!((s - (400.0 + 0.25 * 400.0)).abs() < 1e-9 && (l - (500.0 - 0.2 * 500.0)).abs() < 1e-9);
    let back = rpc.locate(s, l, 0.0).unwrap();
    assert!((back.lon - -84.19).abs() < 1e-12 && (back.lat - 36.61).abs() < 1e-12);
    let sensor = RpcSensor {
        rpc,
        geo: geo(),
        width: 800,
        height: 1000,
    };
    let g = sensor
        .geo
        .to_ground(LonLatH {
            lon: -84.19,
            lat: 36.61,
            h: 0.0,
        })
        .unwrap();
    let q = sensor.ground_to_image(g).unwrap();
    assert!((q.col - (s + 0.5)).abs() < 1e-6 && (q.row - (l + 0.5)).abs() < 1e-6);
    // σ² = 3² + 4² = 25 m² per axis; the sample axis: 400 px per 0.04° of longitude.
    let c = sensor.pointing_covariance(g).unwrap();
    let m_per_deg_lon = 111_320.0 * 36.61f64.to_radians().cos();
    let px_per_m = 400.0 / 0.04 / m_per_deg_lon;
    let want = 25.0 * px_per_m * px_per_m;
    assert!((c[0][0] / want - 1.0).abs() < 0.01, "{} vs {want}", c[0][0]);
}

/// An image larger than the one the RPCs were made for is refused; the image itself passes.
#[test]
fn an_image_beyond_its_rpcs_domain_is_refused() {
    let s = spot_like(0.0);
    let (rpc, _) = fit_rpc(&s, &geo(), [0.0, 1000.0], FitGrid::default()).unwrap();
    let mut sensor = RpcSensor {
        rpc,
        geo: geo(),
        width: 3000,
        height: 3000,
    };
    sensor.check_extent().unwrap();
    sensor.width = 6000;
    let e = sensor.check_extent().unwrap_err();
    assert!(
        e.contains("6000 × 3000") && e.contains("top-right corner"),
        "{e}"
    );
}

/// A WorldView-3-like model: 0.31 m pixels, a 40 000 × 40 000 px scene centred at
/// (`lon`, `lat`), viewed 20° off nadir across the columns (0.36 m of image shift per metre of
/// height), with small quadratic and cubic terms and a non-constant denominator as vendors'
/// models have. Sample grows east, line south.
fn worldview_like(lon: f64, lat: f64) -> Rpc {
    let half_m = 20_000.0 * 0.31;
    let lat_scale = half_m / 111_320.0;
    let long_scale = half_m / (111_320.0 * lat.to_radians().cos());
    let mut samp_num = [0.0; 20];
    let mut line_num = [0.0; 20];
    let mut den = [0.0; 20];
    samp_num[1] = 1.0; // L
    samp_num[3] = 0.36 * 500.0 / 0.31 / 20_000.0; // H: parallax of the off-nadir view
    samp_num[2] = 0.01; // a little rotation
    samp_num[7] = 2e-4; // L²
    samp_num[11] = -3e-5; // L³
    line_num[2] = -1.0; // −P: lines run south
    line_num[1] = 0.012;
    line_num[8] = 1.5e-4; // P²
    line_num[10] = 2e-5; // PLH
    den[0] = 1.0;
    den[1] = 1e-4;
    den[2] = -2e-4;
    den[3] = 5e-5;
    Rpc {
        err_bias: -1.0,
        err_rand: -1.0,
        line_off: 20_000.0,
        samp_off: 20_000.0,
        lat_off: lat,
        long_off: lon,
        height_off: 500.0,
        line_scale: 20_000.0,
        samp_scale: 20_000.0,
        lat_scale,
        long_scale,
        height_scale: 500.0,
        line_num,
        line_den: den,
        samp_num,
        samp_den: den,
    }
}

/// Where the image → ground iteration must converge: WorldView-3's 0.31 m pixels on the
/// equator, across the antimeridian (±180°), at ±80° latitude and both at once. There one
/// unit in the last place of a longitude is up to 1.8e-9 px, so a fixed 1e-9 px cannot be
/// reached; the test of [`Convergence`] takes the coordinates' resolution.
const PLACES: [(f64, f64); 7] = [
    (55.3, 25.2),
    (179.97, 0.0),
    (-179.97, -12.0),
    (12.0, 80.0),
    (-70.0, -80.0),
    (179.99, 79.9),
    (-179.99, -79.9),
];

#[test]
fn ground_from_image_converges_at_0_31_m_pixels_anywhere_on_earth() {
    for (lon, lat) in PLACES {
        let rpc = worldview_like(lon, lat);
        rpc.check().unwrap();
        let mut worst: f64 = 0.0;
        let mut floor: f64 = 0.0;
        for i in 0..=10 {
            for j in 0..=10 {
                for h in [0.0, 500.0, 1000.0] {
                    let (s, l) = (i as f64 * 4000.0 - 0.5, j as f64 * 4000.0 - 0.5);
                    let g = rpc
                        .locate(s, l, h)
                        .unwrap_or_else(|e| panic!("({lon}, {lat}): ({s}, {l}) at {h} m: {e}"));
                    let (s2, l2) = rpc.project(g).unwrap();
                    worst = worst.max((s2 - s).hypot(l2 - l));
                    // One unit in the last place of the longitude, in pixels.
                    let px_per_deg = rpc.samp_scale / rpc.long_scale;
                    floor = floor.max(crate::geometry::convergence::ulp(g.lon) * px_per_deg);
                }
            }
        }
        eprintln!("({lon}°, {lat}°): round trip within {worst:.1e} px; a longitude resolves {floor:.1e} px");
        assert!(worst < 1e-7, "({lon}, {lat}): {worst:e} px");
    }
}

proptest::proptest! {
    #![proptest_config(proptest::prelude::ProptestConfig { cases: 400, failure_persistence: None, .. Default::default() })]

    /// Image → ground → image returns to the pixel, for any pixel of the scene, any height
    /// in the model's range and any of the places above.
    #[test]
    fn image_to_ground_to_image_round_trips(
        place in 0usize..PLACES.len(),
        s in -0.5f64..39_999.5,
        l in -0.5f64..39_999.5,
        h in 0.0f64..1000.0,
    ) {
        let (lon, lat) = PLACES[place];
        let rpc = worldview_like(lon, lat);
        let g = rpc.locate(s, l, h);
        proptest::prop_assert!(g.is_ok(), "({}, {}) at {} m: {:?}", s, l, h, g);
        let g = g.unwrap();
        proptest::prop_assert!(g.lon >= -180.0 && g.lon <= 180.0 && g.lat.abs() <= 90.0);
        let (s2, l2) = rpc.project(g).unwrap();
        proptest::prop_assert!((s2 - s).hypot(l2 - l) < 1e-6, "({}, {}) → ({}, {})", s, l, s2, l2);
    }
}

/// A crop tool's RPCs keep the product's LINE_OFF and SAMP_OFF and fold the crop's corner
/// into the numerators (sample − c₀ = (N − c₀/scale · D)/D · scale + off): the crop passes the
/// domain check, which an image that the model does not cover fails, naming the corner.
#[test]
fn a_crop_with_the_products_offsets_passes_and_an_image_beyond_the_model_does_not() {
    let product = worldview_like(55.3, 25.2);
    let (c0, r0) = (19_488.0, 18_892.0);
    let mut crop = product.clone();
    for k in 0..20 {
        crop.samp_num[k] -= c0 / crop.samp_scale * crop.samp_den[k];
        crop.line_num[k] -= r0 / crop.line_scale * crop.line_den[k];
    }
    let g = LonLatH {
        lon: 55.3001,
        lat: 25.2002,
        h: 321.0,
    };
    let (a, b) = (product.project(g).unwrap(), crop.project(g).unwrap());
    assert!((a.0 - c0 - b.0).abs() < 1e-7 && (a.1 - r0 - b.1).abs() < 1e-7);
    let sensor = |rpc: Rpc, side: usize| RpcSensor {
        rpc,
        geo: Geographic::new(Crs::Epsg(32640)).unwrap(),
        width: side,
        height: side,
    };
    sensor(crop.clone(), 1024).check_extent().unwrap();
    sensor(product.clone(), 40_000).check_extent().unwrap();
    // The crop's RPCs given to a 40 000 px image: its far corners lie 1.9 scales away.
    let e = sensor(crop, 40_000).check_extent().unwrap_err();
    assert!(
        e.contains("corner")
            && e.contains("40000 × 40000")
            && e.contains("outside where the RPCs are valid"),
        "{e}"
    );
}
