// The live view's rig overlays in a browser, run by tests/tests/hil/rigview.rs on `spidar run`'s
// path (simulated rig -> rt-loop -> link -> child world process serving the view):
// `node rigview.mjs URL`. The scripted user holds both grips at home (where the shipped rig's
// back strings cross within a millimetre), then moves the right grip 10 cm right and 10 cm up
// (where no string is near another).
// - The workspace: each hand's feasible cells, as many as the rig map gives (the world checks),
//   drawn where they project on the screen and nowhere else (the pixels that change when the
//   workspace is shown lie around the cells' projections), and hidden again by its toggle.
// - The near strings: the page marks exactly the strings the world's maths finds within the
//   rig's distance of another hand's string or a forearm, for the grips it shows (the world
//   checks); the marked ones are drawn magenta, the others not; the toggle takes them back to
//   their tension colours; with the grips apart none is marked.
import { ask, check, log, open, state, untilTime, pause, run } from './harness.mjs';

const [url] = process.argv.slice(2);

// The canvas's pixels now (RGBA, device pixels), kept in the page under `name`.
const grab = (page, name) => page.evaluate((name) => {
  const src = document.querySelector('#view canvas');
  const c = document.createElement('canvas');
  c.width = src.width; c.height = src.height;
  const g = c.getContext('2d', { willReadFrequently: true });
  g.drawImage(src, 0, 0);
  window.__grabs = window.__grabs || {};
  window.__grabs[name] = { w: c.width, h: c.height, s: src.width / src.clientWidth, d: g.getImageData(0, 0, c.width, c.height).data };
}, name);

// Where grabs `a` and `b` differ (device pixels whose colour moved by more than `by` in sum), split
// into those within `radius` CSS px of a segment of `segs` (CSS px, [x0, y0, x1, y1]; a point is
// a segment of no length) and the others; per segment, how many differing pixels lie near it
// (within `radius`); and how many of the near ones are magenta in `a` (a string marked near).
const diff = (page, a, b, segs, radius, by = 24) => page.evaluate((a, b, segs, radius, by) => {
  const A = window.__grabs[a]; const B = window.__grabs[b];
  const { w, h, s } = A;
  const near = new Uint8Array(w * h);
  const owner = new Int32Array(w * h).fill(-1);
  const r = radius * s;
  segs.forEach(([x0, y0, x1, y1], k) => {
    const [X0, Y0, X1, Y1] = [x0 * s, y0 * s, x1 * s, y1 * s];
    const lx = Math.max(0, Math.floor(Math.min(X0, X1) - r)); const hx = Math.min(w - 1, Math.ceil(Math.max(X0, X1) + r));
    const ly = Math.max(0, Math.floor(Math.min(Y0, Y1) - r)); const hy = Math.min(h - 1, Math.ceil(Math.max(Y0, Y1) + r));
    const dx = X1 - X0; const dy = Y1 - Y0; const l2 = dx * dx + dy * dy;
    for (let y = ly; y <= hy; y++) {
      for (let x = lx; x <= hx; x++) {
        const t = l2 > 0 ? Math.min(1, Math.max(0, ((x - X0) * dx + (y - Y0) * dy) / l2)) : 0;
        if (Math.hypot(x - (X0 + t * dx), y - (Y0 + t * dy)) > r) continue;
        near[y * w + x] = 1;
        owner[y * w + x] = owner[y * w + x] === -1 ? k : -2; // -2: near more than one
      }
    }
  });
  let inside = 0; let outside = 0; let magenta = 0;
  const area = near.reduce((n, x) => n + x, 0) / (w * h);
  const per = new Array(segs.length).fill(0);
  for (let i = 0; i < w * h; i++) {
    const o = i * 4;
    const d = Math.abs(A.d[o] - B.d[o]) + Math.abs(A.d[o + 1] - B.d[o + 1]) + Math.abs(A.d[o + 2] - B.d[o + 2]);
    if (d <= by) continue;
    if (!near[i]) { outside++; continue; }
    inside++;
    if (owner[i] >= 0) per[owner[i]]++;
    const [R, G, Bl] = [A.d[o], A.d[o + 1], A.d[o + 2]];
    if (R > G + 60 && Bl > G + 40) magenta++;
  }
  return { inside, outside, per, magenta, area };
}, a, b, segs, radius, by);

