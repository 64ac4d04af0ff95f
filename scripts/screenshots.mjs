// Screenshots of a report's figures as a reader sees them: the page laid
// out 1400 px wide in headless Chromium, the last <figure> whose image alt
// is one of the given stems captured with its caption.
//
//   node --experimental-websocket scripts/screenshots.mjs REPORT.html OUT_DIR PREFIX STEM ...
//
// writes OUT_DIR/PREFIX-STEM.png (the README's images under docs/img/).

import { existsSync, mkdirSync, writeFileSync } from "node:fs";
import { join } from "node:path";
import { openPage } from "./chromium.mjs";

const [report, out, prefix, ...stems] = process.argv.slice(2);
if (!report || !existsSync(report) || !out || !stems.length) {
  console.error("usage: screenshots.mjs REPORT.html OUT_DIR PREFIX STEM ...");
  process.exit(2);
}
mkdirSync(out, { recursive: true });
const page = await openPage(report);
await page.load(1400);
for (const stem of stems) {
  const box = await page.evaluate(`(() => {
    // the last match: the figures section comes after the held-out runs' figures
    const img = Array.from(document.images).filter(i => (i.alt || "") === ${JSON.stringify(stem)}).pop();
    if (!img) return null;
    const f = img.closest("figure") || img;
    f.scrollIntoView();
    const r = f.getBoundingClientRect();
    return { x: r.left + window.scrollX, y: r.top + window.scrollY, width: r.width, height: r.height };
  })()`);
  if (!box) page.finish(1, `screenshots: no figure ${stem} in ${report}`);
  const shot = await page.send("Page.captureScreenshot", { format: "png", captureBeyondViewport: true, clip: { ...box, scale: 1 } });
  const file = join(out, `${prefix}-${stem}.png`);
  writeFileSync(file, Buffer.from(shot.result.data, "base64"));
  console.log(`wrote ${file} (${Math.round(box.width)} × ${Math.round(box.height)} px)`);
}
page.finish(0);
