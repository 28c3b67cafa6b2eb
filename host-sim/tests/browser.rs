//! Every HTML page the commands write, opened in a real browser: Debian's headless
//! Chromium driven by playwright-core (`scripts/browser/check_pages.mjs`). A page passes
//! when it loads, every image on it decoded (natural width above zero), the browser
//! logged no error and no request failed, and every file it links or names in its text
//! exists beside it.
//!
//! `scripts/test.sh` installs Chromium and playwright-core and sets
//! `DNCAL_REQUIRE_BROWSER=1`, so there a missing browser fails the test; elsewhere (a
//! developer's `cargo test`) it skips with one line.

mod support;

use std::path::{Path, PathBuf};
use std::process::Command;

use support::succeed;

/// The checker script and the browser, or why the test cannot run.
fn browser() -> Option<PathBuf> {
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("../scripts/browser/check_pages.mjs");
    let chromium = std::env::var_os("CHROMIUM").map(PathBuf::from).unwrap_or_else(|| "/usr/bin/chromium".into());
    let modules = script.with_file_name("node_modules").join("playwright-core");
    let node = Command::new("node").arg("--version").output().is_ok_and(|o| o.status.success());
    let missing = [(!node, "node"), (!chromium.is_file(), "Chromium (/usr/bin/chromium or $CHROMIUM)"), (!modules.is_dir(), "playwright-core (npm ci in scripts/browser)")]
        .into_iter()
        .filter_map(|(absent, what)| absent.then_some(what))
        .collect::<Vec<_>>();
    if missing.is_empty() {
        return Some(script);
    }
    let message = format!("the browser test needs {}; scripts/test.sh installs them", missing.join(", "));
    assert!(std::env::var_os("DNCAL_REQUIRE_BROWSER").is_none(), "{message}");
    eprintln!("skipping: {message}");
    None
}

/// The checker's report of each page.
fn open_in_browser(script: &Path, pages: &[PathBuf]) -> Vec<serde_json::Value> {
    let out = Command::new("node").arg(script).args(pages).output().expect("node runs");
    assert!(out.status.success(), "check_pages.mjs failed: {}", String::from_utf8_lossy(&out.stderr));
    let report: serde_json::Value = serde_json::from_slice(&out.stdout).expect("the checker prints JSON");
    report.as_array().expect("one entry per page").clone()
}

/// Local files a page refers to: its links and image sources (not `http:`, `mailto:` or
/// in-page anchors), and file names its text mentions that are not the label of such a
/// link (a link's label names its file, which the link already locates).
fn referenced_files(page: &serde_json::Value) -> Vec<String> {
    let strings = |key: &str| -> Vec<String> { page[key].as_array().into_iter().flatten().filter_map(|v| v.as_str().map(String::from)).collect() };
    let mut files: Vec<String> = strings("links").into_iter().chain(page["images"].as_array().into_iter().flatten().filter_map(|i| i["src"].as_str().map(String::from))).collect();
    files.retain(|f| !(f.starts_with('#') || f.contains("://") || f.starts_with("mailto:")));
    let linked = |word: &str| files.iter().any(|f| f == word || f.ends_with(&format!("/{word}")));
    // File names in the text: a word ending in one of the extensions the commands write.
    let text = page["text"].as_str().unwrap_or("");
    let mut named = Vec::new();
    for word in text.split(|c: char| c.is_whitespace() || "()[],;:\"'`".contains(c)) {
        let word = word.trim_end_matches('.');
        if [".png", ".fits", ".html", ".toml", ".json", ".bin"].iter().any(|e| word.ends_with(e)) && !word.contains("://") && word.len() > 5 && !linked(word) {
            named.push(word.to_string());
        }
    }
    files.extend(named);
    files.sort();
    files.dedup();
    files
}

