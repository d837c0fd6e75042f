// The rig's screen, the headset and the bodies as people, run by tests/tests/hil/display.rs (which
// runs `spidar run`'s path and answers ASK lines): `node display.mjs screen|headset|bodies|... URL`.
import { ask, check, open, pause, run, screenshot } from './harness.mjs';

const [mode, url, ...rest] = process.argv.slice(2);
const sleep = (ms) => new Promise((r) => setTimeout(r, ms));
const dist2 = (a, b) => Math.hypot(a.x - b.x, a.y - b.y);

// Pixels of a class in a rectangle of the canvas (CSS px): count and centroid. Classes: `yellow`
// and `cyan` (the grips' colours under any light), `red` (the virtual human), and for an anaglyph
// `redchannel` (red bright above the blue: the left eye's yellow grip) and `cyanchannels` (bright green and
// blue: the right eye's cyan grip).
export function classPixels(page, cls, rect) {
  return page.evaluate((cls, rect) => {
    const src = document.querySelector('#view canvas');
    const c = document.createElement('canvas');
    c.width = src.width; c.height = src.height;
    const g = c.getContext('2d', { willReadFrequently: true });
    g.drawImage(src, 0, 0);
    const s = src.width / src.clientWidth;
    const x0 = Math.max(0, Math.floor(rect.x * s)); const y0 = Math.max(0, Math.floor(rect.y * s));
    const x1 = Math.min(c.width, Math.ceil((rect.x + rect.w) * s)); const y1 = Math.min(c.height, Math.ceil((rect.y + rect.h) * s));
    const d = g.getImageData(0, 0, c.width, c.height).data;
    const is = {
      yellow: (R, G, B) => R >= 80 && G >= 60 && R > 1.5 * B && G > 1.3 * B && G > 0.55 * R,
      cyan: (R, G, B) => G >= 70 && B >= 70 && G > 1.3 * R && B > 1.3 * R,
      red: (R, G, B) => R >= 70 && R > 1.8 * G && R > 1.8 * B,
      redchannel: (R, G, B) => R >= 100 && R > 1.3 * B,
      cyanchannels: (R, G, B) => G >= 100 && B >= 100,
      skin: (R, G, B) => R >= 90 && R > G && G > B && R < 1.8 * G && R - B > 30,
    }[cls];
    let n = 0; let sx = 0; let sy = 0;
    for (let y = y0; y < y1; y++) {
      for (let x = x0; x < x1; x++) {
        const i = (y * c.width + x) * 4;
        if (!is(d[i], d[i + 1], d[i + 2])) continue;
        n++; sx += x + 0.5; sy += y + 0.5;
      }
    }
    return { n, x: n ? sx / n / s : null, y: n ? sy / n / s : null };
  }, cls, rect);
}

const clip = (r, v) => {
  const x = Math.max(r.x, v.x); const y = Math.max(r.y, v.y);
  return { x, y, w: Math.min(r.x + r.w, v.x + v.w) - x, h: Math.min(r.y + r.h, v.y + v.h) - y };
};

// Pauses the page on a frame where neither hand feels a force (no arrow drawn at a grip) and both
// grips are shown; returns the grips.
async function pauseStill(page) {
  for (let tries = 0; tries < 100; tries++) {
    await pause(page);
    const grips = await page.evaluate(() => spidarView.grips());
    if (grips.every((g) => g.visible && Math.hypot(...g.force) < 0.04)) return grips;
    await page.evaluate(() => spidarView.resume());
    await sleep(150);
  }
  throw new Error('no frame with both grips shown and no force on them');
}

