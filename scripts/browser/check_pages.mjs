// Opens each HTML page given on the command line in headless Chromium (Debian's
// /usr/bin/chromium, or $CHROMIUM) and prints one JSON object per page on stdout: its
// images (loaded or not, natural size), console errors, uncaught page errors, requests
// that failed, and every local link and image source it refers to. The Rust test
// host-sim/tests/browser.rs runs the commands that write the pages and judges this.
import { chromium } from "playwright-core";
import { pathToFileURL } from "node:url";
import { mkdtempSync, rmSync } from "node:fs";
import { tmpdir } from "node:os";
import { join, resolve } from "node:path";

const pages = process.argv.slice(2);
if (pages.length === 0) {
  console.error("usage: node check_pages.mjs PAGE.html...");
  process.exit(2);
}
const profile = mkdtempSync(join(tmpdir(), "dncal-chromium-"));
// The flags that keep Chromium off the network on a closed machine (it would retry
// connections and look up Google's hosts at every start) and out of a sandbox root
// cannot create.
const browser = await chromium.launchPersistentContext(profile, {
  executablePath: process.env.CHROMIUM || "/usr/bin/chromium",
  headless: true,
  args: [
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
  ],
});
const results = [];
try {
  for (const file of pages) {
    const page = await browser.newPage();
    const consoleErrors = [];
    const pageErrors = [];
    const failedRequests = [];
    page.on("console", (m) => {
      if (m.type() === "error") consoleErrors.push(m.text());
    });
    page.on("pageerror", (e) => pageErrors.push(String(e)));
    page.on("requestfailed", (r) => failedRequests.push(`${r.url()}: ${r.failure()?.errorText}`));
    const response = await page.goto(pathToFileURL(resolve(file)).href, { waitUntil: "load" });
    const found = await page.evaluate(() => ({
      title: document.title,
      images: [...document.images].map((i) => ({
        src: i.getAttribute("src"),
        complete: i.complete,
        naturalWidth: i.naturalWidth,
        naturalHeight: i.naturalHeight,
        alt: i.getAttribute("alt"),
      })),
      links: [...document.querySelectorAll("a[href]")].map((a) => a.getAttribute("href")),
      tables: document.querySelectorAll("table").length,
      text: document.body ? document.body.innerText : "",
    }));
    results.push({ page: file, ok: response !== null && response.ok(), consoleErrors, pageErrors, failedRequests, ...found });
    await page.close();
  }
} finally {
  await browser.close();
  rmSync(profile, { recursive: true, force: true });
}
process.stdout.write(JSON.stringify(results, null, 1) + "\n");
