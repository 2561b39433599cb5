//! The simulated camera through the `Camera` trait: sequence gaps are reported, and the image
//! shows what lies under the lens where the stage really is.

use rig::camera::{Camera, SimCamera};
use rig::coords::CarriageUm;
use rig::digitise::Averager;
use rig::stage::{self, DriverOptions};
use rig_sim::{Dialect, EmbeddedSim, FaultSpec, SimConfig};
use std::time::Duration;

/// A simulator at time scale 0, homed, with or without a film.
fn sim(film: bool) -> EmbeddedSim {
    EmbeddedSim::start(SimConfig {
        dialect: Dialect::Native,
        time_scale: 0.0,
        start_homed: true,
        faults: FaultSpec::default(),
        film,
        ..Default::default()
    })
    .unwrap()
}

/// The stage driver on a simulator.
fn open_stage(s: &EmbeddedSim) -> Box<dyn rig::stage::Stage> {
    stage::open(
        &s.port,
        stage::Dialect::Native,
        DriverOptions::default(),
        &Default::default(),
    )
    .unwrap()
}

#[test]
fn dropped_frames_are_detected() {
    let s = sim(false);
    let mut cam = SimCamera::new(s.world.clone(), 0.1);
    let mut seqs = Vec::new();
    for _ in 0..200 {
        seqs.push(cam.next_frame(Duration::from_secs(1)).unwrap().seq);
    }
    let truth = cam.truth_dropped().to_vec();
    assert!(!truth.is_empty(), "frames were dropped");
    // Every frame the simulator lost before the last one delivered is counted, and none other.
    let lost_before_last = truth.iter().filter(|&&q| q < *seqs.last().unwrap()).count() as u64;
    assert_eq!(cam.dropped(), lost_before_last);
    for q in truth.iter().filter(|&&q| q < *seqs.last().unwrap()) {
        assert!(
            !seqs.contains(q),
            "seq {q} was reported dropped and delivered"
        );
    }
}

#[test]
fn the_camera_sees_the_cross_the_stage_is_over() {
    let s = sim(false);
    let mut st = open_stage(&s);
    // Drive the plate's central cross under the measuring mark (nominal position: the host
    // would know it from the plate certificate).
    let nominal = s.world.plate.crosses[4].nominal_um;
    st.move_to(CarriageUm::new(nominal[0], nominal[1])).unwrap();
    let mut cam = SimCamera::new(s.world.clone(), 0.0);
    let info = cam.info();
    let mut avg = Averager::new(info.width, info.height);
    for _ in 0..8 {
        let f = cam.next_frame(Duration::from_secs(1)).unwrap();
        avg.add(f.width, f.height, f.seq, &f.data).unwrap();
    }
    let img = avg.finish().unwrap().mean;
    // The cross's centre is where its two arms cross: the darkest 5×5 block.
    let (mut best, mut at) = (f32::MAX, (0, 0));
    for r in 10..img.height - 10 {
        for c in 10..img.width - 10 {
            let mut sum = 0.0;
            for dr in 0..5 {
                for dc in 0..5 {
                    sum += img.at(c + dc - 2, r + dr - 2);
                }
            }
            if sum < best {
                best = sum;
                at = (c, r);
            }
        }
    }
    let mark = s.world.camera.affine.mark_px;
    // Within a pixel or two: stage noise, engraving error and backlash are a few µm.
    assert!(
        (at.0 as f64 - mark[0]).abs() <= 2.0 && (at.1 as f64 - mark[1]).abs() <= 2.0,
        "cross at {at:?}, mark at {mark:?}"
    );
}

#[test]
fn the_camera_sees_each_fiducial_where_the_film_lies() {
    let s = sim(true);
    let film = s.world.film.clone().expect("a film is loaded");
    let mut st = open_stage(&s);
    let mut cam = SimCamera::new(s.world.clone(), 0.0);
    let mark = s.world.camera.affine.mark_px;
    for fid in film.fiducials.iter() {
        // The truth's placement puts the fiducial's centre here on the carriage.
        let c = film.to_carriage(fid.photo_mm);
        st.move_to(CarriageUm::new(c[0], c[1])).unwrap();
        let f = cam.next_frame(Duration::from_secs(1)).unwrap();
        // Centroid of darkness within 12 px of the mark: only the centre dot is that close
        // (lines start 15 px out, rings lie at 30 px).
        let w = f.width;
        let bright = f.data[20 * w + 20] as f64; // clear film base far from the mark
        let (mut sw, mut sx, mut sy) = (0.0, 0.0, 0.0);
        for r in (mark[1] as usize - 12)..=(mark[1] as usize + 12) {
            for cc in (mark[0] as usize - 12)..=(mark[0] as usize + 12) {
                let d = (bright - f.data[r * w + cc] as f64).max(0.0);
                let d = if d > 0.4 * bright { d } else { 0.0 };
                sw += d;
                sx += d * (cc as f64 + 0.5);
                sy += d * (r as f64 + 0.5);
            }
        }
        let at = (sx / sw, sy / sw);
        assert!(
            (at.0 - mark[0]).abs() <= 1.0 && (at.1 - mark[1]).abs() <= 1.0,
            "fiducial {} ({:?}) at {at:?}, mark at {mark:?}",
            fid.id,
            fid.shape
        );
    }
}

/// Largest absolute difference of two images, DN: where a cross moved, it is the cross's
/// contrast; between two averages at one place, the noise's extreme.
fn mad(a: &rig::digitise::ImageF32, b: &rig::digitise::ImageF32) -> f64 {
    a.data
        .iter()
        .zip(&b.data)
        .map(|(x, y)| (x - y).abs() as f64)
        .fold(0.0, f64::max)
}

#[test]
fn frames_queued_during_a_move_never_enter_an_average() {
    use rig::digitise::capture::capture;
    let s = sim(false);
    let mut st = open_stage(&s);
    let mut cam = SimCamera::new(s.world.clone(), 0.0);
    let c = s.world.plate.crosses[4].nominal_um;
    let a = CarriageUm::new(c[0], c[1]);
    let b = CarriageUm::new(c[0] + 1500.0, c[1] + 1000.0);
    let t = Duration::from_secs(1);
    let take = |cam: &mut SimCamera, n: u32, fresh: bool| {
        let now = fresh.then(|| cam.now().unwrap());
        capture(cam, n, false, t, now, |_| {}).unwrap()
    };
    st.move_to(a).unwrap();
    let at_a = take(&mut cam, 8, true);
    // Two averages at one place differ by their noise only.
    let noise = mad(&at_a.image, &take(&mut cam, 8, true).image).max(0.1);
    // Negative control: taken the old way, right after a move, the average holds frames the
    // driver's buffers filled at A. (If the simulated camera did not queue like V4L2, this
    // test could not tell the fix from no fix.)
    st.move_to(b).unwrap();
    let old_way = take(&mut cam, 4, false);
    let at_b = take(&mut cam, 16, true);
    let contaminated = mad(&old_way.image, &at_b.image);
    assert!(
        contaminated > 5.0 * noise,
        "{contaminated} vs noise {noise}"
    );
    // The fix: back at A, frames from before the stage stood still are set aside.
    st.move_to(a).unwrap();
    let fresh = take(&mut cam, 4, true);
    assert_eq!(fresh.stale, rig_sim::frames::BUFFERS as u64 - 1);
    let off = mad(&fresh.image, &at_a.image);
    assert!(off < 3.0 * noise, "{off} vs noise {noise}");
}