async function screen(browser) {
  for (const format of ['mono', 'side-by-side', 'top-bottom', 'anaglyph']) {
    // In the anaglyph a channel's picture is one eye's: the red virtual human would be in the left
    // eye's grip's channel, so it is not drawn there.
    const hide = format === 'anaglyph' ? '&hide=virtual%20human' : '';
    const page = await open(browser, url, `camera=eye&avatar=0&strings=0&hud=0&labels=0&stereo=${format}${hide}`);
    await page.waitForFunction(() => spidarView.screen().on, { timeout: 60000 });
    check((await page.evaluate(() => spidarView.screen().format)) === format, `${format}: the page draws the screen ${format}`);
    const grips = await pauseStill(page);
    const head = await page.evaluate(() => spidarView.shape('virtual human/head')); // drawn or not
    const points = [
      { name: 'left grip', pos: grips[0].pos, radius: true, cls: 'yellow' },
      { name: 'right grip', pos: grips[1].pos, radius: true, cls: 'cyan' },
      { name: 'virtual human head', pos: head.pos },
    ];
    const { W, H } = await page.evaluate(() => ({ W: innerWidth, H: innerHeight }));
    const gripR = (await page.evaluate(() => spidarView.rigInfo())).grip_radius_m[0];
    const withImage = await ask({
      ask: 'screen_pixels', format, w: W, h: H,
      points: points.map((p) => (p.radius ? { name: p.name, pos: p.pos, radius: gripR } : { name: p.name, pos: p.pos })),
    });
    for (const [k, p] of points.entries()) {
      const drawn = await page.evaluate((pos) => spidarView.projectEyes(pos), p.pos);
      const w = withImage.points[k];
      check(drawn.length === w.eyes.length, `${format}: ${p.name} drawn for ${drawn.length} eye(s)`);
      for (const [e, eye] of w.eyes.entries()) {
        const err = dist2(drawn[e], eye.centre);
        check(err < 2, `${format}, ${drawn[e].eye} eye: ${p.name} drawn at (${drawn[e].x.toFixed(1)}, ${drawn[e].y.toFixed(1)}), its ray crosses the screen at (${eye.centre.x.toFixed(1)}, ${eye.centre.y.toFixed(1)}): ${err.toFixed(2)} px`);
        if (p.cls) {
          // The grip's pixels: centred on its image within 2 px.
          const cls = format === 'anaglyph' ? (e === 0 ? 'redchannel' : 'cyanchannels') : p.cls;
          if (format === 'anaglyph' && ((e === 0 && p.cls !== 'yellow') || (e === 1 && p.cls !== 'cyan'))) continue;
          const half = eye.radius_px * 1.6 + 10;
          const rect = clip({ x: eye.image.x - half, y: eye.image.y - half, w: 2 * half, h: 2 * half }, eye.view);
          const px = await classPixels(page, cls, rect);
          const area = Math.PI * eye.radius_px ** 2;
          check(px.n > 0.5 * area, `${format}, eye ${e}: ${p.name}: ${px.n} ${cls} pixels (its image is about ${area.toFixed(0)})`);
          const off = dist2(px, eye.image);
          check(off < 2, `${format}, eye ${e}: ${p.name}'s pixels centre at (${px.x.toFixed(1)}, ${px.y.toFixed(1)}), its image's centre is (${eye.image.x.toFixed(1)}, ${eye.image.y.toFixed(1)}): ${off.toFixed(2)} px`);
        } else if (format !== 'anaglyph') {
          const px = await classPixels(page, 'red', clip({ x: eye.centre.x - 25, y: eye.centre.y - 25, w: 50, h: 50 }, eye.view));
          check(px.n > 300, `${format}, eye ${e}: the virtual human is drawn around its head's crossing (${px.n} red pixels within 25 px)`);
        }
      }
    }
    await page.close();
    // SPIDAR_SHOTS=DIR: the README's pictures, the page as a user sees it.
    if (process.env.SPIDAR_SHOTS && (format === 'mono' || format === 'side-by-side')) {
      const shot = await open(browser, url, `camera=eye&bodies=people&stereo=${format}`);
      await sleep(2500);
      await screenshot(shot, `${process.env.SPIDAR_SHOTS}/screen-${format}.png`);
      await shot.close();
    }
  }
}

