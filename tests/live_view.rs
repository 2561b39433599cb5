//! The live view in a real browser: headless Chromium over WebDriver against `rig serve --sim`.
//! The page loads and follows the events; items queued from the page run (a home, a move over
//! the film); the live frame changes when the stage is jogged from the page (by more than it
//! changes between two frames standing still);
//! a calibration item queued from the page shows its frames and its progress advancing, pauses
//! and resumes from the page's buttons. Screenshots are kept in target/tmp/live-view/.

mod common;

use common::serve::Server;
use common::webdriver::{available, Browser};
use serde_json::{json, Value};
use std::path::PathBuf;

/// The canvas as 40 × 30 cell means (a coarse look that a shift of the picture changes and
/// the camera's noise barely does).
const CELLS: &str = r#"
const c = document.querySelector('#live');
const g = c.getContext('2d');
const d = g.getImageData(0, 0, c.width, c.height).data;
const out = new Array(40 * 30).fill(0), n = new Array(40 * 30).fill(0);
for (let y = 0; y < c.height; y += 2) for (let x = 0; x < c.width; x += 2) {
  const k = Math.floor(y * 30 / c.height) * 40 + Math.floor(x * 40 / c.width);
  out[k] += d[4 * (y * c.width + x) + 1]; n[k] += 1;
}
return [Number(c.dataset.frame), out.map((v, k) => v / Math.max(1, n[k]))];
"#;

fn cells(b: &Browser) -> (u64, Vec<f64>) {
    let v = b.js(CELLS, json!([]));
    let frame = v[0].as_u64().unwrap_or(0);
    let cells = v[1]
        .as_array()
        .unwrap()
        .iter()
        .map(|x| x.as_f64().unwrap())
        .collect();
    (frame, cells)
}

/// The next frame drawn after `after`.
fn next_frame(b: &Browser, after: u64) -> (u64, Vec<f64>) {
    b.wait("a new live frame", 20, |b| {
        let c = cells(b);
        (c.0 > after).then_some(c)
    })
}

fn mean_abs_diff(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| (x - y).abs()).sum::<f64>() / a.len() as f64
}

fn shots() -> PathBuf {
    PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join("live-view")
}

