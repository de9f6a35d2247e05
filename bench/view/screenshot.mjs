// Opens the Rerun web viewer (served by `rerun --web-viewer FILE.rrd`) in headless Chromium,
// waits for it to draw, records the console's errors and writes a screenshot.
//   node bench/view/screenshot.mjs URL OUT.png [SECONDS]
// playwright-core drives Debian's /usr/bin/chromium (no browser download); run by
// bench/view/screenshot.sh, which starts the viewer. Requests to other hosts than the viewer's
// (the viewer asks the web for news and fonts; this machine's network is closed) are listed
// apart, with the console errors they cause; any other console error fails the script.
import { chromium } from "playwright-core";

const [url, out, seconds = "40"] = process.argv.slice(2);
const local = (u) => /^(https?|wss?):\/\/(127\.0\.0\.1|localhost)(:|\/)/.test(u) || u.startsWith("data:") || u.startsWith("blob:");
const browser = await chromium.launch({
  executablePath: process.env.CHROMIUM ?? "/usr/bin/chromium",
  args: [
    "--no-sandbox", "--disable-gpu-sandbox", "--no-first-run", "--disable-quic",
    "--disable-background-networking", "--disable-component-update", "--disable-sync",
    "--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--ignore-gpu-blocklist",
  ],
});
const page = await browser.newPage({ viewport: { width: 1600, height: 1000 } });
const external = [];
// Requests off this machine are refused here rather than left to fail on name lookup.
await page.route((u) => !local(u.toString()), (route) => {
  external.push(route.request().url());
  return route.abort("blockedbyclient");
});
const errors = [];
page.on("console", (m) => { if (m.type() === "error") errors.push(m.text()); });
page.on("pageerror", (e) => errors.push(String(e)));
await page.goto(url, { waitUntil: "load" });
await page.waitForTimeout(Number(seconds) * 1000);
await page.screenshot({ path: out });
await browser.close();
// The console errors of refused external requests: "Failed to load resource:
// net::ERR_BLOCKED_BY_CLIENT" and the fetch that made it.
const ofExternal = (e) => e.includes("ERR_BLOCKED_BY_CLIENT") || (external.length > 0 && e.startsWith("TypeError: Failed to fetch"));
const viewerErrors = errors.filter((e) => !ofExternal(e));
console.log(JSON.stringify({ url, out, external_requests_refused: [...new Set(external)],
  console_errors_of_those: errors.length - viewerErrors.length, viewer_errors: viewerErrors }, null, 2));
process.exit(viewerErrors.length ? 1 : 0);
