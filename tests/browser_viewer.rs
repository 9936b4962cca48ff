//! The browser viewer in a real browser: `tests/browser/viewer_check.mjs` opens the page
//! of a running `rigless demo` in headless Chromium (Playwright), and this test checks
//! what it measured. Skips, saying why, when Node.js, Chromium or the test's npm
//! packages are absent (`.ci/run` installs them: `npm ci --prefix tests/browser`).

mod common;

use std::path::Path;
use std::process::Command;
use std::time::Duration;

/// Longest the whole browser check may take, seconds (it takes about 30).
const TIMEOUT_S: u64 = 180;

/// One browser check at a time: each runs a demo and a software-WebGL Chromium, and two
/// at once on two cores halve the rates each measures.
static ONE_BROWSER: std::sync::Mutex<()> = std::sync::Mutex::new(());

fn missing_peer() -> Option<String> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/browser");
    if Command::new("node").arg("--version").output().is_err() {
        return Some("node is not installed".into());
    }
    let chromium = std::env::var("CHROMIUM").unwrap_or_else(|_| "/usr/bin/chromium".into());
    if !Path::new(&chromium).exists() {
        return Some(format!(
            "no Chromium at {chromium} (Debian's `chromium`; or set CHROMIUM)"
        ));
    }
    if !dir.join("node_modules/playwright-core").is_dir() {
        return Some(
            "playwright-core is not installed: run `npm ci --prefix tests/browser`".into(),
        );
    }
    None
}

#[test]
fn the_viewer_page_draws_the_stream_and_reconnects_in_chromium() {
    if let Some(why) = missing_peer() {
        common::skip_for_missing_peer(&why);
        return;
    }
    let _one = ONE_BROWSER.lock().unwrap_or_else(|e| e.into_inner());
    let out = tempfile::tempdir().unwrap();
    let r = common::run_json_check(
        "node",
        "tests/browser/viewer_check.mjs",
        out.path(),
        Duration::from_secs(TIMEOUT_S),
    );
    let f = |k: &str| r[k].as_f64().unwrap_or_else(|| panic!("{k} in {r}"));

    // The page decodes the same IEEE floats the TCP stream carries: exactly equal.
    assert!(f("compared_frames") >= 3.0, "{r}");
    assert_eq!(f("max_vertex_diff_m"), 0.0, "{r}");
    // Two reads 150 ms apart see a newer frame and moved vertices (the hand plays its
    // fingers all the time); most of the read pairs must.
    assert!(
        f("reads_advanced") >= 2.0 && f("reads_changed") >= 2.0,
        "{r}"
    );
    assert_eq!(r["topology"]["character"], "hand", "{r}");
    assert_eq!(r["topology"]["actors"], 1, "{r}");
    assert_eq!(r["topology"]["markers"], 8, "{r}");

    // The solver publishes at 120 Hz; the page must take at least half of it. It draws
    // at what software WebGL gives on this machine (35–38 fps measured): at least 5.
    assert!(f("received_fps") >= 60.0, "{r}");
    assert!(f("drawn_fps") >= 5.0, "{r}");
    // Marker received → drawn, median over about 3 s: 13 ms measured with software
    // WebGL; 100 ms would be a page that lags behind the stream.
    assert!(
        f("latency_ms_p50") < 100.0 && f("latency_samples") >= 30.0,
        "{r}"
    );

    // The framed hand covers 5–10 % of the 960×720 picture; 2 % is a blank or lost
    // picture. Each marker is a 7-pixel square in its fill state's colour (8 markers, 49
    // pixels each, some behind the overlay's text or each other).
    let px = &r["pixels"];
    let share = px["skin"].as_f64().unwrap() / px["total"].as_f64().unwrap();
    assert!(share >= 0.02, "character share {share}: {r}");
    assert!(px["marker"].as_f64().unwrap() >= 20.0, "{r}");
    assert!(out.path().join("viewer.png").is_file());

    // The daemon was stopped and started again on the same ports: a second connection.
    assert!(r["reconnect"]["connects"].as_f64().unwrap() >= 2.0, "{r}");
    assert_eq!(r["page_errors"], serde_json::json!([]), "{r}");
}

/// The two-actor demo: both bodies drawn once their markers appear, each labelled with
/// its name, and kept inside the picture by the camera as they walk (Bob passes Ann and
/// the two end about 4 m apart).
#[test]
fn the_viewer_draws_every_actor_labelled_and_keeps_them_in_view() {
    if let Some(why) = missing_peer() {
        common::skip_for_missing_peer(&why);
        return;
    }
    let _one = ONE_BROWSER.lock().unwrap_or_else(|e| e.into_inner());
    let out = tempfile::tempdir().unwrap();
    let r = common::run_json_check_with(
        "node",
        "tests/browser/viewer_check.mjs",
        out.path(),
        &["--actors", "2"],
        Duration::from_secs(TIMEOUT_S),
    );
    assert_eq!(r["topology"]["actors"], 2, "{r}");
    assert_eq!(r["topology"]["actor"], "Ann", "{r}");
    // The page's first actor's vertices are the stream's, exactly.
    assert!(r["compared_frames"].as_f64().unwrap() >= 3.0, "{r}");
    assert_eq!(r["max_vertex_diff_m"], 0.0, "{r}");
    assert_eq!(r["actors"]["follow"], true, "{r}");
    for name in ["Ann", "Bob"] {
        let a = &r["actors"]["each"][name];
        let n = |k: &str| a[k].as_u64().unwrap_or_else(|| panic!("{name} {k}: {r}"));
        // 24 reads over 6 s, after both were drawn: each read shows the actor, labelled,
        // every corner of its box inside the picture (the camera follows them; a box
        // corner is at most 0.9 of the way to the edge with the 1.15 margin).
        assert_eq!(n("samples"), 24, "{r}");
        assert_eq!(n("shown"), 24, "{name}: {r}");
        assert_eq!(n("labelled"), 24, "{name}: {r}");
        assert_eq!(n("inside"), 24, "{name}: {r}");
    }
    assert!(out.path().join("actors.png").is_file());
    assert_eq!(r["page_errors"], serde_json::json!([]), "{r}");
}
