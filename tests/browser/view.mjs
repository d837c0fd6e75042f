// The view's browser tests, run by tests/tests/hil/view.rs (which hosts the world and answers
// ASK lines): `node view.mjs boxing|crowd|live|flash URL`, and `node view.mjs screenshot URL CAMERA
// FILE` for the README's pictures; `node view.mjs replay URL`, run by tests/tests/hil/replay.rs,
// for a recording played into the view (`spidar replay`).
import { ask, check, log, launch, open, state, untilTime, pause, pixels, around, screenshot, run, RED, GREEN, FLASH } from './harness.mjs';

const [mode, url, ...rest] = process.argv.slice(2);
const dist = (a, b) => Math.hypot(...a.map((x, i) => x - b[i]));
const sleep = (ms) => new Promise((r) => setTimeout(r, ms));
const describe = async () => (await fetch(`${url}/scene.json`)).json();

// Waits until the page has a status (its HUD shows it) composed at world time >= t with the link
// up: a status of the world as it is now, not one on its way since before.
const statusAfter = (page, t) => page.waitForFunction((t) => {
  const s = spidarView.state().status;
  return s && s.t_s >= t && s.link.state === 'up';
}, { timeout: 60000, polling: 50 }, t);

async function shapes(page, names) {
  return page.evaluate((names) => Object.fromEntries(names.map((n) => [n, spidarView.shape(n)])), names);
}

async function boxing(browser) {
  const desc = await describe();
  const vh = desc.shapes.filter((s) => s.name.startsWith('virtual human/')).map((s) => s.name);
  const a = await open(browser, url, 'camera=orbit');
  await untilTime(a, (await state(a)).t + 0.3);

  // 1. The virtual human is drawn where the world says it is.
  const pa = await pause(a);
  const A = await shapes(a, vh);
  await ask({ ask: 'check_shapes', t: pa.t, shapes: Object.fromEntries(vh.map((n) => [n, A[n].frame])) });
  for (const n of vh) check(dist(A[n].pos, A[n].frame.slice(0, 3)) < 1e-5, `${n} mesh is at its frame position`);
  const head = A['virtual human/head'];
  const atHead = await pixels(a, RED, around(head.screen, 45));
  check(atHead.n > 400, `the head is drawn at its place on the screen (${atHead.n} red pixels within 45 px of (${head.screen.x.toFixed(0)}, ${head.screen.y.toFixed(0)}))`);
  check(Math.hypot(atHead.cx - head.screen.x, atHead.cy - head.screen.y) < 20, `the red pixels there centre on the head (${atHead.cx.toFixed(0)}, ${atHead.cy.toFixed(0)})`);
  const above = await pixels(a, RED, around({ x: head.screen.x, y: head.screen.y - 160 }, 45));
  check(above.n < 40, `nothing red where the world has nothing, above the head (${above.n} pixels)`);
  const maskA = (await pixels(a, RED)).mask;

  // 2. A scripted punch moves it (the world is held with the fist out).
  const { t_punch } = await ask({ ask: 'punch' });
  await a.evaluate(() => spidarView.resume());
  await untilTime(a, t_punch + 0.5);
  const pb = await pause(a);
  const B = await shapes(a, vh);
  await ask({ ask: 'check_shapes', t: pb.t, shapes: Object.fromEntries(vh.map((n) => [n, B[n].frame])) });
  let moved = vh[0];
  for (const n of vh) if (dist(B[n].pos, A[n].pos) > dist(B[moved].pos, A[moved].pos)) moved = n;
  const d = dist(B[moved].pos, A[moved].pos);
  check(d > 0.03, `the punch moved the virtual human: ${moved} by ${(d * 100).toFixed(1)} cm`);
  // The part that moved most is drawn at its new place (or the next: the avatar may hide one).
  let seen = null;
  const byMotion = vh.filter((n) => dist(B[n].pos, A[n].pos) > 0.03)
    .sort((x, y) => dist(B[y].pos, A[y].pos) - dist(B[x].pos, A[x].pos));
  for (const n of byMotion) {
    const px = await pixels(a, RED, around(B[n].screen, 25));
    if (px.n > 80 && !seen) seen = `${n} (${px.n} red pixels)`;
  }
  check(seen !== null, `a moved part is drawn at its new place: ${seen}`);
  const maskB = (await pixels(a, RED)).mask;
  const changed = maskA.reduce((s, v, i) => s + (v !== maskB[i] ? 1 : 0), 0);
  check(changed > 30, `the drawing changed with it (${changed} cells of 4 px)`);

  // 3. The heads-up display shows the world's numbers (the world held still), 4. in every browser.
  await ask({ ask: 'hold' });
  await a.evaluate(() => spidarView.resume());
  const second = await launch(); // a second browser, not a tab: both draw all the time
  const b = await open(second.browser, url, 'camera=orbit');
  // A status composed after the second browser came (and after the hold): both count it.
  const tb = (await state(b)).t + 0.3;
  for (const p of [a, b]) await statusAfter(p, tb);
  for (const [name, p] of [['first', a], ['second', b]]) {
    await ask({ ask: 'check_hud', browser: name, hud: await p.evaluate(() => spidarView.hud()) });
  }
  const [sa, sb] = [await pause(a), await pause(b)];
  const [SA, SB] = [await shapes(a, vh), await shapes(b, vh)];
  for (const n of vh) check(dist(SA[n].frame, SB[n].frame) < 1e-6, `both browsers show ${n} at the same pose`);
  const [ma, mb] = [(await pixels(a, RED)).mask, (await pixels(b, RED)).mask];
  const differ = ma.reduce((s, v, i) => s + (v !== mb[i] ? 1 : 0), 0);
  const red = ma.reduce((s, v) => s + v, 0);
  check(red > 100 && differ <= red * 0.02, `both browsers draw the same picture (${differ} of ${red} red cells differ; frames ${sa.seq} and ${sb.seq})`);
  const [stA, stB] = [await state(a), await state(b)];
  check(stA.status.viewers === 2 && stB.status.viewers === 2, 'both count two viewers');
  await second.close();
}

