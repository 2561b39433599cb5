use super::*;
use crate::geometry::pushbroom::fixtures::spot_like;
use crate::geometry::rpc::{fit_rpc, FitGrid};
use crate::geometry::{Crs, Geographic};

/// The SPOT-like view of the unit tests, looking 20° right of its northward track.
fn truth() -> Pushbroom {
    spot_like(20.0)
}

/// A low-discrepancy scatter of `n` image points with heights in 300 … 900 m, on the
/// ground through `s`.
fn scatter(s: &Pushbroom, n: usize, phase: f64) -> Vec<(PixelXY, GroundM)> {
    let frac = |v: f64| v - v.floor();
    (0..n)
        .map(|i| {
            let i = i as f64 + phase;
            let q = PixelXY::new(
                50.0 + frac(0.5 + i * 0.754_877_7) * 2900.0,
                50.0 + frac(0.5 + i * 0.569_840_3) * 2900.0,
            );
            let z = 300.0 + frac(i * 0.618_034) * 600.0;
            (q, s.image_to_ground(q, z).unwrap())
        })
        .collect()
}

/// The truth model disturbed as an ephemeris and attitude sensors would leave it: tens of
/// metres in position, tens of microradians in attitude, a drift.
fn disturbed() -> Pushbroom {
    corrected(
        &truth(),
        &[60.0, -40.0, 20.0, -6e-5, 4e-5, 1e-4, 1e-6, -5e-7, 2e-7],
    )
}

/// Seed 004's rigorous solution: from nine exact control points (weighted as measured to a
/// thousandth of a pixel, so that the priors barely pull) the corrected model puts 400 other
/// points (other places, other heights) where the true model does, to a hundredth of a pixel,
/// although the disturbed model was pixels off; the corrections themselves need not equal the
/// disturbance (a shift and a turn move the image alike), the projection must.
#[test]
fn nine_control_points_correct_the_orbit_to_a_hundredth_of_a_pixel() {
    let t = truth();
    let d = disturbed();
    let control = scatter(&t, 9, 0.0);
    let (fixed, fit) = correct_orbit(&d, &control, 1e-3, OrbitPrior::default()).unwrap();
    let worst = |m: &Pushbroom| {
        scatter(&t, 400, 1000.0)
            .iter()
            .map(|(q, g)| m.ground_to_image(*g).unwrap().dist(*q))
            .fold(0.0, f64::max)
    };
    let (off, left) = (worst(&d), worst(&fixed));
    eprintln!(
        "orbit correction from 9 points: check points off by {off:.1} px before, {left:.2e} px after; control RMS {:.1} → {:.2e} px in {} iterations",
        fit.rms_before_px, fit.rms_after_px, fit.iterations
    );
    assert!(off > 5.0, "the disturbance must matter: {off} px");
    assert!(left < 0.01, "{left} px at the check points; {fit:?}");
    assert_eq!(fit.parameters.len(), 9);
}

/// With 0.3 px of noise on 12 control points the check points' error stays at the noise's
/// order (the corrections average it down), and the control points' RMS after the fit is
/// the noise's, less the share the nine unknowns absorb.
#[test]
fn noisy_control_points_leave_a_check_error_of_the_noise_order() {
    let t = truth();
    let mut control = scatter(&t, 12, 0.0);
    // Deterministic noise of 0.3 px RMS (a scrambled sine, no RNG needed).
    for (k, (q, _)) in control.iter_mut().enumerate() {
        let k = k as f64;
        q.col += 0.3 * 2f64.sqrt() * (12.9898 * k + 1.0).sin();
        q.row += 0.3 * 2f64.sqrt() * (78.233 * k + 2.0).sin();
    }
    let (fixed, fit) = correct_orbit(&disturbed(), &control, 0.3, OrbitPrior::default()).unwrap();
    let checks = scatter(&t, 400, 1000.0);
    let rms = (checks
        .iter()
        .map(|(q, g)| fixed.ground_to_image(*g).unwrap().dist(*q).powi(2))
        .sum::<f64>()
        / checks.len() as f64)
        .sqrt();
    eprintln!(
        "12 points with 0.3 px noise: control RMS {:.3} px, check RMS {rms:.3} px",
        fit.rms_after_px
    );
    assert!(rms < 0.3, "check RMS {rms} px");
    assert!(
        (0.1..0.4).contains(&fit.rms_after_px),
        "control RMS {}",
        fit.rms_after_px
    );
}

#[test]
fn too_few_or_broken_control_points_are_refused() {
    let t = truth();
    let two = scatter(&t, 2, 0.0);
    assert!(matches!(
        correct_orbit(&t, &two, 0.3, OrbitPrior::default()),
        Err(ControlFitError::TooFew { got: 2, need: 3 })
    ));
    let mut bad = scatter(&t, 5, 0.0);
    bad[3].1.z = f64::NAN;
    assert_eq!(
        correct_orbit(&t, &bad, 0.3, OrbitPrior::default()).unwrap_err(),
        ControlFitError::NotFinite
    );
    // A point 500 km up the track is beyond the orbit's span.
    let mut far = scatter(&t, 5, 0.0);
    far[1].1.y += 500_000.0;
    assert!(matches!(
        correct_orbit(&t, &far, 0.3, OrbitPrior::default()),
        Err(ControlFitError::OffImage { index: 1, .. })
    ));
}

/// RPCs fitted to the true model, then displaced as a vendor's often are (a few pixels): the
/// shift from four control points brings them back onto the true model.
#[test]
fn an_rpc_shift_from_control_points_takes_out_a_bias() {
    let t = truth();
    let geo = Geographic::new(Crs::Epsg(32616)).unwrap();
    let (mut rpc, _) = fit_rpc(&t, &geo, [300.0, 900.0], FitGrid::default()).unwrap();
    rpc.samp_off += 3.2;
    rpc.line_off -= 1.7;
    let sensor = RpcSensor {
        rpc,
        geo,
        width: 3000,
        height: 3000,
    };
    let (fixed, fit) = correct_rpc_shift(&sensor, &scatter(&t, 4, 0.0), 0.3).unwrap();
    assert!((fit.parameters[0].1 + 3.2).abs() < 1e-4, "{fit:?}");
    assert!((fit.parameters[1].1 - 1.7).abs() < 1e-4, "{fit:?}");
    let worst = scatter(&t, 200, 1000.0)
        .iter()
        .map(|(q, g)| fixed.ground_to_image(*g).unwrap().dist(*q))
        .fold(0.0, f64::max);
    assert!(worst < 1e-3, "{worst} px");
}