// The virtual human and the avatar drawn as people follow the simulated bodies joint for joint.
async function people(browser) {
  const page = await open(browser, url, 'camera=orbit&bodies=people');
  const checkAll = async (when) => {
    const p = await pause(page);
    for (const name of ['virtual human', 'avatar']) {
      const joints = await page.evaluate((n) => spidarView.personJoints(n), name);
      const r = await ask({ ask: 'check_person_joints', t: p.t, name, joints });
      check(r.worst_m < 0.01, `${when}: ${name}'s ${r.ends} joint ends drawn within ${(r.worst_m * 1000).toFixed(2)} mm of the simulation's`);
    }
    // Drawn as people: skin-coloured pixels where the virtual human's head is, no red capsule.
    const head = await page.evaluate(() => spidarView.shape('virtual human/head'));
    const skin = await classPixels(page, 'skin', { x: head.screen.x - 30, y: head.screen.y - 30, w: 60, h: 60 });
    check(skin.n > 150, `${when}: the virtual human's face is drawn (${skin.n} skin pixels at its head)`);
    await page.evaluate(() => spidarView.resume());
  };
  await checkAll('at rest');
  // SPIDAR_SHOTS=DIR: pictures of what the test saw.
  if (process.env.SPIDAR_SHOTS) {
    await page.evaluate(() => spidarView.orbitTo([1.2, 1.7, 0.6], [0, 1.3, -0.6]));
    await sleep(1500);
    await screenshot(page, `${process.env.SPIDAR_SHOTS}/people.png`);
  }
  const { t_punch } = await ask({ ask: 'punch' });
  await page.waitForFunction((t) => spidarView.state().t >= t, { timeout: 60000, polling: 50 }, t_punch + 0.45);
  await checkAll('after a punch');
  // The eyes: without a gaze in the frame they look straight ahead of the head.
  await pause(page);
  const ahead = await page.evaluate(() => {
    const h = spidarView.shape('virtual human/head');
    return { eyes: spidarView.personEyes('virtual human'), quat: h.frame.slice(3, 7), pos: h.pos };
  });
  const rot = (q, v) => { // v turned by the unit quaternion q (x, y, z, w)
    const [x, y, z, w] = q; const [a, b, c] = v;
    const ix = w * a + y * c - z * b; const iy = w * b + z * a - x * c; const iz = w * c + x * b - y * a; const iw = -x * a - y * b - z * c;
    return [ix * w + iw * -x + iy * -z - iz * -y, iy * w + iw * -y + iz * -x - ix * -z, iz * w + iw * -z + ix * -y - iy * -x];
  };
  const dot = (a, b) => a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
  const norm = (a) => { const n = Math.hypot(...a); return a.map((x) => x / n); };
  const headAhead = rot(ahead.quat, [0, 0, -1]);
  for (const e of ahead.eyes) {
    const deg = Math.acos(Math.min(1, dot(norm(e.dir), headAhead))) * 180 / Math.PI;
    check(deg < 1, `no gaze sent: an eye looks along the head's own forward (${deg.toFixed(2)} degrees off)`);
  }
  // With a gaze (a frame of the test's making: the scene's gaze entry and 9 numbers per looker),
  // both eyes turn to the attended point.
  const target = [ahead.pos[0] + 0.35, ahead.pos[1] - 0.15, ahead.pos[2] + 1.2];
  const eyes = await page.evaluate(async (target) => {
    const desc = JSON.parse(JSON.stringify(spidarView.desc()));
    const f = spidarView.frameWords();
    const L = desc.layout;
    const head = desc.shapes.findIndex((s) => s.name === 'virtual human/head');
    desc.gaze = [{ name: 'virtual human', head_shape: head }];
    L.id = (L.id ^ 0x5a5a5a) >>> 0;
    const o = L.shapes_at + head * L.shape_floats;
    const mid = f.slice(o, o + 3);
    const dir = target.map((t, i) => t - mid[i]);
    const n = Math.hypot(...dir);
    const gaze = [...mid, ...dir.map((d) => d / n), ...target];
    const words = [...f.slice(0, L.contacts_at), ...gaze, ...f.slice(L.contacts_at)];
    L.gaze_at = L.contacts_at;
    L.contacts_at += 9;
    const fw = new Float32Array(words);
    new Uint32Array(fw.buffer)[1] = L.id;
    spidarView.resume();
    spidarView.feed(desc, Array.from(fw));
    await new Promise((r) => setTimeout(r, 300));
    await spidarView.rendered();
    spidarView.pause();
    return spidarView.personEyes('virtual human');
  }, target);
  for (const e of eyes) {
    const want = norm(target.map((t, i) => t - e.at[i]));
    const deg = Math.acos(Math.min(1, dot(norm(e.dir), want))) * 180 / Math.PI;
    check(deg < 1, `gaze sent: an eye looks at the attended point (${deg.toFixed(2)} degrees off)`);
  }
  // The toggle: the collision shapes instead (a red capsule head).
  await page.evaluate(() => spidarView.setBodies(false));
  await pause(page);
  const head = await page.evaluate(() => spidarView.shape('virtual human/head'));
  const red = await classPixels(page, 'red', { x: head.screen.x - 30, y: head.screen.y - 30, w: 60, h: 60 });
  check(red.n > 400, `as collision shapes the head is the red capsule again (${red.n} red pixels)`);
  if (rest[0]) await screenshot(page, rest[0]);
}

const modes = { screen, people };
if (!modes[mode]) {
  process.stdout.write(`RESULT failed: unknown mode ${mode}\n`);
  process.exit(1);
}
run((b) => modes[mode](b));