// A character's numbers in a frame (world/src/look.rs): body position xyz, rotation xyzw, control
// state, push force, then its drawn figure: each joint's position in the scene.
const STATE = 7;
const HEAD_FLOATS = 9;
const rot = (q, v) => { // q * v * q^-1
  const [x, y, z, w] = q;
  const t = [2 * (y * v[2] - z * v[1]), 2 * (z * v[0] - x * v[2]), 2 * (x * v[1] - y * v[0])];
  return [v[0] + w * t[0] + y * t[2] - z * t[1], v[1] + w * t[1] + z * t[0] - x * t[2], v[2] + w * t[2] + x * t[1] - y * t[0]];
};

// The joints of a character's drawn figure as the frame carries them (the world's, checked by the
// Rust side against the world's own figure).
const skeleton = (joints, c) => joints.map((_, k) => c.slice(HEAD_FLOATS + 3 * k, HEAD_FLOATS + 3 * k + 3));

async function crowd(browser) {
  const desc = await describe();
  const n = desc.crowd.characters;
  const joints = desc.crowd.joints;
  const states = desc.crowd.states;
  // The rig's strings hidden: a taut string is drawn red, and would count as a red figure.
  const a = await open(browser, url, 'camera=orbit&strings=0');
  await untilTime(a, (await state(a)).t + 0.3);
  const snap = async () => {
    const p = await pause(a);
    const chars = await a.evaluate((n) => Array.from({ length: n }, (_, i) => ({
      f: spidarView.character(i), joints: spidarView.characterJoints(i).map((j) => j.pos) })), n);
    await ask({ ask: 'check_characters', t: p.t, characters: chars.map((c) => c.f) });
    // Every drawn joint is where the frame's numbers put it (and they are the world's figure).
    let worst = 0;
    chars.forEach((c) => skeleton(joints, c.f).forEach((p, j) => { worst = Math.max(worst, dist(p, c.joints[j])); }));
    check(worst < 1e-3, `every character's ${joints.length} joints are drawn where the world's drawn figure has them (worst ${(worst * 1000).toFixed(2)} mm)`);
    return { t: p.t, chars };
  };
  const s1 = await snap();
  await a.evaluate(() => spidarView.resume());
  await untilTime(a, s1.t + 0.6);
  const s2 = await snap();
  // The characters that walked, and how much their drawn limbs moved relative to their pelvis, in
  // their body's frame (turning is not a change of pose).
  const rel = (s, i, j) => {
    const J = s.chars[i].joints;
    const q = s.chars[i].f.slice(3, 7);
    return rot([-q[0], -q[1], -q[2], q[3]], J[j].map((x, k) => x - J[0][k]));
  };
  const limbs = joints.map((j, k) => [j.name, k]).filter(([name]) => /knee|elbow/.test(name)).map(([, k]) => k);
  let w = -1; let wd = 0; let change = 0;
  for (let i = 0; i < n; i++) {
    const [f1, f2] = [s1.chars[i].f, s2.chars[i].f];
    const d = Math.hypot(f2[0] - f1[0], f2[2] - f1[2]);
    const c = Math.max(...limbs.map((k) => dist(rel(s1, i, k), rel(s2, i, k))));
    if (f2[STATE] === 0 && d > 0.15 && c > change) { w = i; wd = d; change = c; }
  }
  check(w >= 0, `a character walks (character ${w}: ${wd.toFixed(2)} m in ${(s2.t - s1.t).toFixed(2)} s)`);
  check(change > 0.03, `its drawn pose changes as it walks (knees and elbows move ${(change * 100).toFixed(1)} cm relative to the pelvis)`);
  const spine = joints.findIndex((j) => j.name === 'spine');
  const at2 = await a.evaluate((p) => spidarView.project(p), skeleton(joints, s2.chars[w].f)[spine]);
  const green = await pixels(a, GREEN, around(at2, 40));
  check(green.n > 150, `it is drawn where the world has it, in the balancing colour (${green.n} green pixels)`);

  // A push makes it fall: the world holds still once it is down.
  const { t_down } = await ask({ ask: 'push', i: w });
  await a.evaluate(() => spidarView.resume());
  const s3 = await (async () => {
    const { t } = await state(a);
    await untilTime(a, t + 0.2);
    return snap();
  })();
  const f3 = s3.chars[w].f;
  const st = states[f3[STATE]];
  check(st === 'down', `the frame says character ${w} is ${st}`);
  const neck = joints.findIndex((j) => j.name === 'neck');
  const neckY = s3.chars[w].joints[neck][1];
  check(neckY < 0.6, `its drawn neck is near the floor (${neckY.toFixed(2)} m; standing it was ${s2.chars[w].joints[neck][1].toFixed(2)} m)`);
  // The whole figure lies on the floor: every drawn joint low (a body lying is 0.26 m thick), none
  // through the floor.
  const ys = s3.chars[w].joints.map((p) => p[1]);
  const [low, high] = [Math.min(...ys), Math.max(...ys)];
  check(high < 0.45 && low > -0.03, `all ${ys.length} of its drawn joints lie near the floor (from ${low.toFixed(2)} to ${high.toFixed(2)} m high)`);
  const labels = await a.evaluate(() => spidarView.labels());
  const lab = labels.find((l) => l.character === String(w));
  check(lab && lab.state === st, `its label says ${lab && lab.text}`);
  // Look down on it from above (a push may send it out of the picture, or behind the others).
  const sk = skeleton(joints, f3);
  const mid = sk[spine].map((x, i) => (x + sk[neck][i]) / 2);
  await a.evaluate((p) => spidarView.orbitTo([p[0], 2.4, p[2] + 0.01], [p[0], 0, p[2]]), mid);
  await a.evaluate(() => spidarView.rendered());
  const at3 = await a.evaluate((p) => spidarView.project(p), mid);
  const red = await pixels(a, RED, around(at3, 30));
  check(red.n > 300, `it is drawn lying there in the down colour (${red.n} red pixels around its chest)`);
  // Its head and its feet are drawn where the world's figure has them, and nothing red lies a
  // head's length beyond them (along the figure, away from its pelvis).
  const named = (re) => joints.map((j, k) => [j.name, k]).filter(([name]) => re.test(name)).map(([, k]) => k);
  const pelvis = sk[0];
  for (const [what, ks] of [['head', named(/head/)], ['feet', named(/ankle/)]]) {
    for (const k of ks) {
      const at = await a.evaluate((p) => spidarView.project(p), sk[k]);
      const px = await pixels(a, RED, around(at, 12));
      const out = [sk[k][0] - pelvis[0], 0, sk[k][2] - pelvis[2]];
      const len = Math.hypot(...out);
      const past = sk[k].map((x, i) => x + (out[i] / len) * 0.35);
      const beyond = await pixels(a, RED, around(await a.evaluate((p) => spidarView.project(p), past), 12));
      check(px.n > 300 && beyond.n < px.n * 0.1, `its drawn ${what} (${joints[k].name}) is at the world's place (${px.n} red pixels there, ${beyond.n} 35 cm beyond)`);
    }
  }
  // From the side, the eye at 0.55 m looking level: a point higher than the eye is drawn above the
  // horizon whatever its distance, one lower below it, so the red figure (joints under 0.45 m,
  // limbs a few centimetres thick) is all below the horizon. A camera lower than the line would
  // lift the figure's near parts over it in perspective.
  const EYE = 0.55;
  const far = [mid[0] + 3, EYE, mid[2] + 0.01];
  await a.evaluate((p, t) => spidarView.orbitTo(p, t), far, [mid[0], EYE, mid[2]]);
  await a.evaluate(() => spidarView.rendered());
  const [floor, horizon, above] = await a.evaluate((ps) => ps.map((p) => spidarView.project(p)),
    [[mid[0], 0, mid[2]], [mid[0], EYE, mid[2]], [mid[0], 1.4, mid[2]]]);
  const band = (y0, y1) => ({ x: 0, y: y0, w: 800, h: y1 - y0 });
  const [onFloor, over] = [await pixels(a, RED, band(horizon.y + 2, floor.y + 40)), await pixels(a, RED, band(above.y, horizon.y - 2))];
  check(onFloor.n > 200 && over.n < onFloor.n * 0.02, `seen from the side it lies on the floor: ${onFloor.n} red pixels below ${EYE} m, ${over.n} above`);
  await a.evaluate(() => spidarView.resume());
  await statusAfter(a, t_down + 0.3);
  await ask({ ask: 'check_hud', browser: 'crowd', hud: await a.evaluate(() => spidarView.hud()) });
}

