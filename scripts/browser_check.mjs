// Opens an HTML report in headless Chromium and fails (exit 1) on console
// errors, uncaught exceptions, failed loads or images that did not decode.
// No packages needed: Chromium's DevTools protocol over Node's WebSocket.
//
//   node --experimental-websocket scripts/browser_check.mjs REPORT.html [SECTION_ID ...]
//
// CHROMIUM overrides the browser (default /usr/bin/chromium).

import { spawn } from "node:child_process";
import { mkdtempSync, readFileSync, rmSync, existsSync } from "node:fs";
import { tmpdir } from "node:os";
import { join, resolve } from "node:path";
import { pathToFileURL } from "node:url";

const [report, ...sections] = process.argv.slice(2);
if (!report || !existsSync(report)) {
  console.error(`browser_check: no such report: ${report}`);
  process.exit(2);
}
const chromium = process.env.CHROMIUM || "/usr/bin/chromium";
const profile = mkdtempSync(join(tmpdir(), "mrbp-chromium-"));
const browser = spawn(chromium, [
  "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
  "--disable-background-networking", "--disable-component-update", "--disable-sync",
  `--user-data-dir=${profile}`, "--remote-debugging-port=0", "about:blank",
], { stdio: ["ignore", "ignore", "pipe"] });

const sleep = (ms) => new Promise((r) => setTimeout(r, ms));
let finished = false;
function finish(code, message) {
  if (finished) return;
  finished = true;
  if (message) (code === 0 ? console.log : console.error)(message);
  browser.kill("SIGKILL");
  try { rmSync(profile, { recursive: true, force: true }); } catch {}
  process.exit(code);
}
setTimeout(() => finish(1, "browser_check: timed out after 60 s"), 60000);

// Chromium writes its DevTools port into the profile once it listens
let port;
for (let i = 0; i < 200 && !port; i++) {
  await sleep(100);
  try { port = readFileSync(join(profile, "DevToolsActivePort"), "utf8").split("\n")[0]; } catch {}
}
if (!port) finish(1, "browser_check: Chromium did not start");
const targets = await (await fetch(`http://127.0.0.1:${port}/json/list`)).json();
const page = targets.find((t) => t.type === "page");
const ws = new WebSocket(page.webSocketDebuggerUrl);
await new Promise((r, e) => { ws.onopen = r; ws.onerror = e; });

let id = 0;
const pending = new Map();
const problems = [];
let loaded;
const loadedPromise = new Promise((r) => { loaded = r; });
ws.onmessage = (event) => {
  const msg = JSON.parse(event.data);
  if (msg.id && pending.has(msg.id)) {
    pending.get(msg.id)(msg);
    pending.delete(msg.id);
    return;
  }
  switch (msg.method) {
    case "Runtime.consoleAPICalled":
      if (msg.params.type === "error" || msg.params.type === "assert")
        problems.push(`console.${msg.params.type}: ${msg.params.args.map((a) => a.value ?? a.description).join(" ")}`);
      break;
    case "Runtime.exceptionThrown":
      problems.push(`exception: ${msg.params.exceptionDetails.text} ${msg.params.exceptionDetails.exception?.description ?? ""}`);
      break;
    case "Log.entryAdded":
      if (msg.params.entry.level === "error") problems.push(`log: ${msg.params.entry.text} ${msg.params.entry.url ?? ""}`);
      break;
    case "Network.loadingFailed":
      problems.push(`failed load: ${msg.params.errorText}`);
      break;
    case "Page.loadEventFired":
      loaded();
      break;
  }
};
const send = (method, params = {}) =>
  new Promise((r) => { const n = ++id; pending.set(n, r); ws.send(JSON.stringify({ id: n, method, params })); });

for (const domain of ["Runtime", "Log", "Network", "Page"]) await send(`${domain}.enable`);
await send("Page.navigate", { url: pathToFileURL(resolve(report)).href });
await loadedPromise;
await sleep(500);
const evaluate = async (expression) => (await send("Runtime.evaluate", { expression, returnByValue: true })).result.result.value;
const images = await evaluate("document.images.length");
const broken = await evaluate(
  "Array.from(document.images).filter(i => !i.complete || i.naturalWidth === 0).map(i => i.alt || i.src.slice(0, 40))");
const missing = [];
for (const s of sections) if (!(await evaluate(`!!document.getElementById(${JSON.stringify(s)})`))) missing.push(s);
if (images === 0) problems.push("no images in the report");
for (const b of broken) problems.push(`image did not load: ${b}`);
for (const s of missing) problems.push(`section missing: #${s}`);
if (problems.length) finish(1, `browser_check: ${report}\n  ${problems.join("\n  ")}`);
finish(0, `browser_check: ${report}: ${images} images decoded, ${sections.length} sections found, no console errors`);
