//! Mark location against the simulator's truth (issue 4, item 6): coarse location within
//! 0.5 px, also for crosses cut by the frame; least-squares matching of crosses on 32-frame
//! averages better than 0.01 px RMSE; a mark that is not there is reported, not invented.

use rig::coords::PixelXY;
use rig::digitise::{average_frames, estimate_stripes, remove_stripes, ImageF32};
use rig::targets::{
    locate, match_template, render, CoarseOptions, LsmOptions, MarkShape, Polarity, Template,
    TemplateSpec,
};
use rig_sim::camera::{expose, render_scene, CameraConfig};
use rig_sim::plate::Plate;
use rig_sim::rng::Rng;

struct World {
    cfg: CameraConfig,
    plate: Plate,
    seed: u64,
}

fn world(seed: u64) -> World {
    let mut rng = Rng::new(seed);
    let cfg = CameraConfig::new(&mut rng);
    let plate = Plate::new(&mut rng);
    World { cfg, plate, seed }
}

/// A 32-frame average, stripes removed, as `rig camera grab` makes it.
fn grab(w: &World, mark_um: [f64; 2], first_seq: u64) -> ImageF32 {
    let ideal = render_scene(&w.cfg, &w.plate, None, mark_um);
    let frames: Vec<Vec<u16>> = (first_seq..first_seq + 32)
        .map(|s| expose(&w.cfg, &ideal, w.seed, s))
        .collect();
    let refs: Vec<&[u16]> = frames.iter().map(|f| f.as_slice()).collect();
    let mut img = average_frames(w.cfg.width, w.cfg.height, &refs)
        .unwrap()
        .mean;
    let e = estimate_stripes(&img);
    remove_stripes(&mut img, &e);
    img
}

/// Where the truth puts a carriage point in the image with the mark at `mark_um`.
fn truth_px(w: &World, mark_um: [f64; 2], p_um: [f64; 2]) -> PixelXY {
    let af = &w.cfg.affine;
    let (dx, dy) = (p_um[0] - mark_um[0], p_um[1] - mark_um[1]);
    let det = af.a[0] * af.b[1] - af.a[1] * af.b[0];
    PixelXY::new(
        af.mark_px[0] + (af.b[1] * dx - af.a[1] * dy) / det,
        af.mark_px[1] + (-af.b[0] * dx + af.a[0] * dy) / det,
    )
}

/// Templates for coarse location at the pixel spacing and shear a first look gives (the truth
/// 0.3 % off: a cut cross leans by the shear, 0.5°, and without it its visible arm would pull
/// the centre half a pixel), and for LSM at a nominal spacing 2 % off (its affine parameters
/// take up the rest).
fn templates(w: &World) -> (Template, Template) {
    let shape = MarkShape::cross(w.plate.arm_um, w.plate.line_um);
    let af = &w.cfg.affine;
    let spec = |size, um_per_px, fine| TemplateSpec {
        size,
        um_per_px,
        blur_px: 0.7,
        polarity: Polarity::DarkOnClear,
        fine,
    };
    let k = 1.003;
    let first_look = [[af.a[0] * k, af.a[1] * k], [af.b[0] * k, af.b[1] * k]];
    let nominal = [[10.0, 0.0], [0.0, 11.2]];
    let whole = (2.0 * w.plate.arm_um / 10.0) as usize + 12;
    (
        render(&shape.for_coarse(), &spec(whole, first_look, false)),
        render(&shape, &spec(71, nominal, true)),
    )
}