// A hit as a flash on the part hit: a jab that misses lights nothing, one that lands on the
// passive virtual human lights the part it lands on (the page's state and its pixels).
async function flash(browser) {
  const desc = await describe();
  const vh = desc.shapes.filter((s) => s.name.startsWith('virtual human/')).map((s) => s.name);
  const a = await open(browser, url, 'camera=orbit');
  await untilTime(a, (await state(a)).t + 0.3);
  const parts = () => a.evaluate((vh) => vh.map((n) => { const s = spidarView.shape(n); return { n, flash: s.flash, force: s.force }; }), vh);
  const headAt = async () => (await a.evaluate(() => spidarView.shape('virtual human/head'))).screen;

  // 1. A jab that misses: no part ever flashes, none takes a force; the head is drawn red.
  const miss = await ask({ ask: 'jab', hit: false });
  let worst = { flash: 0, force: 0 };
  while ((await state(a)).t < miss.t_out + 0.5) {
    for (const p of await parts()) worst = { flash: Math.max(worst.flash, p.flash), force: Math.max(worst.force, p.force) };
    await sleep(30);
  }
  check(worst.flash === 0 && worst.force === 0, 'a jab that misses lights no part of the virtual human');
  await pause(a);
  const h1 = await headAt();
  const [missFlash, missRed] = [await pixels(a, FLASH, around(h1, 30)), await pixels(a, RED, around(h1, 30))];
  check(missFlash.n < 30 && missRed.n > 300, `the head is drawn red (${missRed.n} red, ${missFlash.n} flash pixels)`);
  await a.evaluate(() => spidarView.resume());
  await ask({ ask: 'release' });

  // 2. A jab at the head, held there: the part it lands on flashes (the page is paused on the first
  // frame that lights a part fully).
  const hit = await ask({ ask: 'jab', hit: true });
  await a.waitForFunction((vh) => {
    if (!vh.some((n) => spidarView.shape(n).flash === 1)) return false;
    spidarView.pause();
    return true;
  }, { timeout: 60000, polling: 'raf' }, vh);
  await a.evaluate(() => spidarView.rendered());
  const fist = (await a.evaluate(() => spidarView.grips()))[1];
  const lit = (await parts()).filter((p) => p.flash > 0);
  const full = lit.filter((p) => p.flash === 1);
  const shapes = await a.evaluate((names) => names.map((n) => spidarView.shape(n)), full.map((p) => p.n));
  const near = shapes.map((s, i) => ({ n: full[i].n, force: full[i].force, d: dist(s.pos, fist.pos), screen: s.screen }))
    .sort((x, y) => x.d - y.d)[0];
  check(near.force > 1 && near.d < 0.2, `the part the fist is on flashes: ${near.n} (${near.force.toFixed(1)} N, its centre ${(near.d * 100).toFixed(0)} cm from the fist; lit: ${lit.map((p) => p.n).join(', ')})`);
  const hitFlash = await pixels(a, FLASH, around(near.screen, 30));
  check(hitFlash.n > 150 && hitFlash.n > 5 * (missFlash.n + 1), `it is drawn lit (${hitFlash.n} flash pixels; the missed jab: ${missFlash.n})`);
  await a.evaluate(() => spidarView.resume());
  await ask({ ask: 'release' });
}

