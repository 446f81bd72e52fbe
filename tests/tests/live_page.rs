//! The learner's live page at `/`, in a real browser: headless Chromium
//! (Debian's `chromium`) loads it from a learner with two actors, and the
//! curves are drawn with data, the actors listed and the config shown; a
//! screenshot is saved (the README's, docs/figures/live-page.png, comes from this test). Without
//! Chromium the browser part is skipped with a message, except where
//! `AFX_REQUIRE_BROWSER` is set (CI), where it fails.

use std::path::Path;
use std::process::Command;
use std::time::Duration;

use system_tests::{http_get, scratch_dir, start_actor, wait_for, Learner};

/// The Chromium binary, if one is installed.
fn chromium() -> Option<String> {
    ["chromium", "chromium-browser", "google-chrome"]
        .into_iter()
        .find(|name| {
            Command::new(name)
                .arg("--version")
                .output()
                .is_ok_and(|o| o.status.success())
        })
        .map(String::from)
}

/// Runs headless Chromium on `url` with `args`, letting the page's scripts
/// run for a few seconds of virtual time first.
fn headless(browser: &str, url: &str, args: &[&str], profile: &Path) -> std::process::Output {
    Command::new(browser)
        .args(["--headless", "--no-sandbox", "--disable-gpu"])
        .arg(format!("--user-data-dir={}", profile.display()))
        .args(["--virtual-time-budget=8000", "--window-size=1280,1500"])
        .args(args)
        .arg(url)
        .output()
        .expect("running chromium")
}

#[test]
fn the_live_page_draws_the_curves_in_a_browser() {
    let dir = scratch_dir("live-page");
    let prefix = format!("it-live-{}", std::process::id());
    let (learner, config) = Learner::start_bandit(&dir, &prefix);
    let _actors: Vec<_> = (0..2)
        .map(|id| start_actor(id, &prefix, &dir, &["--config", &config]))
        .collect();
    wait_for(Duration::from_secs(30), "40 episodes", || {
        (learner.status()["episodes"].as_u64() >= Some(40)).then_some(())
    });

    let (code, page) = http_get(&learner.addr, "/").expect("the learner answers /");
    assert_eq!(code, 200);
    assert!(page.contains("<title>affordance-explorer: live training</title>"));
    assert!(
        !page.contains("http://") && !page.contains("https://"),
        "the page fetches nothing from elsewhere"
    );
    let (code, config_text) = http_get(&learner.addr, "/api/config").expect("/api/config");
    assert_eq!(code, 200);
    assert!(
        config_text.contains("env = \"bandit-fixture\""),
        "{config_text}"
    );

    let Some(browser) = chromium() else {
        assert!(
            std::env::var_os("AFX_REQUIRE_BROWSER").is_none(),
            "AFX_REQUIRE_BROWSER is set but no chromium is installed"
        );
        eprintln!("skipping the browser check: `apt-get install chromium` to run it");
        return;
    };
    let url = format!("http://{}/", learner.addr);
    let dom = headless(&browser, &url, &["--dump-dom"], &dir.join("profile-dom"));
    let dom_text = String::from_utf8_lossy(&dom.stdout);
    assert!(
        dom.status.success(),
        "{}",
        String::from_utf8_lossy(&dom.stderr)
    );
    // The bandit fixture reports the return and the success rate; each of
    // their curves has a point per episode and a drawn line.
    for key in ["episode_return", "interaction_success_rate"] {
        let marker = format!("id=\"chart-{key}\" data-points=\"");
        let at = dom_text
            .find(&marker)
            .unwrap_or_else(|| panic!("no chart of {key} in:\n{dom_text}"));
        let points: usize = dom_text[at + marker.len()..]
            .split('"')
            .next()
            .and_then(|n| n.parse().ok())
            .expect("a point count");
        assert!(points >= 40, "{key}: {points} points");
        assert!(
            dom_text[at..].contains("<polyline class=\"curve\" points=\""),
            "{key} has no line"
        );
    }
    assert!(
        dom_text.contains("<td>0</td><td class=\"\">yes</td>"),
        "actor 0 listed alive:\n{dom_text}"
    );
    assert!(dom_text.contains("bandit-fixture"), "the config is shown");
    assert!(
        dom_text.contains("not scored: the task has no U-Net to score"),
        "the validation section says why it is empty:\n{dom_text}"
    );
    // Actor 0's steps/s: the learner's rate over its chunks, never "–" or 0.0
    // once it has sent a few.
    let row = dom_text
        .find("<td>0</td><td class=\"\">yes</td>")
        .map(|at| &dom_text[at..])
        .expect("actor 0's row");
    let rate: f64 = row
        .split("<td>")
        .nth(3) // after the id and alive cells, and env steps
        .and_then(|cell| cell.split('<').next())
        .and_then(|n| n.parse().ok())
        .unwrap_or_else(|| panic!("actor 0's steps/s in {row}"));
    assert!(rate > 0.0, "actor 0 runs at {rate} steps/s");

    let shot = dir.join("live-page.png");
    let out = headless(
        &browser,
        &url,
        &[&format!("--screenshot={}", shot.display())],
        &dir.join("profile-shot"),
    );
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let png = std::fs::read(&shot).expect("the screenshot");
    assert!(
        png.starts_with(b"\x89PNG") && png.len() > 10_000,
        "a real screenshot"
    );
    eprintln!("live page screenshot: {}", shot.display());
}
