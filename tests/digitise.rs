//! Digitisation against the simulator's truth (issue 3, item 6): averaging lowers the noise as
//! 1/√N, the stripe filter removes the field shift and the 12-pixel column pattern that the
//! simulated sensor really has, and it leaves edges as sharp as they were, where the seed's
//! low-pass filters widen them.

use rig::digitise::{estimate_stripes, remove_stripes, seed_lowpass, Averager, ImageF32};
use rig_sim::camera::{expose, render_plate, CameraConfig};
use rig_sim::plate::Plate;
use rig_sim::rng::Rng;

struct World {
    cfg: CameraConfig,
    plate: Plate,
}

fn world() -> World {
    let mut rng = Rng::new(42);
    let cfg = CameraConfig::new(&mut rng);
    let plate = Plate::new(&mut rng);
    World { cfg, plate }
}

fn average(w: &World, ideal: &[f32], first_seq: u64, n: u64) -> ImageF32 {
    let mut a = Averager::new(w.cfg.width, w.cfg.height);
    for seq in first_seq..first_seq + n {
        a.add(
            w.cfg.width,
            w.cfg.height,
            seq,
            &expose(&w.cfg, ideal, 42, seq),
        )
        .unwrap();
    }
    a.finish().unwrap().mean
}

fn std_of_diff(a: &ImageF32, b: &ImageF32, rows: std::ops::Range<usize>) -> f64 {
    let v: Vec<f64> = rows
        .flat_map(|r| (0..a.width).map(move |c| (r, c)))
        .map(|(r, c)| (a.at(c, r) - b.at(c, r)) as f64)
        .collect();
    let m = v.iter().sum::<f64>() / v.len() as f64;
    (v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (v.len() - 1) as f64).sqrt()
}

/// A flat field: the plate far from any cross.
fn flat(w: &World) -> Vec<f32> {
    let img = render_plate(&w.cfg, &w.plate, [75_000.0, 60_000.0]);
    assert!(
        img.iter().all(|&v| v == w.plate.clear as f32),
        "no cross in view"
    );
    img
}

#[test]
fn noise_falls_as_one_over_sqrt_n() {
    let w = world();
    let ideal = flat(&w);
    // Temporal noise of an N-frame average: two independent averages differ by √2·σ_N; the
    // fixed patterns (stripes, dust) cancel in the difference.
    let sigma = |n: u64| {
        std_of_diff(
            &average(&w, &ideal, 0, n),
            &average(&w, &ideal, 10_000, n),
            100..500,
        ) / 2f64.sqrt()
    };
    let s1 = sigma(1);
    assert!(
        s1 > 1.0,
        "single-frame noise {s1} DN should dwarf the quantisation step"
    );
    for n in [4u64, 16, 32] {
        let ratio = sigma(n) * (n as f64).sqrt() / s1;
        println!("noise: σ_1 = {s1:.3} DN, N = {n}: σ_N·√N/σ_1 = {ratio:.3}");
        assert!(
            (ratio - 1.0).abs() < 0.10,
            "N = {n}: σ_N·√N/σ_1 = {ratio:.3}"
        );
    }
}

/// Odd-minus-even row shift, and the peak-to-peak of the column profile folded with the
/// sensor's 12-pixel period (per column the median of the even rows, so neither the field
/// shift nor the dust blobs count as stripes).
fn stripe_metrics(img: &ImageF32) -> (f64, f64) {
    let (w, h) = (img.width, img.height);
    let rows = 100..h;
    let mut odd = 0.0;
    let mut even = 0.0;
    for r in rows.clone() {
        let m: f64 = img.row(r).iter().map(|&v| v as f64).sum::<f64>() / w as f64;
        if r % 2 == 1 {
            odd += m;
        } else {
            even += m;
        }
    }
    let half = (rows.len() / 2) as f64;
    let field = (odd - even) / half;
    let col: Vec<f64> = (0..w)
        .map(|c| {
            let mut v: Vec<f64> = rows
                .clone()
                .filter(|r| r % 2 == 0)
                .map(|r| img.at(c, r) as f64)
                .collect();
            v.sort_by(f64::total_cmp);
            v[v.len() / 2]
        })
        .collect();
    let mut fold = [0.0f64; 12];
    let per = [(w / 12) as f64 + 1.0, (w / 12) as f64];
    for (c, v) in col.iter().enumerate() {
        fold[c % 12] += v / if c % 12 < w % 12 { per[0] } else { per[1] };
    }
    let pp = fold.iter().cloned().fold(f64::MIN, f64::max)
        - fold.iter().cloned().fold(f64::MAX, f64::min);
    (field, pp)
}

