// Drives the inssplat page in headless Chromium (playwright-core) against a running service,
// as a person would: choose the photos, reconstruct, wait for the 3D view, then type a label
// that the reconstruction reports and let the page highlight it; then submit the same photos as
// a batch job on /jobs and follow it to its end, and open /docs, all without exceptions. No request may leave the service's origin. It saves screenshots and
// prints one JSON line of measurements (pixels counted in the screenshots); the Rust test
// tests/tests/web_page.rs starts the service, runs this and judges the numbers.
//
//   node tests/web/page.mjs URL OUT_DIR PHOTO...
// env: INSSPLAT_WEB_DIR (node_modules with playwright-core), CHROMIUM (the browser binary).

import { createRequire } from "node:module";
import { join } from "node:path";
import { writeFileSync } from "node:fs";

const [url, out, ...photos] = process.argv.slice(2);
const require = createRequire(join(process.env.INSSPLAT_WEB_DIR, "noop.js"));
const { chromium } = require("playwright-core");

// The page's colours (web/colours.js): background of the 3D view, and the highlight.
const BACKGROUND = [0x15, 0x17, 0x1c];

/** Counts, in the PNG `shot`, pixels away from the background and pixels of the highlight. */
async function count(helper, shot) {
  return helper.evaluate(async ({ b64, bg }) => {
    const blob = await (await fetch(`data:image/png;base64,${b64}`)).blob();
    const bitmap = await createImageBitmap(blob);
    const ctx = new OffscreenCanvas(bitmap.width, bitmap.height).getContext("2d");
    ctx.drawImage(bitmap, 0, 0);
    const px = ctx.getImageData(0, 0, bitmap.width, bitmap.height).data;
    let drawn = 0;
    let highlight = 0;
    for (let i = 0; i < px.length; i += 4) {
      const [r, g, b] = [px[i], px[i + 1], px[i + 2]];
      if (Math.max(Math.abs(r - bg[0]), Math.abs(g - bg[1]), Math.abs(b - bg[2])) > 12) drawn++;
      if (r > 150 && b > 150 && g < 0.6 * Math.min(r, b)) highlight++;
    }
    return { pixels: px.length / 4, drawn, highlight };
  }, { b64: shot.toString("base64"), bg: BACKGROUND });
}

/** Screenshots the canvas until `done(counts)` or `seconds` pass; the last shot and counts. */
async function settle(page, helper, done, seconds) {
  const until = Date.now() + seconds * 1000;
  for (;;) {
    const shot = await page.locator("#viewer").screenshot();
    const counts = await count(helper, shot);
    if (done(counts) || Date.now() > until) return { shot, counts };
    await page.waitForTimeout(500);
  }
}

const browser = await chromium.launch({
  executablePath: process.env.CHROMIUM,
  // WebGL on the CPU (SwiftShader); none of Chromium's own background connections (the
  // machine has no network: they would only be refused).
  args: [
    "--no-sandbox", "--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--ignore-gpu-blocklist",
    "--disable-background-networking", "--disable-component-update", "--disable-sync", "--no-first-run", "--disable-quic",
  ],
});
try {
  const context = await browser.newContext({ viewport: { width: 1280, height: 900 } });
  // Requests for another origin, less those the content security policy refused to send.
  const foreign = new Set();
  const refused = [];
  context.on("request", (r) => new URL(r.url()).origin !== new URL(url).origin && !r.url().startsWith("data:") && foreign.add(r));
  context.on("requestfailed", (r) => foreign.has(r) && r.failure()?.errorText === "csp" && foreign.delete(r) && refused.push(r.url()));
  const page = await context.newPage();
  const errors = [];
  page.on("pageerror", (e) => errors.push(String(e)));
  page.on("console", (m) => m.type() === "error" && errors.push(m.text()));
  const helper = await context.newPage();
  const started = Date.now();
  const seconds = {};
  const lap = (name) => (seconds[name] = (Date.now() - started) / 1000);

  await page.goto(url);
  await page.locator("#photos").setInputFiles(photos);
  await page.locator("#refine-steps").fill("10");
  await page.locator("#run").click();
  await page.waitForSelector("body[data-state=ready], body[data-state=error]", { timeout: 180_000 });
  const progress = await page.locator("#progress").innerText();
  if ((await page.locator("body").getAttribute("data-state")) === "error") throw new Error(`the page failed: ${progress}; ${errors.join("; ")}`);
  lap("reconstructed");
  const summary = await page.locator("#summary").innerText();
  if (!/refined for 10 steps: input views [\d.]+ → [\d.]+ dB PSNR/.test(summary)) throw new Error(`the summary does not report the refinement asked for: ${summary}`);

  const scene = await settle(page, helper, (c) => c.drawn > c.pixels / 5, 60);
  writeFileSync(join(out, "scene.png"), scene.shot);
  lap("drawn");

  const labels = await page.locator("#instances li").evaluateAll((items) => items.map((i) => i.dataset.label));
  const label = labels[0];
  await page.locator("#query-text").fill(label);
  await page.locator("#query-text").press("Enter");
  await page.waitForSelector("#query-result[data-matches]", { timeout: 60_000 });
  const matches = Number(await page.locator("#query-result").getAttribute("data-matches"));
  const queried = await settle(page, helper, (c) => c.highlight > scene.counts.highlight + c.pixels / 50, 60);
  writeFileSync(join(out, "query.png"), queried.shot);
  lap("highlighted");
  await page.screenshot({ path: join(out, "page.png") });
  const masked = await page.locator("#views canvas").count();

  // The other pages load and run too (redoc renders the API; its CDN logo is refused by the
  // page's content security policy, a console message, so only exceptions count there).
  const other = await context.newPage();
  other.on("pageerror", (e) => errors.push(`${other.url()}: ${e}`));
  await other.goto(new URL("/jobs", url).href);
  await other.locator("#set-name").fill("room");
  await other.locator("#set-photos").setInputFiles(photos);
  await other.locator("#add-set button").click();
  await other.locator("#refine-steps").fill("5");
  await other.locator("#submit").click();
  const jobState = other.locator("article .state");
  await other.waitForFunction(() => /^(done|failed|cancelled) /.test(document.querySelector("article .state")?.textContent), null, { timeout: 120_000 });
  const job = { state: await jobState.innerText(), plyLinks: await other.locator('article a[href$="scene.ply"]').count() };
  lap("job");
  await other.goto(new URL("/docs", url).href);
  await other.getByText("/v1/reconstruct").first().waitFor({ timeout: 30_000 });
  lap("other_pages");

  console.log(JSON.stringify({ seconds, labels, label, matches, masked, progress, scene: scene.counts, query: queried.counts, job, errors, foreign: [...foreign].map((r) => r.url()), refused }));
} finally {
  await browser.close();
}