// The page as a user opens it from the address `spidar run`'s world process printed: frames flow,
// the virtual human is drawn where they put it, the grips are shown, the HUD shows the rig and the
// world's link (checked against the world's own /status.json by the Rust test).
async function live(browser) {
  const a = await open(browser, url, 'camera=orbit');
  await a.waitForFunction(() => { const s = spidarView.state().status; return s && s.rig && s.rig.state === 'active' && s.link.state === 'up'; },
    { timeout: 60000, polling: 100 });
  const t0 = (await state(a)).t;
  await untilTime(a, t0 + 1.0);
  const st = await state(a);
  check(st.scene === 'boxing' && st.hasRig, `the page has the world's scene (${st.scene}) and the rig's geometry`);
  check(st.framesReceived > 10, `frames arrive (${st.framesReceived} received)`);
  // The page draws the newest frame it has: while its main thread is busy (a long picture), the
  // frames that come wait in no queue; the next picture shows the newest of them.
  const busy = await a.evaluate(async () => {
    const seq0 = spidarView.state().seq;
    const until = performance.now() + 10000;
    while (performance.now() < until && !(spidarView.newestSeq() >= seq0 + 10)); // busy: no task runs
    const newest = spidarView.newestSeq();
    const renders = spidarView.state().renders;
    await spidarView.rendered();
    const after = spidarView.state();
    return { worker: after.framesWorker, seq0, newest, seq: after.seq, renders: after.renders - renders };
  });
  check(busy.worker, 'a worker receives the frames (the page is cross-origin isolated)');
  // The frames handed over from the worker come in a few buffers used again, not a new one each.
  const reuse = await a.evaluate(async () => {
    const s0 = spidarView.state();
    for (let k = 0; k < 30; k++) await spidarView.rendered();
    const s1 = spidarView.state();
    return { frames: s1.seq - s0.seq, made: s1.frameBuffersMade - s0.frameBuffersMade };
  });
  check(reuse.frames > 20 && reuse.made === 0,
    `frames ${reuse.frames} handed over in the page's buffers, ${reuse.made} new buffers made`);
  check(busy.newest >= busy.seq0 + 10 && busy.seq >= busy.newest,
    `after its main thread was busy while frames ${busy.seq0 + 1}..${busy.newest} came, the page draws frame ${busy.seq} (the newest, not the next) in ${busy.renders} pictures`);
  const p = await pause(a);
  const head = await a.evaluate(() => spidarView.shape('virtual human/head'));
  check(dist(head.pos, head.frame.slice(0, 3)) < 1e-5, 'the head mesh is at its frame position');
  const px = await pixels(a, RED, around(head.screen, 45));
  check(px.n > 400, `the virtual human's head is drawn at its place (${px.n} red pixels)`);
  const grips = await a.evaluate(() => spidarView.grips());
  check(grips.length === 2 && grips.every((g) => g.visible), 'both grips are shown');
  await ask({ ask: 'check_live', t: p.t, hud: await a.evaluate(() => spidarView.hud()), page_steps: st.status.steps });
}

