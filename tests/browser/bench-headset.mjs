// The benchmarks' headset: Debian's chromium through puppeteer-core with a WebXR headset emulated
// inside the page (npm `iwer`, as the headset test has it), on the live view at URL, in an
// immersive session for as long as this script's stdin stays open. Run by `spidar bench view
// --headset` (lab/src/browser.rs), not by the tests: `node bench-headset.mjs URL WIDTH HEIGHT [QUERY]`.
//
// Lines out: `CHROMIUM PID` once the browser runs (the caller stops its process group if this
// script dies), `PRESENTING` once the page draws in the session, `FAILED why` if it cannot. On
// stdin's end the browser is closed and the script exits.
import fs from 'node:fs';
import os from 'node:os';
import path from 'node:path';
import puppeteer from 'puppeteer-core';

const [url, width, height, query = ''] = process.argv.slice(2);
const say = (l) => process.stdout.write(`${l}\n`);
const IWER_JS = fs.readFileSync(new URL('./node_modules/iwer/build/iwer.min.js', import.meta.url), 'utf8');

const userDataDir = fs.mkdtempSync(path.join(os.tmpdir(), 'spidar-bench-headset-'));
let browser = null;
async function close(code) {
  if (browser) await browser.close().catch(() => {});
  fs.rmSync(userDataDir, { recursive: true, force: true });
  process.exit(code);
}
process.stdin.on('end', () => close(0));
process.stdin.resume();

try {
  // The flags of lab/src/browser.rs's screen browser (software WebGL, nothing in the background).
  browser = await puppeteer.launch({
    executablePath: process.env.SPIDAR_CHROMIUM || '/usr/bin/chromium',
    headless: true,
    userDataDir,
    args: ['--no-sandbox', '--ignore-certificate-errors', '--disable-gpu', '--no-first-run', '--disable-background-networking',
      '--disable-component-update', '--disable-sync', '--use-angle=swiftshader', '--enable-unsafe-swiftshader',
      '--disable-background-timer-throttling', '--disable-renderer-backgrounding', '--disable-backgrounding-occluded-windows'],
  });
  say(`CHROMIUM ${browser.process().pid}`);
  const page = await browser.newPage();
  await page.setViewport({ width: Number(width), height: Number(height) });
  await page.evaluateOnNewDocument(IWER_JS);
  await page.evaluateOnNewDocument(() => {
    const d = new IWER.XRDevice(IWER.metaQuest3);
    d.installRuntime({ forceInstall: true }); // over chromium's own navigator.xr
    d.stereoEnabled = true; // both eyes, side by side on the canvas
    d.position.set(0, 1.5, 0);
    window.emulatedHeadset = d;
  });
  await page.goto(`${url}/?${query}`);
  await page.waitForFunction(() => window.spidarView && spidarView.xr.state().supported && spidarView.state().seq !== null,
    { timeout: 60000 });
  await page.click('#xr-button');
  // In the session and drawing there (two pictures more after it began).
  await page.waitForFunction(() => spidarView.xr.state().presenting, { timeout: 60000 });
  const renders = await page.evaluate(() => spidarView.state().renders);
  await page.waitForFunction((r) => spidarView.xr.state().presenting && spidarView.state().renders >= r + 2,
    { timeout: 60000 }, renders);
  say('PRESENTING');
} catch (e) {
  say(`FAILED ${String(e.message || e).split('\n')[0]}`);
  await close(1);
}