const rigView = (page) => page.evaluate(() => spidarView.rigView());
const render = (page) => page.evaluate(() => spidarView.rendered());

// The strings as drawn (scene frame): hand h string s from its grip to its anchor.
const strings = (page) => page.evaluate(() => {
  const info = spidarView.rigInfo();
  return spidarView.grips().map((g, h) => info.anchors_m[h].map((a) => ({ grip: g.pos, anchor: a })));
});

// A view from above and behind the user, looking at the middle of the frame.
async function frameTheRig(page) {
  await page.evaluate(() => {
    const info = spidarView.rigInfo();
    const all = info.anchors_m.flat();
    const c = [0, 1, 2].map((i) => all.reduce((m, a) => m + a[i], 0) / all.length);
    spidarView.setCamera('orbit');
    spidarView.orbitTo([c[0] + 0.7, c[1] + 2.2, c[2] + 5.0], c);
  });
  await render(page);
}

async function workspace(page) {
  const info = await page.evaluate(() => spidarView.rigInfo());
  const cells = info.workspace.map((w) => w.cells.length);
  await ask({ ask: 'check_workspace', cells, strings_near_m: info.strings_near_m });
  let v = await rigView(page);
  check(v.workspace.length === 2 && v.workspace.every((w, h) => w.cells === cells[h] && !w.visible),
    `the page holds each hand's ${cells.join(' and ')} feasible cells, hidden at first`);
  // Each cell centre on the screen (CSS px), as a segment of no length.
  const centres = await page.evaluate(() => spidarView.rigInfo().workspace.flatMap((w) => {
    const [nx, ny] = w.n;
    return w.cells.map((c) => {
      const p = [c % nx, Math.floor(c / nx) % ny, Math.floor(c / (nx * ny))].map((k, i) => w.origin_m[i] + k * w.step_m);
      const q = spidarView.project(p);
      return [q.x, q.y, q.x, q.y, q.z];
    });
  }));
  const onScreen = centres.filter((p) => p[4] < 1 && p[0] >= 0 && p[0] < 800 && p[1] >= 0 && p[1] < 600);
  check(onScreen.length > 0.5 * centres.length, `the camera sees the workspace (${onScreen.length} of ${centres.length} cells on the screen)`);
  await grab(page, 'hidden');
  await page.evaluate(() => spidarView.toggleRig('workspace'));
  await render(page);
  v = await rigView(page);
  check(v.workspace.every((w) => w.visible), 'the workspace toggle shows both clouds');
  await grab(page, 'shown');
  // A point is drawn half a cell wide: within 10 px of its centre at this distance.
  const d = await diff(page, 'shown', 'hidden', centres.map((p) => p.slice(0, 4)), 10);
  log(`workspace shown: ${d.inside} pixels changed around the cells' projections, ${d.outside} elsewhere`);
  check(d.area < 0.5, `the cells' projections cover part of the picture (${(100 * d.area).toFixed(0)} %), so "elsewhere" is most of it`);
  check(d.inside > 300, `the workspace is drawn where its cells project (${d.inside} pixels changed there)`);
  check(d.outside <= 0.005 * d.inside, `and not elsewhere (${d.outside} pixels changed away from every cell)`);
  await page.evaluate(() => spidarView.toggleRig('workspace'));
  await render(page);
  await grab(page, 'hidden again');
  v = await rigView(page);
  const back = await diff(page, 'hidden again', 'hidden', [], 0, 0);
  check(v.workspace.every((w) => !w.visible) && back.outside === 0,
    `toggled again, the workspace is hidden and the picture is as before (${back.outside} pixels differ)`);
}