// Pauses the page on the frame it shows, checks the virtual human's head is drawn there (mesh at
// the frame's numbers, red pixels at its place on the screen) and asks the Rust test whether the
// recording has it there at that time (`question`: check_pose, or check_seek with `extra`).
async function headAsRecorded(page, question, extra = {}) {
  const p = await pause(page);
  const head = await page.evaluate(() => spidarView.shape('virtual human/head'));
  check(dist(head.pos, head.frame.slice(0, 3)) < 1e-5, 'the head mesh is at its frame position');
  const r = await ask({ ask: question, t: p.t, head: head.frame, ...extra });
  const px = await pixels(page, RED, around(head.screen, 45));
  check(px.n > 300, `the head is drawn at its place at t = ${p.t.toFixed(3)} s (${px.n} red pixels)`);
  await page.evaluate(() => spidarView.resume());
  return { t: p.t, r };
}

// The replay's frames against its own clock, at `speed`: from the playback messages the page got
// while playing at that speed (after the `since`-th), each with the newest frame's time when it
// came.
const logLength = (page) => page.evaluate(() => spidarView.playbackLog().length);
async function rate(page, speed, clockSpan, since) {
  const log = await page.waitForFunction((speed, span, since) => {
    const l = spidarView.playbackLog().slice(since).filter((e) => e.playing && e.speed === speed && e.frame_t !== null);
    return l.length >= 2 && l[l.length - 1].clock_s - l[0].clock_s >= span ? l : null;
  }, { timeout: 60000, polling: 100 }, speed, clockSpan, since).then((h) => h.jsonValue());
  const [a, b] = [log[0], log[log.length - 1]];
  return { r: (b.frame_t - a.frame_t) / (b.clock_s - a.clock_s), clock: b.clock_s - a.clock_s, frames: b.frame_t - a.frame_t };
}