/// Judges one page's report; `dir` is the page's folder.
fn assert_page_works(page: &serde_json::Value, dir: &Path, min_images: usize) {
    let name = page["page"].as_str().unwrap_or("?");
    assert_eq!(page["ok"], true, "{name} did not load");
    for key in ["consoleErrors", "pageErrors", "failedRequests"] {
        assert_eq!(page[key].as_array().map(Vec::len), Some(0), "{name}: {key}: {}", page[key]);
    }
    let images = page["images"].as_array().expect("images");
    assert!(images.len() >= min_images, "{name}: {} images, expected at least {min_images}", images.len());
    for image in images {
        assert!(image["complete"] == true && image["naturalWidth"].as_u64().unwrap_or(0) > 0, "{name}: image not decoded: {image}");
        assert!(image["alt"].as_str().is_some_and(|a| !a.is_empty()), "{name}: image without alt text: {image}");
    }
    let referenced = referenced_files(page);
    let missing: Vec<&String> = referenced.iter().filter(|f| !dir.join(f).exists()).collect();
    assert!(missing.is_empty(), "{name} refers to files that are not there: {missing:?}");
    assert!(!page["title"].as_str().unwrap_or("").is_empty(), "{name} has no title");
}

#[test]
fn every_page_the_commands_write_works_in_chromium() {
    let Some(script) = browser() else { return };
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    // The demo writes its report and two diagnosis pages; emva its data sheet.
    succeed(&["demo", "-o", "demo", "--frames", "1", "-q"], d);
    let descriptor = support::write_set(&d.join("set"), &support::photons(20, 20000.0), support::linear);
    succeed(&["emva", descriptor.to_str().unwrap(), "-o", "emva", "-q"], d);
    let pages = [("demo/report.html", 6), ("demo/diagnose/report.html", 1), ("demo/diagnose-linearity/report.html", 1), ("emva/datasheet.html", 3)];
    // Every HTML file the commands wrote is in the list (a new page gets checked).
    let mut written = Vec::new();
    for sub in ["demo", "demo/diagnose", "demo/diagnose-linearity", "demo/linearity", "emva"] {
        for entry in std::fs::read_dir(d.join(sub)).unwrap() {
            let path = entry.unwrap().path();
            if path.extension().is_some_and(|e| e == "html") {
                written.push(path.strip_prefix(d).unwrap().to_string_lossy().into_owned());
            }
        }
    }
    written.sort();
    let mut listed: Vec<String> = pages.iter().map(|(p, _)| p.to_string()).collect();
    listed.sort();
    assert_eq!(written, listed);
    let paths: Vec<PathBuf> = pages.iter().map(|(p, _)| d.join(p)).collect();
    let report = open_in_browser(&script, &paths);
    assert_eq!(report.len(), pages.len());
    for (page, (path, min_images)) in report.iter().zip(pages) {
        let at = d.join(path);
        assert_page_works(page, at.parent().unwrap(), min_images);
    }
}

#[test]
fn the_checker_catches_a_broken_image_and_a_missing_file() {
    // The oracle's own test: a page with an image that does not decode and a link to a
    // file that is not there must fail the checks above.
    let Some(script) = browser() else { return };
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::fs::write(d.join("broken.png"), b"not a png").unwrap();
    std::fs::write(d.join("page.html"), "<!DOCTYPE html><html><head><title>t</title></head><body><img src=\"broken.png\" alt=\"x\"><a href=\"gone.fits\">data</a><p>see absent.png</p></body></html>").unwrap();
    let report = open_in_browser(&script, &[d.join("page.html")]);
    let page = &report[0];
    assert_eq!(page["images"][0]["naturalWidth"], 0, "{page}");
    let referenced = referenced_files(page);
    assert!(referenced.contains(&"gone.fits".to_string()) && referenced.contains(&"absent.png".to_string()), "{referenced:?}");
    let caught = std::panic::catch_unwind(|| assert_page_works(page, d, 1));
    assert!(caught.is_err());
}
