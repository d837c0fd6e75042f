// The browser harness of the view tests: Debian's chromium through puppeteer-core (software
// WebGL), a line protocol with the Rust test that hosts the world (`ASK {json}` out, one JSON
// line back on stdin), and picture measurements on the page's WebGL canvas.
import puppeteer from 'puppeteer-core';
import fs from 'node:fs';
import os from 'node:os';
import path from 'node:path';
import readline from 'node:readline';

export const W = 800;
export const H = 600;

const rl = readline.createInterface({ input: process.stdin });
const replies = [];
const waiting = [];
rl.on('line', (l) => { if (waiting.length) waiting.shift()(l); else replies.push(l); });

// Asks the Rust test something about the world; resolves with its JSON reply.
export async function ask(what) {
  process.stdout.write(`ASK ${JSON.stringify(what)}\n`);
  const line = replies.length ? replies.shift() : await new Promise((res) => waiting.push(res));
  const r = JSON.parse(line);
  if (r.error) throw new Error(`the world says: ${r.error}`);
  return r;
}

export function log(...a) {
  process.stdout.write(`LOG ${a.join(' ')}\n`);
}

export function check(ok, msg) {
  if (!ok) throw new Error(`check failed: ${msg}`);
  log(`ok: ${msg}`);
}

export async function launch() {
  const userDataDir = fs.mkdtempSync(path.join(os.tmpdir(), 'spidar-chromium-'));
  const browser = await puppeteer.launch({
    executablePath: process.env.SPIDAR_CHROMIUM || '/usr/bin/chromium',
    headless: true,
    userDataDir,
    // Self-signed certificates: the headset test serves the page over HTTPS with one it made.
    args: ['--no-sandbox', '--ignore-certificate-errors', '--disable-gpu', '--disable-quic', '--no-first-run', '--disable-background-networking',
      '--disable-component-update', '--disable-sync', '--use-angle=swiftshader', '--enable-unsafe-swiftshader',
      '--disable-background-timer-throttling', '--disable-renderer-backgrounding', '--disable-backgrounding-occluded-windows'],
  });
  return { browser, close: async () => { await browser.close(); fs.rmSync(userDataDir, { recursive: true, force: true }); } };
}

const pages = [];

// `before(page)`: run before the page loads (a script to add to every document, say).
export async function open(browser, url, query, size = { width: W, height: H }, before = null) {
  const page = await browser.newPage();
  pages.push(page);
  page.on('pageerror', (e) => log(`page error: ${e.message}`));
  await page.setViewport(size);
  if (before) await before(page);
  // 15 drawings a second: software WebGL shares the machine with the other tests. The bodies as
  // their collision shapes, whose colours the checks look for, unless the query says otherwise.
  const bodies = query.includes('bodies=') ? '' : 'bodies=shapes&';
  await page.goto(`${url}/?fps=15&${bodies}${query}`);
  await page.waitForFunction(() => window.spidarView && spidarView.state().seq !== null, { timeout: 60000 });
  return page;
}

export const state = (page) => page.evaluate(() => spidarView.state());

// Waits until the page has applied a frame of world time >= t.
export async function untilTime(page, t, timeout = 60000) {
  await page.waitForFunction((t) => spidarView.state().t >= t, { timeout, polling: 50 }, t);
}

// Pauses the page on its current frame and waits until the screen shows it.
export async function pause(page) {
  const p = await page.evaluate(() => spidarView.pause());
  await page.evaluate(() => spidarView.rendered());
  return p;
}

// Pixel classes: a colour family under any lighting.
export const RED = { r: 1 }; // red dominant: the virtual human, a character lying down
export const GREEN = { g: 1 }; // green dominant: a balancing character
export const FLASH = { flash: 1 }; // near white: a part flashing (a hit)
export const BLUE = { b: 1 }; // blue dominant: seat 0's body in the spar scene
// Any clear colour, not the grey floor or the dark sky: a body in its colour, skin, a flash.
export const COLOURED = { any: 1 };

// Counts the pixels of class `cls` in `rect` (CSS px) of the WebGL canvas, with their centroid, and
// a coarse mask (cells of `cell` px: 1 where the cell has any such pixel).
export function pixels(page, cls, rect = null, cell = 4) {
  return page.evaluate((cls, rect, cell) => {
    const src = document.querySelector('#view canvas');
    const c = document.createElement('canvas');
    c.width = src.width; c.height = src.height;
    const g = c.getContext('2d', { willReadFrequently: true });
    g.drawImage(src, 0, 0);
    const s = src.width / src.clientWidth;
    const r = rect ?? { x: 0, y: 0, w: src.clientWidth, h: src.clientHeight };
    const x0 = Math.max(0, Math.floor(r.x * s)); const y0 = Math.max(0, Math.floor(r.y * s));
    const x1 = Math.min(c.width, Math.ceil((r.x + r.w) * s)); const y1 = Math.min(c.height, Math.ceil((r.y + r.h) * s));
    const d = g.getImageData(0, 0, c.width, c.height).data;
    const is = (R, G, B) => {
      if (cls.flash) return R >= 200 && G >= 170 && B >= 120;
      if (cls.r) return R >= 70 && R > 1.8 * G && R > 1.8 * B;
      if (cls.b) return B >= 70 && B > 1.4 * R && B > 1.1 * G;
      if (cls.any) return Math.max(R, G, B) - Math.min(R, G, B) > 40;
      return G >= 60 && G > 1.25 * R && G > 1.15 * B;
    };
    let n = 0; let sx = 0; let sy = 0;
    const cw = Math.ceil(c.width / (cell * s)); const ch = Math.ceil(c.height / (cell * s));
    const mask = new Array(cw * ch).fill(0);
    for (let y = y0; y < y1; y++) {
      for (let x = x0; x < x1; x++) {
        const i = (y * c.width + x) * 4;
        if (!is(d[i], d[i + 1], d[i + 2])) continue;
        n++; sx += x; sy += y;
        mask[Math.floor(y / (cell * s)) * cw + Math.floor(x / (cell * s))] = 1;
      }
    }
    return { n, cx: n ? sx / n / s : null, cy: n ? sy / n / s : null, mask };
  }, cls, rect, cell);
}

export const around = (p, half) => ({ x: p.x - half, y: p.y - half, w: 2 * half, h: 2 * half });

export async function screenshot(page, file) {
  fs.mkdirSync(path.dirname(file), { recursive: true });
  await page.screenshot({ path: file });
  log(`wrote ${file}`);
}

// Runs a test body and reports: `RESULT ok` or `RESULT failed: why` (and exit code 1).
export async function run(body) {
  let b = null;
  try {
    b = await launch();
    await body(b.browser);
    process.stdout.write('RESULT ok\n');
    await b.close();
    process.exit(0);
  } catch (e) {
    // What the pages showed, for whoever reads the failure (tests/browser/out/).
    for (const [i, p] of pages.entries()) await screenshot(p, path.join('out', `failed-${i}.png`)).catch(() => {});
    process.stdout.write(`RESULT failed: ${e.stack || e}\n`);
    if (b) await b.close().catch(() => {});
    process.exit(1);
  }
}