#[test]
fn stripe_filter_removes_what_the_sensor_adds() {
    let w = world();
    let ideal = flat(&w);
    let mut img = average(&w, &ideal, 0, 32);
    let (field0, cols0) = stripe_metrics(&img);
    let est = estimate_stripes(&img);
    // Estimated from the data, and equal to the truth.
    let scale = w.cfg.scale() as f32;
    assert!(
        (est.field_offset - w.cfg.field_shift_dn8 as f32 * scale).abs() < 0.3,
        "field {}",
        est.field_offset
    );
    assert_eq!(est.column_period, Some(12));
    // The darkest 3-pixel stripe starts where the truth's phase puts it.
    let darkest = est.column_darkest_phase.unwrap();
    assert!(
        (0..3)
            .map(|k| (12 - w.cfg.stripe_phase_px + k) % 12)
            .any(|c| c == darkest),
        "darkest phase {darkest}"
    );
    remove_stripes(&mut img, &est);
    let (field1, cols1) = stripe_metrics(&img);
    println!("stripes: field shift {field0:.3} → {field1:.3} DN, 12-px pattern p-p {cols0:.3} → {cols1:.3} DN; estimate {est:?}");
    assert!(
        field0 > 3.0 && cols0 > 2.5,
        "the sensor has stripes: {field0:.2}, {cols0:.2}"
    );
    assert!(
        field1.abs() < 0.1 * field0,
        "field shift {field0:.3} → {field1:.3}"
    );
    assert!(
        cols1 < 0.1 * cols0,
        "column pattern {cols0:.3} → {cols1:.3}"
    );
}

/// 10–90 % width of the left edge of the cross's vertical arm, averaged over rows of the arm.
fn edge_width(img: &ImageF32, mark: [f64; 2]) -> f64 {
    let (mc, mr) = (mark[0] as usize, mark[1] as usize);
    let mut widths = Vec::new();
    for r in mr + 20..mr + 80 {
        let p: Vec<f64> = (mc - 12..mc + 1).map(|c| img.at(c, r) as f64).collect();
        let hi = p[..4].iter().sum::<f64>() / 4.0;
        let lo = p.iter().cloned().fold(f64::MAX, f64::min);
        let cross = |frac: f64| -> f64 {
            let level = hi - frac * (hi - lo);
            for i in 0..p.len() - 1 {
                if p[i] >= level && p[i + 1] < level {
                    return i as f64 + (p[i] - level) / (p[i] - p[i + 1]);
                }
            }
            f64::NAN
        };
        widths.push(cross(0.9) - cross(0.1));
    }
    widths.iter().sum::<f64>() / widths.len() as f64
}

#[test]
fn stripe_filter_keeps_edges_sharp_and_the_seed_filter_does_not() {
    let w = world();
    let c = w.plate.crosses[4];
    let ideal = render_plate(&w.cfg, &w.plate, c.true_um);
    let mark = w.cfg.affine.mark_px;
    let raw = average(&w, &ideal, 0, 32);
    let mut ours = raw.clone();
    remove_stripes(&mut ours, &estimate_stripes(&raw));
    let seed = seed_lowpass(&raw);
    let truth = edge_width(
        &ImageF32 {
            width: w.cfg.width,
            height: w.cfg.height,
            data: ideal.clone(),
        },
        mark,
    );
    let (w_raw, w_ours, w_seed) = (
        edge_width(&raw, mark),
        edge_width(&ours, mark),
        edge_width(&seed, mark),
    );
    println!("edge 10–90 %: rendered {truth:.3} px, 32-frame average {w_raw:.3}, stripe-filtered {w_ours:.3}, seed low-pass {w_seed:.3}");
    assert!(truth > 1.0 && truth < 3.0, "rendered edge width {truth}");
    assert!(
        (w_ours - w_raw).abs() / w_raw < 0.05,
        "our filter changed the edge: {w_raw:.3} → {w_ours:.3} px (truth {truth:.3})"
    );
    assert!(
        w_seed > 1.2 * w_raw,
        "the seed's low-pass should widen the edge: {w_raw:.3} → {w_seed:.3} px"
    );
}
