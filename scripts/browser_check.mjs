// Opens an HTML report in headless Chromium and fails (exit 1) on console
// errors, uncaught exceptions, failed loads or images that did not decode.
// No packages needed: Chromium's DevTools protocol over Node's WebSocket.
//
//   node --experimental-websocket scripts/browser_check.mjs REPORT.html [SECTION_ID ...]
//
// CHROMIUM overrides the browser (default /usr/bin/chromium).

import { existsSync } from "node:fs";
import { openPage } from "./chromium.mjs";

const [report, ...sections] = process.argv.slice(2);
if (!report || !existsSync(report)) {
  console.error(`browser_check: no such report: ${report}`);
  process.exit(2);
}
const problems = [];
const page = await openPage(report, (msg) => {
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
  }
});
await page.load();
const images = await page.evaluate("document.images.length");
const broken = await page.evaluate(
  "Array.from(document.images).filter(i => !i.complete || i.naturalWidth === 0).map(i => i.alt || i.src.slice(0, 40))");
const missing = [];
for (const s of sections) if (!(await page.evaluate(`!!document.getElementById(${JSON.stringify(s)})`))) missing.push(s);
if (images === 0) problems.push("no images in the report");
for (const b of broken) problems.push(`image did not load: ${b}`);
for (const s of missing) problems.push(`section missing: #${s}`);
if (problems.length) page.finish(1, `browser_check: ${report}\n  ${problems.join("\n  ")}`);
page.finish(0, `browser_check: ${report}: ${images} images decoded, ${sections.length} sections found, no console errors`);