// Checks the near strings of the frame shown; returns the marked strings' indices (h * 4 + s).
async function nearStrings(page, what) {
  const v = await rigView(page);
  const s = await strings(page);
  const grips = s.map((h) => h[0].grip);
  const { mask } = await ask({ ask: 'near_mask', grips });
  const page_mask = v.near.reduce((m, n, i) => m | (n === 'string' ? 1 << i : n === 'forearm' ? 1 << (8 + i) : 0), 0);
  check(page_mask === mask, `${what}: the page marks the strings the world's maths finds near (${page_mask.toString(16)} = ${mask.toString(16)})`);
  const marked = v.near.map((n, i) => (n ? i : -1)).filter((i) => i >= 0);
  // Linear colours (three.js): magenta #ff2bd6 is (1, 0.02, 0.67), orange #ff8c00 (1, 0.26, 0);
  // a tension colour (grey #9aa0a6 to red #ff3b2f) has blue below 0.4 and, where red, no green.
  v.colours.forEach((c, i) => {
    const isMagenta = c[0] > 0.95 && c[1] < 0.1 && c[2] > 0.5;
    const isOrange = c[0] > 0.95 && c[1] > 0.2 && c[1] < 0.4 && c[2] < 0.05;
    const want = v.near[i] === 'string' ? isMagenta : v.near[i] === 'forearm' ? isOrange : !isMagenta && !isOrange;
    if (!want) throw new Error(`${what}: string ${i} (${v.near[i]}) drawn in ${c.map((x) => x.toFixed(2))}`);
  });
  log(`${what}: strings marked ${JSON.stringify(marked)}, the rest in their tension colours`);
  return { marked, s };
}

async function near(page) {
  const home = await nearStrings(page, 'grips at home');
  check(home.marked.length > 0 && home.marked.length < 8, `at home some strings are near and some are not (${home.marked.length} of 8 marked)`);
  // The same strings drawn: toggling the marks off changes pixels only along the marked strings,
  // along each of them, and they were magenta.
  const proj = await page.evaluate((s) => s.flat().map((x) => {
    const a = spidarView.project(x.grip); const b = spidarView.project(x.anchor);
    return [a.x, a.y, b.x, b.y];
  }), home.s);
  await grab(page, 'near on');
  await page.evaluate(() => spidarView.toggleRig('near'));
  await render(page);
  check(!(await rigView(page)).showNear, 'the near-string toggle turns the marks off');
  await grab(page, 'near off');
  const d = await diff(page, 'near on', 'near off', home.marked.map((i) => proj[i]), 3);
  log(`near strings toggled: ${d.inside} pixels changed along the marked strings (${d.magenta} magenta when marked), ${d.outside} elsewhere, per string ${JSON.stringify(d.per)}`);
  check(d.inside > 50 && d.magenta > 0.5 * d.inside, `the marked strings are drawn magenta (${d.magenta} of ${d.inside} pixels along them)`);
  check(d.outside === 0, `the strings not marked are drawn as they were (${d.outside} pixels changed away from the marked strings)`);
  // Each marked string is seen changing somewhere only it is drawn (crossings aside).
  check(d.per.every((n) => n > 5), `each marked string changes colour along its length (${JSON.stringify(d.per)})`);
  await page.evaluate(() => spidarView.toggleRig('near'));
  await render(page);
  await grab(page, 'near on again');
  const back = await diff(page, 'near on again', 'near on', [], 0, 0);
  check(back.outside === 0, `toggled again, the marks are drawn as before (${back.outside} pixels differ)`);
}

run(async (browser) => {
  const page = await open(browser, url, 'camera=orbit');
  await page.waitForFunction(() => spidarView.rigInfo() && spidarView.grips().every((g) => g.visible), { timeout: 60000, polling: 100 });
  await untilTime(page, (await state(page)).t + 0.2);
  await frameTheRig(page);
  // 1. Grips at home (the scripted user holds them there first).
  const at = { homes: await page.evaluate(() => spidarView.rigInfo().home_m) };
  await page.waitForFunction((homes) => spidarView.grips().every((g, h) => Math.hypot(...g.pos.map((x, i) => x - homes[h][i])) < 0.003),
    { timeout: 60000, polling: 100 }, at.homes);
  await pause(page);
  await workspace(page);
  await near(page);
  // 2. The right grip moved away: nothing near.
  await page.evaluate(() => spidarView.resume());
  await page.waitForFunction((homes) => {
    const g = spidarView.grips()[1].pos;
    return Math.hypot(...g.map((x, i) => x - homes[1][i])) > 0.13;
  }, { timeout: 90000, polling: 100 }, at.homes);
  await untilTime(page, (await state(page)).t + 0.6);
  await pause(page);
  const apart = await nearStrings(page, 'right grip 10 cm right and up');
  check(apart.marked.length === 0, 'with the grips apart no string is marked');
});