async function replay(browser) {
  const a = await open(browser, url, 'camera=orbit');
  const pb = () => a.evaluate(() => spidarView.playback());
  await a.waitForFunction(() => spidarView.playback() !== null, { timeout: 60000, polling: 50 });
  let p = await pb();
  const { first_s: first, last_s: last } = p;
  const bar = await a.evaluate(() => getComputedStyle(document.getElementById('playback')).display);
  check(bar !== 'none' && (await state(a)).replay, 'the page shows the playback bar');
  check(!p.playing && p.button === 'play', `a replay opens paused (${p.shown}, ${p.file})`);
  check(Math.abs((await state(a)).t - first) < 1e-3, `on its first frame (t = ${first} s)`);

  // 1. Playing: frames arrive, the virtual human is drawn where the recording has it.
  await a.click('[data-pb=play]');
  await untilTime(a, first + 1.0);
  const n1 = (await state(a)).framesReceived;
  check(n1 > 20, `frames arrive while playing (${n1})`);
  await headAsRecorded(a, 'check_pose');

  // 2. Pause: the time stands still (no frame comes, the position does not move).
  await a.click('[data-pb=play]');
  await a.waitForFunction(() => { const p = spidarView.playback(); return p && !p.playing; }, { timeout: 60000, polling: 50 });
  await a.waitForFunction(() => Math.abs(spidarView.state().receivedT - spidarView.playback().frame_t_s) < 1e-5,
    { timeout: 60000, polling: 50 });
  const [s2, p2, log2] = [await state(a), await pb(), (await a.evaluate(() => spidarView.playbackLog())).length];
  await sleep(1500);
  const [s3, p3, log3] = [await state(a), await pb(), (await a.evaluate(() => spidarView.playbackLog())).length];
  check(log3 > log2, `the paused replay still talks to the page (${log3 - log2} playback messages)`);
  check(s3.framesReceived === s2.framesReceived && s3.receivedT === s2.receivedT && p3.t_s === p2.t_s && p3.clock_s === p2.clock_s,
    `paused, the time does not advance (t = ${s3.receivedT.toFixed(3)} s, ${s3.framesReceived} frames before and after)`);

  // 3. Seeks, forward and back, with the slider: the page shows the recording's frame at that time.
  for (const frac of [0.7, 0.25]) {
    const asked = await a.evaluate((T) => {
      const s = document.querySelector('[data-pb=slider]');
      s.value = String(T);
      s.dispatchEvent(new Event('change'));
      return Number(s.value);
    }, first + frac * (last - first));
    await a.waitForFunction((T) => { const t = spidarView.state().t; return t !== null && t <= T + 1e-4 && t > T - 0.1; },
      { timeout: 60000, polling: 50 }, asked);
    const { t } = await headAsRecorded(a, 'check_seek', { asked });
    const shown = (await pb()).shown;
    check(shown.startsWith(t.toFixed(2)), `after the seek to ${asked} s the bar shows ${shown}`);
  }

  // 4. Speed: at 2x the frames advance twice as fast as at 1x, by the replay's own clock.
  const since1 = await logLength(a);
  await a.click('[data-pb=play]');
  const r1 = await rate(a, 1, 1.5, since1);
  const since2 = await logLength(a);
  await a.select('[data-pb=speed]', '2');
  const r2 = await rate(a, 2, 1.5, since2);
  log(`1x: ${r1.frames.toFixed(3)} s of frames in ${r1.clock.toFixed(3)} s of the replay's clock; 2x: ${r2.frames.toFixed(3)} s in ${r2.clock.toFixed(3)} s`);
  check(Math.abs(r1.r - 1) < 0.15, `1x plays the recording at its own pace (${r1.r.toFixed(3)})`);
  check(Math.abs(r2.r - 2) < 0.3, `2x plays it twice as fast (${r2.r.toFixed(3)})`);
  await a.click('[data-pb=play]');

  // 5. A second browser sees the same frame.
  await a.waitForFunction(() => { const p = spidarView.playback(); return p && !p.playing; }, { timeout: 60000, polling: 50 });
  const second = await launch();
  const b = await open(second.browser, url, 'camera=orbit');
  await a.waitForFunction(() => Math.abs(spidarView.state().t - spidarView.playback().frame_t_s) < 1e-5, { timeout: 60000, polling: 50 });
  await b.waitForFunction(() => spidarView.playback() && Math.abs(spidarView.state().t - spidarView.playback().frame_t_s) < 1e-5,
    { timeout: 60000, polling: 50 });
  const [ta, tb] = [(await state(a)).t, (await state(b)).t];
  check(ta === tb, `both browsers show the frame at t = ${ta.toFixed(3)} s`);
  await second.close();
}