#[test]
fn the_page_shows_the_camera_runs_items_and_controls_them() {
    if !available() {
        return;
    }
    let d = tempfile::tempdir().unwrap();
    let store = d.path().join("store");
    // A pixel session for the page's calibration panel and for the interior item.
    common::quick_pixel_session(&store);
    let s = Server::start(
        &d.path().join("data"),
        &["--sim", "--store", store.to_str().unwrap()],
    );
    let b = Browser::start();
    b.goto(&s.url);
    // Loaded: following the events, a frame drawn, the calibration shown.
    b.wait("the event stream", 20, |b| {
        (b.text("#conn") == "live").then_some(())
    });
    b.wait("a first frame", 20, |b| (cells(b).0 > 0).then_some(()));
    b.wait("the calibration panel", 20, |b| {
        b.text("#calibration")
            .contains("pixel session")
            .then_some(())
    });
    b.screenshot(&shots().join("1-loaded.png"));

    // The simulator's film, lifted off and laid again from the page.
    b.wait("the film laid", 20, |b| {
        (b.text("#sim-film-state") == "laid").then_some(())
    });
    b.click("#sim-film-lift");
    b.wait("the film lifted", 20, |b| {
        (b.text("#sim-film-state") == "lifted").then_some(())
    });
    assert_eq!(
        s.call("GET", "/api/v1/status", None, None).1["sim_film"],
        "lifted"
    );
    b.click("#sim-film-lay");
    b.wait("the film laid again", 20, |b| {
        (b.text("#sim-film-state") == "laid").then_some(())
    });

    // An item queued from the page runs: home, then the queue started from the page.
    b.click("#add-kind option[value=home]");
    b.click("#add-btn");
    b.wait("the home item in the queue", 20, |b| {
        (b.js(
            "return document.querySelectorAll('#queue tr').length",
            json!([]),
        ) == 1)
            .then_some(())
    });
    b.click("#q-start");
    // And a move over the film (the page's default position, 100, 100 mm).
    b.click("#add-kind option[value=move]");
    b.click("#add-btn");
    b.wait("the home and the move done, in the history", 60, |b| {
        let n = b.js(
            "return document.querySelectorAll('#history tr[data-state=done]').length",
            json!([]),
        );
        (n == 2).then_some(())
    });

    // The live frame changes when the stage moves, by more than standing still.
    // (Frames drawn before the home finished are skipped: one in flight, then two standing.)
    let now = next_frame(&b, cells(&b).0);
    let still_a = next_frame(&b, now.0);
    let still_b = next_frame(&b, still_a.0);
    let noise = mean_abs_diff(&still_a.1, &still_b.1);
    let x0 = b.text("#pos-x");
    b.click(".jog button[data-dx='1']");
    b.wait("the position to change", 20, |b| {
        (b.text("#pos-x") != x0).then_some(())
    });
    let moved_a = next_frame(&b, still_b.0);
    let moved = next_frame(&b, moved_a.0);
    let change = mean_abs_diff(&still_b.1, &moved.1);
    eprintln!("live frame: {noise:.2} grey levels between two frames standing still, {change:.2} across a 1 mm jog");
    assert!(
        change > 3.0 * noise.max(0.3),
        "the frame barely changed with the stage: {change:.2} moved vs {noise:.2} still"
    );
    b.screenshot(&shots().join("2-jogged.png"));

    // A calibration item queued from the page: its progress advances; pause and resume from
    // the page's buttons; it ends done.
    let before = cells(&b).0;
    b.click("#add-kind option[value=calibrate_interior]");
    b.type_into("#add-frames-n", "12");
    b.click("#add-btn");
    let first = b.wait("progress", 60, |b| {
        let v = b.js(
            "return Number(document.querySelector('#progress').value)",
            json!([]),
        );
        v.as_f64().filter(|&p| p >= 1.0)
    });
    b.click("#run-pause");
    b.wait("the item paused", 60, |b| {
        (b.js(
            "return document.querySelector('#run-item').dataset.state",
            json!([]),
        ) == "paused")
            .then_some(())
    });
    // The frames the calibration took were shown as it took them.
    b.wait("a frame of the calibration", 20, |b| {
        (cells(b).0 > before + 1).then_some(())
    });
    b.screenshot(&shots().join("3-paused.png"));
    b.click("#run-resume");
    let mut seen = vec![first];
    b.wait("the calibration done, in the history", 120, |b| {
        if let Some(p) = b
            .js(
                "return Number(document.querySelector('#progress').value)",
                json!([]),
            )
            .as_f64()
        {
            if seen.last() != Some(&p) {
                seen.push(p);
            }
        }
        let n = b.js(
            "return document.querySelectorAll('#history tr[data-state=done]').length",
            json!([]),
        );
        (n == 3).then_some(())
    });
    // The new interior session's residual plots are shown beside the pixel session's.
    b.wait("the calibration's plots", 20, |b| {
        let n = b.js(
            "return document.querySelectorAll('#plots img').length",
            json!([]),
        );
        (n.as_u64() >= Some(4)).then_some(())
    });
    b.screenshot(&shots().join("4-done.png"));
    assert!(
        seen.windows(2).any(|w| w[1] > w[0]),
        "the progress bar never advanced: {seen:?}"
    );
    // The service agrees: the item done; its pause ended the first session before its next
    // mark (kept, marked failed with the reason), and the resumed one is the newest.
    let (_, h) = s.call("GET", "/api/v1/history", None, None);
    let it: &Value = h["history"]
        .as_array()
        .unwrap()
        .iter()
        .find(|i| i["task"]["kind"] == "calibrate_interior")
        .unwrap();
    assert_eq!(it["state"], "done", "{it}");
    let mut sessions: Vec<PathBuf> = std::fs::read_dir(&store)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.to_string_lossy().contains("-interior"))
        .collect();
    sessions.sort();
    assert_eq!(sessions.len(), 2, "{sessions:?}");
    let log = std::fs::read_to_string(sessions[0].join("log.jsonl")).unwrap();
    assert!(log.contains("interrupted by the operator"), "{log}");
    assert_eq!(
        it["result"]["session"].as_str().map(PathBuf::from),
        Some(sessions[1].clone())
    );
    eprintln!("screenshots in {}", shots().display());
}