#[test]
fn crosses_to_a_hundredth_of_a_pixel() {
    let w = world(7);
    let (big, patch) = templates(&w);
    let c = w.plate.crosses[4].true_um;
    let mut rng = Rng::new(99);
    let (mut se, mut n, mut worst_coarse) = (0.0, 0, 0.0f64);
    let mut rows = Vec::new();
    for k in 0..12 {
        // Anywhere the 71-px patch fits in the frame.
        let want = PixelXY::new(45.0 + 422.0 * rng.uniform(), 45.0 + 422.0 * rng.uniform());
        let af = &w.cfg.affine;
        let (dc, dr) = (want.col - af.mark_px[0], want.row - af.mark_px[1]);
        let mark = [
            c[0] - (af.a[0] * dc + af.a[1] * dr),
            c[1] - (af.b[0] * dc + af.b[1] * dr),
        ];
        let truth = truth_px(&w, mark, c);
        let img = grab(&w, mark, 1000 * k);
        let co = locate(&img, &big, &CoarseOptions::default()).unwrap();
        worst_coarse = worst_coarse.max(co.centre.dist(truth));
        let m = match_template(&img, &patch, co.centre, &LsmOptions::default()).unwrap();
        let e = [m.centre.col - truth.col, m.centre.row - truth.row];
        se += e[0] * e[0] + e[1] * e[1];
        n += 2;
        rows.push((truth, co.centre.dist(truth), e, m));
    }
    let rmse = (se / n as f64).sqrt();
    for (t, ce, e, m) in &rows {
        println!(
            "truth ({:7.2},{:7.2}) coarse err {:.3} px, LSM err ({:+.4},{:+.4}) σ ({:.4},{:.4}) ρ {:.3} σ0 {:.2} DN, {} it",
            t.col, t.row, ce, e[0], e[1], m.sigma_px[0], m.sigma_px[1], m.correlation, m.sigma0_dn, m.iterations
        );
    }
    println!(
        "cross centres: LSM RMSE {rmse:.4} px per coordinate; coarse worst {worst_coarse:.3} px"
    );
    assert!(worst_coarse < 0.5, "coarse location {worst_coarse:.3} px");
    // The issue asks for 0.01 px; sampling the finely drawn template instead of resampling
    // the image reaches the noise floor (σ ≈ 0.001 px), so hold it to 0.002.
    assert!(rmse < 0.002, "LSM RMSE {rmse:.4} px");
}

#[test]
fn coarse_location_of_crosses_cut_by_the_frame() {
    let w = world(8);
    let (big, _) = templates(&w);
    let c = w.plate.crosses[4].true_um;
    let af = &w.cfg.affine;
    let mut worst = 0.0f64;
    // Centres near every edge and corner: most of the cross is out of the frame.
    for (k, want) in [
        (5.0, 256.0),
        (507.0, 256.0),
        (256.0, 3.0),
        (256.0, 509.0),
        (20.0, 20.0),
        (495.0, 500.0),
        (8.0, 503.0),
        (300.0, 490.0),
    ]
    .into_iter()
    .enumerate()
    {
        let (dc, dr) = (want.0 - af.mark_px[0], want.1 - af.mark_px[1]);
        let mark = [
            c[0] - (af.a[0] * dc + af.a[1] * dr),
            c[1] - (af.b[0] * dc + af.b[1] * dr),
        ];
        let truth = truth_px(&w, mark, c);
        let img = grab(&w, mark, 5000 + 100 * k as u64);
        let co = locate(&img, &big, &CoarseOptions::default()).unwrap();
        let e = co.centre.dist(truth);
        println!(
            "cut cross at ({:7.2},{:7.2}): coarse error {e:.3} px ({:+.3},{:+.3}), score {:.2}, visible {:.2}",
            truth.col, truth.row, co.centre.col - truth.col, co.centre.row - truth.row, co.score, co.visible
        );
        worst = worst.max(e);
    }
    assert!(worst < 0.5, "coarse location of cut crosses: {worst:.3} px");
}

#[test]
fn no_mark_is_reported_not_invented() {
    let w = world(9);
    let (big, patch) = templates(&w);
    // Clear glass between the crosses (only the measuring mark and dust in view).
    let img = grab(&w, [75_000.0, 75_000.0], 0);
    let e = locate(&img, &big, &CoarseOptions::default()).unwrap_err();
    println!("empty field: {e}");
    // LSM started on flat glass: too little contrast.
    let start = PixelXY::new(100.0, 400.0);
    let e = match_template(&img, &patch, start, &LsmOptions::default()).unwrap_err();
    assert!(
        matches!(e, rig::targets::LsmError::LowContrast { .. }),
        "{e}"
    );
    // Started where the window is partly outside the image and holds no mark: no match.
    let c = w.plate.crosses[4].true_um;
    let img = grab(&w, c, 100);
    let e = match_template(
        &img,
        &patch,
        PixelXY::new(20.0, 240.0),
        &LsmOptions::default(),
    )
    .unwrap_err();
    println!("window half out, no mark in it: {e}");
    // Started wholly outside the image.
    let e = match_template(
        &img,
        &patch,
        PixelXY::new(-40.0, 240.0),
        &LsmOptions::default(),
    )
    .unwrap_err();
    assert!(matches!(e, rig::targets::LsmError::LeftWindow), "{e}");
}
