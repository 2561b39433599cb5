//! `rig camera` through the binary.

mod common;
use common::*;

#[test]
fn grab_writes_a_tiff_and_a_sidecar() {
    let dir = tempfile::tempdir().unwrap();
    let tiff = dir.path().join("plate.tiff");
    let out = rig()
        // The issue's own form: the camera options after the action.
        .args([
            "camera",
            "grab",
            "--sim",
            "--sim-frame-drop",
            "0.2",
            "--frames",
            "16",
            "--json",
            "-o",
        ])
        .arg(&tiff)
        .output()
        .unwrap();
    let (code, j, err) = parse(out);
    assert_eq!(code, 0, "{err}");
    let (w, h, px) = rig::digitise::output::read_tiff16(&tiff).unwrap();
    assert_eq!((w, h), (512, 512));
    // Stretched to the full 16-bit range.
    assert_eq!(*px.iter().min().unwrap(), 0);
    assert_eq!(*px.iter().max().unwrap(), 65535);
    let side: serde_json::Value =
        serde_json::from_slice(&std::fs::read(tiff.with_extension("json")).unwrap()).unwrap();
    assert_eq!(side, j, "the sidecar is what --json printed");
    assert_eq!(side["frames"], 16);
    assert!(
        side["dropped_frames"].as_u64().unwrap() > 0,
        "frame drops were injected and must be reported"
    );
    assert_eq!(side["stripes"]["column_period"], 12);
    assert!((side["stripes"]["field_offset"].as_f64().unwrap() - 4.5).abs() < 0.5);
    let pos = &side["stage_position_mm"];
    assert!(
        (pos[0].as_f64().unwrap() - 125.0).abs() < 0.01
            && (pos[1].as_f64().unwrap() - 125.0).abs() < 0.01
    );
}

#[test]
fn bad_grab_options_are_named() {
    let dir = tempfile::tempdir().unwrap();
    let tiff = dir.path().join("x.tiff");
    for (args, needle) in [
        (vec!["--frames", "0"], "--frames"),
        (vec!["--stretch", "50,10"], "--stretch"),
        (vec!["--gain", "loud"], "--gain"),
        (vec!["--exposure", "0"], "--exposure"),
    ] {
        let out = rig()
            .args(["camera", "--sim", "grab"])
            .args(&args)
            .arg("-o")
            .arg(&tiff)
            .output()
            .unwrap();
        assert_ne!(out.status.code(), Some(0), "{args:?}");
        assert!(
            String::from_utf8_lossy(&out.stderr).contains(needle),
            "{args:?}: {}",
            String::from_utf8_lossy(&out.stderr)
        );
        assert!(!tiff.exists(), "nothing written on bad options");
    }
}

#[test]
fn camera_socket_shows_where_the_stage_moved() {
    let dir = tempfile::tempdir().unwrap();
    let sock = dir.path().join("cam.sock");
    let sim = SimProcess::start(
        "native",
        &[
            "--start-homed",
            "--camera-drop",
            "0.1",
            "--camera-socket",
            sock.to_str().unwrap(),
        ],
    );
    // Put the plate's central cross under the measuring mark, from another process.
    let truth = sim.truth();
    let c = &truth["plate"]["crosses"][4]["nominal_um"];
    let (x, y) = (
        c[0].as_f64().unwrap() / 1000.0,
        c[1].as_f64().unwrap() / 1000.0,
    );
    let (code, _, err) = sim.stage("native", &["move", &x.to_string(), &y.to_string()]);
    assert_eq!(code, 0, "{err}");
    let tiff = dir.path().join("s.tiff");
    let cam = format!("sim:{}", sock.display());
    let (code, j, err) = parse(
        rig()
            .args([
                "camera", "--camera", &cam, "grab", "--frames", "16", "--json", "-o",
            ])
            .arg(&tiff)
            .output()
            .unwrap(),
    );
    assert_eq!(code, 0, "{err}");
    assert!(
        j["dropped_frames"].as_u64().unwrap() > 0,
        "drops over the socket are seen as sequence gaps"
    );
    let (w, _, px) = rig::digitise::output::read_tiff16(&tiff).unwrap();
    // Darkest 5×5 block = where the arms cross = the measuring mark's pixel (from the truth).
    let mark = &truth["camera"]["affine"]["mark_px"];
    let (mc, mr) = (mark[0].as_f64().unwrap(), mark[1].as_f64().unwrap());
    let mut best = (u64::MAX, 0, 0);
    for r in 5..507 {
        for cc in 5..507 {
            let s: u64 = (0..5)
                .flat_map(|dr| (0..5).map(move |dc| (dr, dc)))
                .map(|(dr, dc)| px[(r + dr - 2) * w + cc + dc - 2] as u64)
                .sum();
            if s < best.0 {
                best = (s, cc, r);
            }
        }
    }
    assert!(
        (best.1 as f64 - mc).abs() <= 2.0 && (best.2 as f64 - mr).abs() <= 2.0,
        "cross at {:?}, mark at {mc},{mr}",
        (best.1, best.2)
    );
    sim.stop(); // SIGTERM
    assert!(
        !sock.exists(),
        "the socket is removed when the simulator stops on SIGTERM"
    );
}

#[test]
fn camera_needs_a_device_and_list_explains_the_build() {
    let out = rig().args(["camera", "info"]).output().unwrap();
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("--camera"));
    let out = rig().args(["camera", "list"]).output().unwrap();
    if cfg!(feature = "v4l2") {
        assert_eq!(out.status.code(), Some(0));
    } else {
        assert_ne!(out.status.code(), Some(0));
        assert!(String::from_utf8_lossy(&out.stderr).contains("--features v4l2"));
    }
    let out = rig()
        .args(["camera", "--camera", "sim:/nonexistent/cam.sock", "info"])
        .output()
        .unwrap();
    assert_ne!(out.status.code(), Some(0));
    assert!(
        String::from_utf8_lossy(&out.stderr).contains("camera-socket"),
        "says how to start the simulator: {}",
        String::from_utf8_lossy(&out.stderr)
    );
}