// A measurement, not a test: the frames N browsers each receive per second from a replay playing
// at 1x, over SECONDS of wall time (`node view.mjs rate URL N SECONDS`).
async function rate1(browser) {
  const [n, seconds] = [Number(rest[0] || 1), Number(rest[1] || 5)];
  const others = [];
  for (let i = 1; i < n; i++) others.push(await launch());
  const pages = [];
  for (const b of [browser, ...others.map((o) => o.browser)]) pages.push(await open(b, url, 'camera=orbit'));
  await pages[0].waitForFunction(() => spidarView.playback() !== null, { timeout: 60000 });
  await pages[0].click('[data-pb=play]');
  await sleep(1000);
  const before = await Promise.all(pages.map((p) => state(p)));
  const t0 = Date.now();
  await sleep(seconds * 1000);
  const after = await Promise.all(pages.map((p) => state(p)));
  const wall = (Date.now() - t0) / 1000;
  after.forEach((a, i) => {
    const frames = a.framesReceived - before[i].framesReceived;
    log(`browser ${i + 1} of ${n}: ${(frames / wall).toFixed(1)} frames/s received (${frames} in ${wall.toFixed(2)} s; the recording advanced ${(a.receivedT - before[i].receivedT).toFixed(2)} s)`);
  });
  for (const o of others) await o.close();
}

async function shot(browser) {
  const [camera, file, seconds] = rest;
  const p = await open(browser, url, `camera=${camera}&bodies=people`, { width: 960, height: 600 });
  await sleep(1000 * Number(seconds || 2));
  await pause(p);
  await screenshot(p, file);
}

run({ boxing, crowd, live, flash, replay, rate: rate1, screenshot: shot }[mode] ?? (() => { throw new Error(`unknown mode ${mode}`); }));
