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
    // Every HTML file the commands wrote, in any folder, is in the list (a new page gets
    // checked).
    fn html_under(dir: &Path, root: &Path, found: &mut Vec<String>) {
        for entry in std::fs::read_dir(dir).unwrap() {
            let path = entry.unwrap().path();
            if path.is_dir() {
                html_under(&path, root, found);
            } else if path.extension().is_some_and(|e| e == "html") {
                found.push(path.strip_prefix(root).unwrap().to_string_lossy().into_owned());
            }
        }
    }
    let mut written = Vec::new();
    html_under(d, d, &mut written);
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

/// A 2 x 2 grey PNG.
fn tiny_png() -> Vec<u8> {
    let mut bytes = Vec::new();
    let mut encoder = png::Encoder::new(&mut bytes, 2, 2);
    encoder.set_color(png::ColorType::Grayscale);
    encoder.set_depth(png::BitDepth::Eight);
    encoder.write_header().unwrap().write_image_data(&[128; 4]).unwrap();
    bytes
}

#[test]
fn the_checker_catches_each_fault_alone() {
    // The oracle's own test: a sound page passes; the same page with one fault each (an
    // image that does not decode, a link to a file that is not there, a file named in the
    // text that is not there, an image without alt text) fails.
    let Some(script) = browser() else { return };
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::fs::write(d.join("good.png"), tiny_png()).unwrap();
    std::fs::write(d.join("broken.png"), b"not a png").unwrap();
    std::fs::write(d.join("data.fits"), b"x").unwrap();
    let page = |body: &str| format!("<!DOCTYPE html><html><head><title>t</title></head><body>{body}</body></html>");
    let sound = "<img src=\"good.png\" alt=\"a figure\"><a href=\"data.fits\">data</a><p>see good.png</p>";
    let faults = [
        ("broken", "<img src=\"broken.png\" alt=\"a figure\"><a href=\"data.fits\">data</a>"),
        ("link", "<img src=\"good.png\" alt=\"a figure\"><a href=\"gone.fits\">data</a>"),
        ("named", "<img src=\"good.png\" alt=\"a figure\"><p>see absent.png</p>"),
        ("alt", "<img src=\"good.png\"><a href=\"data.fits\">data</a>"),
    ];
    std::fs::write(d.join("sound.html"), page(sound)).unwrap();
    for (name, body) in faults {
        std::fs::write(d.join(format!("{name}.html")), page(body)).unwrap();
    }
    let mut pages = vec![d.join("sound.html")];
    pages.extend(faults.iter().map(|(name, _)| d.join(format!("{name}.html"))));
    let report = open_in_browser(&script, &pages);
    assert_page_works(&report[0], d, 1);
    for (page, (name, _)) in report[1..].iter().zip(faults) {
        let caught = std::panic::catch_unwind(|| assert_page_works(page, d, 1));
        assert!(caught.is_err(), "the {name} fault passed: {page}");
    }
}
