// node shoot.mjs TRIAL.mcap OUT.png: open a trial log in Foxglove Studio with docs/foxglove-layout.json,
// at $SHOT_TIME (default: the start), in headless Chromium (Debian's /usr/bin/chromium), and save a screenshot.
//
// Foxglove Studio is the @foxglove/studio-base bundle from npm (its App component, with
// an in-memory layout store holding our layout); this script serves it, the page in page/,
// and the log (with HTTP Range requests, which Foxglove's remote-file reader needs) on
// loopback. Exits 1, naming them, if Foxglove reports problems reading the log or the page fails.
import { createReadStream, statSync } from "node:fs";
import { createServer } from "node:http";
import { dirname, extname, join, resolve } from "node:path";
import { fileURLToPath } from "node:url";
import { chromium } from "playwright-core";

const here = dirname(fileURLToPath(import.meta.url));
const [trial, out] = process.argv.slice(2);
if (!trial || !out) {
  console.error("usage: node shoot.mjs TRIAL.mcap OUT.png");
  process.exit(2);
}
const files = {
  "/index.html": join(here, "page/index.html"),
  "/main.js": join(here, "page/main.js"),
  "/layout.json": join(here, "../foxglove-layout.json"),
  "/trial.mcap": resolve(trial),
  "/react.production.min.js": join(here, "node_modules/react/umd/react.production.min.js"),
  "/react-dom.production.min.js": join(here, "node_modules/react-dom/umd/react-dom.production.min.js"),
};
const assets = join(here, "node_modules/@foxglove/studio-base/assets");
const types = { ".html": "text/html", ".js": "text/javascript", ".json": "application/json", ".wasm": "application/wasm",
                ".png": "image/png", ".woff2": "font/woff2", ".mcap": "application/octet-stream" };

const server = createServer((req, res) => {
  const path = new URL(req.url, "http://x").pathname;
  const file = files[path] ?? (path.startsWith("/assets/") && !path.includes("..") ? join(assets, path.slice(8)) : null);
  let size;
  try { size = statSync(file).size; } catch { res.writeHead(404).end(); return; }
  const headers = { "Content-Type": types[extname(file)] ?? "application/octet-stream", "Accept-Ranges": "bytes" };
  const range = /^bytes=(\d*)-(\d*)$/.exec(req.headers.range ?? "");
  if (range) {
    const start = range[1] ? Number(range[1]) : size - Number(range[2]);
    const end = range[1] && range[2] ? Math.min(Number(range[2]), size - 1) : size - 1;
    res.writeHead(206, { ...headers, "Content-Range": `bytes ${start}-${end}/${size}`, "Content-Length": end - start + 1 });
    createReadStream(file, { start, end }).pipe(res);
  } else {
    res.writeHead(200, { ...headers, "Content-Length": size });
    createReadStream(file).pipe(res);
  }
});
await new Promise((ok) => server.listen(0, "127.0.0.1", ok));
const base = `http://127.0.0.1:${server.address().port}`;

const at = process.env.SHOT_TIME;  // the moment to show (RFC 3339); make.sh picks 60 % of the trial
const query = new URLSearchParams({ ds: "remote-file", "ds.url": `${base}/trial.mcap`, layoutId: "tumblebot" });
if (at) query.set("time", at);

const browser = await chromium.launch({ executablePath: "/usr/bin/chromium", args: [
  "--no-sandbox", "--disable-gpu", "--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--disable-quic",
  "--no-first-run", "--disable-background-networking", "--disable-component-update", "--disable-sync"] });
const problems = [];
try {
  const page = await browser.newPage({ viewport: { width: 1600, height: 900 } });
  page.on("pageerror", (e) => problems.push(`page error: ${e}`));
  page.on("console", (m) => {
    // Foxglove reports a log it cannot read (a schema it refuses, a message it cannot decode) as a player problem
    if (m.type() === "error" && m.text().includes("Player problem")) problems.push(m.text().slice(0, 400));
  });
  await page.goto(`${base}/index.html?${query}`, { timeout: 300_000 });
  await page.getByText("/robot/model").first().waitFor({ timeout: 300_000 });  // the log is open (generous: CI is busy)
  await page.waitForTimeout(8_000);  // the 3D panel and plots draw
  const hint = page.getByText("Open settings to configure").locator("..").getByRole("button");
  if (await hint.count()) await hint.first().click();  // the 3D panel's first-use hint
  await page.waitForTimeout(500);
  await page.screenshot({ path: out });
  console.log(`wrote ${out}`);
} finally {
  await browser.close();
  server.close();
}
for (const p of problems) console.error(`shoot.mjs: Foxglove: ${p}`);
process.exit(problems.length ? 1 : 0);
