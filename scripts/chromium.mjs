// Headless Chromium driven over its DevTools protocol with Node's built-in
// WebSocket (no packages): shared by browser_check.mjs and screenshots.mjs.
// CHROMIUM overrides the browser (default /usr/bin/chromium).

import { spawn } from "node:child_process";
import { mkdtempSync, readFileSync, rmSync } from "node:fs";
import { tmpdir } from "node:os";
import { join, resolve } from "node:path";
import { pathToFileURL } from "node:url";

export const sleep = (ms) => new Promise((r) => setTimeout(r, ms));

// Starts Chromium, opens `file` and resolves once it has loaded. `onEvent`
// sees every protocol event. Returns `send`, `evaluate` and `finish(code,
// message)`, which stops the browser and exits.
export async function openPage(file, onEvent = () => {}, { timeoutMs = 60000 } = {}) {
  const chromium = process.env.CHROMIUM || "/usr/bin/chromium";
  const profile = mkdtempSync(join(tmpdir(), "mrbp-chromium-"));
  const browser = spawn(chromium, [
    "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
    "--disable-background-networking", "--disable-component-update", "--disable-sync",
    "--hide-scrollbars", `--user-data-dir=${profile}`, "--remote-debugging-port=0", "about:blank",
  ], { stdio: ["ignore", "ignore", "pipe"] });
  let finished = false;
  const finish = (code, message) => {
    if (finished) return;
    finished = true;
    if (message) (code === 0 ? console.log : console.error)(message);
    browser.kill("SIGKILL");
    try { rmSync(profile, { recursive: true, force: true }); } catch {}
    process.exit(code);
  };
  setTimeout(() => finish(1, `chromium: timed out after ${timeoutMs / 1000} s`), timeoutMs);

  // Chromium writes its DevTools port into the profile once it listens
  let port;
  for (let i = 0; i < 200 && !port; i++) {
    await sleep(100);
    try { port = readFileSync(join(profile, "DevToolsActivePort"), "utf8").split("\n")[0]; } catch {}
  }
  if (!port) finish(1, "chromium: did not start");
  const targets = await (await fetch(`http://127.0.0.1:${port}/json/list`)).json();
  const ws = new WebSocket(targets.find((t) => t.type === "page").webSocketDebuggerUrl);
  await new Promise((r, e) => { ws.onopen = r; ws.onerror = e; });

  let id = 0;
  const pending = new Map();
  let loaded;
  const loadedPromise = new Promise((r) => { loaded = r; });
  ws.onmessage = (event) => {
    const msg = JSON.parse(event.data);
    if (msg.id && pending.has(msg.id)) {
      pending.get(msg.id)(msg);
      pending.delete(msg.id);
      return;
    }
    if (msg.method === "Page.loadEventFired") loaded();
    onEvent(msg);
  };
  const send = (method, params = {}) =>
    new Promise((r) => { const n = ++id; pending.set(n, r); ws.send(JSON.stringify({ id: n, method, params })); });
  const evaluate = async (expression) => (await send("Runtime.evaluate", { expression, returnByValue: true })).result.result.value;

  for (const domain of ["Runtime", "Log", "Network", "Page"]) await send(`${domain}.enable`);
  return {
    send, evaluate, finish,
    async load(width) {
      if (width) await send("Emulation.setDeviceMetricsOverride", { width, height: 900, deviceScaleFactor: 1, mobile: false });
      await send("Page.navigate", { url: pathToFileURL(resolve(file)).href });
      await loadedPromise;
      await sleep(500);
    },
  };
}
