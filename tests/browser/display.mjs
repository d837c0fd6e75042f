// The rig's screen, the headset and the bodies as people, run by tests/tests/hil/display.rs (which
// runs `spidar run`'s path and answers ASK lines): `node display.mjs screen|headset|bodies|... URL`.
import fs from 'node:fs';
import { ask, check, log, open, pause, run, screenshot } from './harness.mjs';

const [mode, url, ...rest] = process.argv.slice(2);
const sleep = (ms) => new Promise((r) => setTimeout(r, ms));
const dist2 = (a, b) => Math.hypot(a.x - b.x, a.y - b.y);

// Pixels of a class in a rectangle of the canvas (CSS px): count and centroid. Classes: `yellow`
// and `cyan` (the grips' colours under any light), `red` (the virtual human), and for an anaglyph
// `redchannel` (red bright above the blue: the left eye's yellow grip) and `cyanchannels` (bright green and
// blue: the right eye's cyan grip).
export function classPixels(page, cls, rect) {
  return page.evaluate((cls, rect) => {
    // The page's WebGL canvas (in a headset session the emulated runtime moves it out of #view).
    const src = document.querySelector('canvas[data-engine]');
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

// Pauses the page on a frame where neither hand feels a force (no arrow drawn at a grip), both
// grips are shown, and nothing else near a grip can be taken for it: no contact within 25 cm (its
// point and force arrow: a contact with the virtual human hidden in the anaglyph, while the rig was
// inactive and the hands felt nothing, once moved the right grip's pixels' centre 8 px), and no
// part drawn within 35 cm lit by a recent hit (a flash fading from white over the virtual human's
// red is the grips' yellow to the pixel classes: a forearm that had just touched the left grip
// once moved its pixels' centre 28 px); returns the grips.
async function pauseStill(page) {
  for (let tries = 0; tries < 100; tries++) {
    await pause(page);
    const grips = await page.evaluate(() => spidarView.grips());
    const near = await page.evaluate((G) => {
      const d = (a, b) => Math.hypot(a[0] - b[0], a[1] - b[1], a[2] - b[2]);
      const nearGrip = (p, r) => G.some((g) => d(p, g) < r);
      const L = spidarView.desc().layout;
      const f = spidarView.frameWords();
      let contacts = 0;
      for (let i = 0; i < (f[L.globals_at + 1] | 0); i++) {
        const o = L.contacts_at + i * L.contact_floats;
        if (nearGrip([f[o], f[o + 1], f[o + 2]], 0.25)) contacts++;
      }
      const lit = spidarView.desc().shapes.filter((s) => { const x = spidarView.shape(s.name); return x.visible && x.flash > 0 && nearGrip(x.pos, 0.35); }).length;
      return { contacts, lit };
    }, grips.map((g) => g.pos));
    if (near.contacts === 0 && near.lit === 0 && grips.every((g) => g.visible && Math.hypot(...g.force) < 0.04)) return grips;
    await page.evaluate(() => spidarView.resume());
    await sleep(150);
  }
  throw new Error('no frame with both grips shown, no force on them, and no contact or part lit by a hit near them');
}

async function screen(browser) {
  for (const format of ['mono', 'side-by-side', 'top-bottom', 'anaglyph']) {
    // In the anaglyph a channel's picture is one eye's: the red virtual human would be in the left
    // eye's grip's channel, so it is not drawn there.
    const hide = format === 'anaglyph' ? '&hide=virtual%20human' : '';
    const page = await open(browser, url, `camera=eye&avatar=0&strings=0&hud=0&labels=0&stereo=${format}${hide}`);
    await page.waitForFunction(() => spidarView.screen().on, { timeout: 60000 });
    check((await page.evaluate(() => spidarView.screen().format)) === format, `${format}: the page draws the screen ${format}`);
    if (format === 'mono') {
      // On chromium's software WebGL the page draws the cheap way (no multisampling, Lambert
      // shading); asked, the GPU's way.
      const gl = await page.evaluate(() => spidarView.state().gl);
      check(/swiftshader/i.test(gl.software) && !gl.antialias && gl.shading === 'lambert', `software WebGL: ${JSON.stringify(gl)}`);
      const asked = await open(browser, url, 'camera=eye&aa=1&shading=standard');
      const gpuWay = await asked.evaluate(() => spidarView.state().gl);
      check(gpuWay.antialias && gpuWay.shading === 'standard', `?aa=1&shading=standard: ${JSON.stringify(gpuWay)}`);
      await asked.close();
    }
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
      // Drawn as with a GPU (the software renderer's cheaper way is not the README's picture).
      const shot = await open(browser, url, `camera=eye&bodies=people&stereo=${format}&aa=1&shading=standard`);
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
  // The eyes: the scene sends the virtual human's gaze (its vision model's); they look at the
  // frame's point looked at (when it is within the eyes' 35 degrees of the head's forward).
  await pause(page);
  const ahead = await page.evaluate(() => {
    const h = spidarView.shape('virtual human/head');
    const L = spidarView.desc().layout;
    const f = spidarView.frameWords();
    return { eyes: spidarView.personEyes('virtual human'), quat: h.frame.slice(3, 7), pos: h.pos,
      gazeAt: L.gaze_at, looked: L.gaze_at === undefined ? null : f.slice(L.gaze_at + 6, L.gaze_at + 9),
      gazes: (spidarView.desc().gaze || []).length };
  });
  const rot = (q, v) => { // v turned by the unit quaternion q (x, y, z, w)
    const [x, y, z, w] = q; const [a, b, c] = v;
    const ix = w * a + y * c - z * b; const iy = w * b + z * a - x * c; const iz = w * c + x * b - y * a; const iw = -x * a - y * b - z * c;
    return [ix * w + iw * -x + iy * -z - iz * -y, iy * w + iw * -y + iz * -x - ix * -z, iz * w + iw * -z + ix * -y - iy * -x];
  };
  const dot = (a, b) => a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
  const norm = (a) => { const n = Math.hypot(...a); return a.map((x) => x / n); };
  const headAhead = rot(ahead.quat, [0, 0, -1]);
  check(ahead.gazes === 1 && ahead.looked !== null, `the scene describes the virtual human's gaze (${ahead.gazes}, at word ${ahead.gazeAt})`);
  for (const e of ahead.eyes) {
    const want = norm(ahead.looked.map((t, i) => t - e.at[i]));
    const off = Math.acos(Math.min(1, dot(want, headAhead))) * 180 / Math.PI;
    const deg = Math.acos(Math.min(1, dot(norm(e.dir), want))) * 180 / Math.PI;
    const clamped = Math.acos(Math.min(1, dot(norm(e.dir), headAhead))) * 180 / Math.PI;
    check(off < 34 ? deg < 1 : Math.abs(clamped - 35) < 1,
      `the scene's gaze: an eye looks at the point the frame says the virtual human looks at (${deg.toFixed(2)} degrees off; that point ${off.toFixed(1)} degrees off the head's forward)`);
  }
  // With a gaze of the test's making (the frame's 9 gaze numbers replaced), both eyes turn to it:
  // a point 1.2 m ahead of the head and 15 degrees off its forward, whichever way the head is
  // turned after the punch (a point beyond the eyes' 35 degrees would be looked toward, clamped).
  const off15 = rot(ahead.quat, [0.25, -0.1, -1.0]).map((x) => x * 1.2 / Math.hypot(0.25, 0.1, 1.0));
  const target = ahead.pos.map((p, i) => p + off15[i]);
  const made = await page.evaluate(async (target) => {
    const desc = JSON.parse(JSON.stringify(spidarView.desc()));
    const f = spidarView.frameWords();
    const L = desc.layout;
    const head = desc.shapes.findIndex((s) => s.name === 'virtual human/head');
    L.id = (L.id ^ 0x5a5a5a) >>> 0;
    const o = L.shapes_at + head * L.shape_floats;
    const mid = f.slice(o, o + 3);
    const dir = target.map((t, i) => t - mid[i]);
    const n = Math.hypot(...dir);
    const gaze = [...mid, ...dir.map((d) => d / n), ...target];
    const words = [...f.slice(0, L.gaze_at), ...gaze, ...f.slice(L.gaze_at + L.gaze_floats)];
    const fw = new Float32Array(words);
    new Uint32Array(fw.buffer)[1] = L.id;
    spidarView.resume();
    spidarView.feed(desc, Array.from(fw));
    await new Promise((r) => setTimeout(r, 300));
    await spidarView.rendered();
    spidarView.pause();
    return { eyes: spidarView.personEyes('virtual human'), headNamed: desc.gaze[0].head_shape === head };
  }, target);
  check(made.headNamed, "the scene's gaze names the virtual human's head");
  for (const e of made.eyes) {
    const want = norm(target.map((t, i) => t - e.at[i]));
    const deg = Math.acos(Math.min(1, dot(norm(e.dir), want))) * 180 / Math.PI;
    const offAhead = Math.acos(Math.min(1, dot(want, headAhead))) * 180 / Math.PI;
    check(deg < 1, `gaze sent: an eye looks at the attended point (${deg.toFixed(2)} degrees off; that point ${offAhead.toFixed(1)} degrees off the head's forward)`);
  }
  // The toggle: the collision shapes instead (a red capsule head).
  await page.evaluate(() => spidarView.setBodies(false));
  await pause(page);
  const head = await page.evaluate(() => spidarView.shape('virtual human/head'));
  const red = await classPixels(page, 'red', { x: head.screen.x - 30, y: head.screen.y - 30, w: 60, h: 60 });
  check(red.n > 400, `as collision shapes the head is the red capsule again (${red.n} red pixels)`);
  if (rest[0]) await screenshot(page, rest[0]);
}

// ---- the headset: an emulated WebXR headset (the `iwer` runtime) inside the page ----

const IWER_JS = fs.readFileSync(new URL('./node_modules/iwer/build/iwer.min.js', import.meta.url), 'utf8');

// The headset's geometry, computed here (never by the page): a point of the headset's floor frame
// seen by one eye of a headset at `pos` turned by `quat` (xyzw), whose eyes are `ipd` apart and
// whose views are perspectives of vertical field `fovy` (rad) on each eye's half of the canvas:
// the pixel of the point's own ray, and of the centre of a sphere's image (radius r).
const v3 = { sub: (a, b) => a.map((x, i) => x - b[i]), add: (a, b) => a.map((x, i) => x + b[i]), scale: (a, k) => a.map((x) => x * k),
  dot: (a, b) => a.reduce((s, x, i) => s + x * b[i], 0), len: (a) => Math.hypot(...a) };
function rotate(q, p, inverse = false) {
  const [x, y, z, w0] = q;
  const w = inverse ? -w0 : w0;
  // p' = p + 2w (u x p) + 2 u x (u x p), u = (x, y, z) (the inverse: w negated)
  const cross = (a, b) => [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
  const u = [x, y, z];
  const t = v3.scale(cross(u, p), 2);
  return v3.add(v3.add(p, v3.scale(t, w)), cross(u, t));
}
function eyePixel(head, eye, p, r, view) {
  const eyePos = v3.add(head.pos, rotate(head.quat, [(eye === 0 ? -0.5 : 0.5) * head.ipd, 0, 0]));
  const pe = rotate(head.quat, v3.sub(p, eyePos), true); // in the eye's frame: x right, y up, -z ahead
  const f = 1 / Math.tan(head.fovy / 2);
  const aspect = view.w / view.h;
  const toPx = (X, Y) => ({ x: view.x + ((f / aspect) * X + 1) / 2 * view.w, y: view.y + (1 - f * Y) / 2 * view.h });
  const centre = toPx(pe[0] / -pe[2], pe[1] / -pe[2]);
  // The sphere's silhouette cone cut by the image plane (z = -1): the midpoint of the two
  // generators in the plane of its axis and the view direction.
  const d = v3.len(pe);
  const a = v3.scale(pe, 1 / d);
  const alpha = Math.asin(r / d);
  const n = [0, 0, -1];
  let w = v3.sub(n, v3.scale(a, v3.dot(n, a)));
  let image = centre;
  if (v3.len(w) > 1e-9) {
    w = v3.scale(w, 1 / v3.len(w));
    const g1 = v3.add(v3.scale(a, Math.cos(alpha)), v3.scale(w, Math.sin(alpha)));
    const g2 = v3.sub(v3.scale(a, Math.cos(alpha)), v3.scale(w, Math.sin(alpha)));
    const p1 = toPx(g1[0] / -g1[2], g1[1] / -g1[2]);
    const p2 = toPx(g2[0] / -g2[2], g2[1] / -g2[2]);
    image = { x: (p1.x + p2.x) / 2, y: (p1.y + p2.y) / 2 };
  }
  return { centre, image, radiusPx: (r / -pe[2]) * f * view.h / 2 };
}

async function headset(browser) {
  const emulate = async (page) => {
    await page.evaluateOnNewDocument(IWER_JS);
    await page.evaluateOnNewDocument(() => {
      const d = new IWER.XRDevice(IWER.metaQuest3);
      d.installRuntime({ forceInstall: true }); // over chromium's own navigator.xr
      d.stereoEnabled = true; // both eyes, side by side on the canvas
      window.emulatedHeadset = d;
    });
  };
  const shots = process.env.SPIDAR_SHOTS;
  const query = 'avatar=0&strings=0&hud=0&labels=0&xrmarkers=0';
  const page = await open(browser, url, query, { width: 800, height: 450 }, emulate);
  await page.waitForFunction(() => spidarView.xr.state().supported && spidarView.state().hasRig, { timeout: 60000 });
  // The headset where the user's eyes are, before the session starts (the floor frame's origin
  // is under them).
  const eyeM = (await page.evaluate(() => spidarView.rigInfo())).eye_m;
  await page.evaluate(() => { emulatedHeadset.position.set(0, 1.5, 0); emulatedHeadset.quaternion.set(0, 0, 0, 1); });
  await page.click('#xr-button');
  await page.waitForFunction(() => spidarView.xr.state().presenting, { timeout: 30000 });
  check(true, 'the page entered an immersive session in the emulated headset');
  const grips = await pauseStill(page);
  const G = grips.map((g) => g.pos);
  // The controllers held on the grips, in the headset's floor frame: the grips turned 20 degrees
  // about the vertical and moved (the floor frame is not the scene's until registered).
  const c = v3.scale(v3.add(G[0], G[1]), 0.5);
  const turn = [0, Math.sin(0.5 * 0.349), 0, Math.cos(0.5 * 0.349)];
  const P = G.map((g) => v3.add(rotate(turn, v3.sub(g, c)), [0.05, 1.2, -0.5]));
  await page.evaluate((P) => {
    for (const [k, side] of ['left', 'right'].entries()) {
      const off = IWER.metaQuest3.controllerConfig.layout[side].gripOffsetMatrix;
      const ctl = emulatedHeadset.controllers[side];
      ctl.quaternion.set(0, 0, 0, 1);
      ctl.position.set(P[k][0] - off[12], P[k][1] - off[13], P[k][2] - off[14]);
    }
  }, P);
  await page.waitForFunction(() => spidarView.xr.controllers() !== null, { timeout: 10000 });
  const tracked = await page.evaluate(() => spidarView.xr.controllers());
  for (const k of [0, 1]) check(v3.len(v3.sub(tracked[k], P[k])) < 1e-4, `the page tracks the ${k ? 'right' : 'left'} controller at its grip`);
  // A trigger pressed: the registration.
  await page.evaluate(async () => {
    emulatedHeadset.controllers.right.updateButtonValue('trigger', 1);
    await spidarView.rendered();
    emulatedHeadset.controllers.right.updateButtonValue('trigger', 0);
    await spidarView.rendered();
  });
  const st = await page.evaluate(() => spidarView.xr.state());
  check(st.registered, `a trigger press registers the headset to the rig (${st.message})`);
  const gripR = (await page.evaluate(() => spidarView.rigInfo())).grip_radius_m[0];
  const { ipd, fovy } = await page.evaluate(() => ({ ipd: emulatedHeadset.ipd, fovy: emulatedHeadset.fovy }));
  const size = await page.evaluate(() => { const c = document.querySelector('canvas[data-engine]'); return { w: c.width, h: c.height, cw: c.clientWidth }; });
  check(size.w === size.cw, `the canvas is drawn at one pixel per CSS pixel (${size.w} x ${size.h})`);
  const views = [{ x: 0, y: 0, w: size.w / 2, h: size.h }, { x: size.w / 2, y: 0, w: size.w / 2, h: size.h }];
  const poses = [
    { pos: [0, 1.5, 0], quat: [0, 0, 0, 1], what: 'the headset where it started' },
    { pos: [0.08, 1.42, -0.04], quat: [0, Math.sin(-0.5 * 0.175), 0, Math.cos(-0.5 * 0.175)], what: 'the headset 8 cm right, 8 cm lower, turned 10 degrees right' },
  ];
  let before = null;
  for (const pose of poses) {
    await page.evaluate((p) => { emulatedHeadset.position.set(...p.pos); emulatedHeadset.quaternion.set(...p.quat); }, pose);
    await page.evaluate(async () => { await spidarView.rendered(); await spidarView.rendered(); });
    const head = { ...pose, ipd, fovy };
    const seen = [];
    for (const e of [0, 1]) {
      const red = await classPixels(page, 'red', views[e]);
      check(red.n > 800, `${pose.what}: the ${e ? 'right' : 'left'} eye draws the virtual human (${red.n} red pixels)`);
      seen.push(red);
      for (const [k, cls] of ['yellow', 'cyan'].entries()) {
        const want = eyePixel(head, e, P[k], gripR, views[e]);
        const half = want.radiusPx * 1.6 + 10;
        const rect = clip({ x: want.image.x - half, y: want.image.y - half, w: 2 * half, h: 2 * half }, views[e]);
        const px = await classPixels(page, cls, rect);
        const area = Math.PI * want.radiusPx ** 2;
        check(px.n > 0.5 * area, `${pose.what}, ${e ? 'right' : 'left'} eye: the ${k ? 'right' : 'left'} grip drawn where its controller is (${px.n} ${cls} pixels, its image about ${area.toFixed(0)})`);
        const off = dist2(px, want.image);
        check(off < 3, `${pose.what}, ${e ? 'right' : 'left'} eye: the ${k ? 'right' : 'left'} grip's pixels centre at (${px.x.toFixed(1)}, ${px.y.toFixed(1)}), the controller's image at (${want.image.x.toFixed(1)}, ${want.image.y.toFixed(1)}): ${off.toFixed(2)} px`);
        if (before) {
          const moved = dist2(want.image, before[e][k]);
          check(moved > 15, `${pose.what}, ${e ? 'right' : 'left'} eye: the ${k ? 'right' : 'left'} grip's picture moved ${moved.toFixed(1)} px`);
        }
        (seen.images = seen.images || [[], []])[e][k] = want.image;
      }
    }
    // The two eyes see the virtual human from 6 cm apart: further right in the left eye's picture.
    const disparity = (seen[0].x - views[0].x) - (seen[1].x - views[1].x);
    check(disparity > 0.5, `${pose.what}: the virtual human is ${disparity.toFixed(1)} px further right in the left eye (stereo)`);
    before = seen.images;
  }
  // Between the world's frames the headset draws blends: a body one world frame interval behind
  // the newest frame (halfway between two frames 1/60 s apart half an interval after the second
  // came; the newest as it is when the world's frames are a step apart), and the grips
  // extrapolated along their velocity to when the picture is shown, at most MAX_LEAD_MS ahead.
  const L = (await page.evaluate(() => spidarView.desc())).layout;
  const a = await page.evaluate(() => spidarView.frameWords());
  const b = a.slice();
  const s0 = L.shapes_at; const h0 = L.hands_at;
  const gap = 1000 / 60;
  b[L.globals_at] = a[L.globals_at] + gap / 1000; // the world's time, a frame later
  b[s0] += 0.1; // the first body 10 cm along x
  const half = Math.SQRT1_2; // and turned 90 degrees about y
  [b[s0 + 3], b[s0 + 4], b[s0 + 5], b[s0 + 6]] = [0, half, 0, half];
  [a[s0 + 3], a[s0 + 4], a[s0 + 5], a[s0 + 6]] = [0, 0, 0, 1];
  b[h0] += 0.02; // the left grip 2 cm along x (1.2 m/s)
  const blend = (since, show, frameMs) => page.evaluate((a, b, gap, since, show, frameMs) => spidarView.xr.blend([a, b], gap, since, show, frameMs),
    a, b, gap, since, show, frameMs);
  const mid = await blend(gap / 2, 5, gap);
  const q = mid.f.slice(s0 + 3, s0 + 7);
  const turned = 2 * Math.atan2(q[1], q[3]) * 180 / Math.PI;
  check(Math.abs(mid.f[s0] - (a[s0] + 0.05)) < 1e-5 && Math.abs(turned - 45) < 0.01,
    `frames 1/60 s apart, half an interval after the second came: a body is drawn halfway, ${((mid.f[s0] - a[s0]) * 100).toFixed(2)} of 10 cm, turned ${turned.toFixed(2)} of 90 degrees`);
  const lead = gap / 2 + 5; // from the newest frame's tick to the picture's showing
  const ahead = (0.02 * lead) / gap;
  // (The lead is a difference of wall-clock times near 1.7e12 ms: good to about 1e-3 ms.)
  check(Math.abs(mid.f[h0] - (b[h0] + ahead)) < 1e-5 && Math.abs(mid.leadMs - lead) < 1e-3,
    `a grip is drawn ${((mid.f[h0] - b[h0]) * 100).toFixed(2)} cm ahead of its newest frame (${(ahead * 100).toFixed(2)} cm: its velocity times the ${mid.leadMs.toFixed(2)} ms from its tick to the picture's showing)`);
  const fast = await blend(3, 0, 3);
  check(Math.abs(fast.f[s0] - b[s0]) < 1e-6 && Math.abs(fast.f[s0 + 4] - half) < 1e-6,
    `the world's frames a step (3 ms) apart: 3 ms after the newest came a body is drawn as the newest has it (${((fast.f[s0] - a[s0]) * 100).toFixed(2)} of 10 cm)`);
  const far = await blend(gap / 2, 500, gap);
  const maxLead = await page.evaluate(() => spidarView.xr.maxLeadMs);
  check(far.leadMs === maxLead && Math.abs(far.f[h0] - (b[h0] + (0.02 * maxLead) / gap)) < 1e-5,
    `a picture shown long after the newest tick: the grip is extrapolated ${far.leadMs} ms ahead, no more (${((far.f[h0] - b[h0]) * 100).toFixed(2)} cm)`);
  // The frames are drawn at the headset's rate, interpolated, and reported as the headset's: the
  // world keeps them apart (its status, fetched by the page over the same HTTPS).
  await page.evaluate(() => spidarView.resume());
  await page.waitForFunction(() => spidarView.state().drawnReport && spidarView.state().drawnReport.xr, { timeout: 10000 });
  if (shots) {
    // The README's picture: the bodies as people, the avatar shown.
    await page.evaluate(() => spidarView.setBodies(true));
    await page.keyboard.press('a');
    await sleep(1500);
    await screenshot(page, `${shots}/headset.png`);
  }
  const proto = await page.evaluate(() => location.protocol);
  await page.waitForFunction(async () => {
    const s = await (await fetch('/status.json')).json();
    return s && s.picture_age.headset && s.picture_age.headset.total > 0;
  }, { timeout: 10000, polling: 200 });
  check(true, `the world keeps the headset's pictures' ages apart (page served over ${proto})`);
  await page.close();
  log(`eye point ${JSON.stringify(eyeM)}`);
}

// ---- the crowd drawn as people ----

async function crowdPeople(browser) {
  // The rig's strings hidden: a taut string is drawn red, and would count as the fallen person.
  const page = await open(browser, url, 'camera=orbit&bodies=people&labels=0&hud=0&strings=0');
  const desc = await page.evaluate(() => spidarView.desc());
  const joints = desc.crowd.joints;
  const n = desc.crowd.characters;
  const skeleton = (c) => joints.map((_, k) => c.slice(9 + 3 * k, 9 + 3 * k + 3));
  const d3 = (a, b) => Math.hypot(a[0] - b[0], a[1] - b[1], a[2] - b[2]);
  // Every joint of every character, as each piece meeting there draws it, against the drawn
  // figure (the frame's joints, and the figure's bones as the page draws them).
  const jointForJoint = async (what) => {
    await pause(page);
    const all = await page.evaluate((n) => Array.from({ length: n }, (_, i) => ({
      f: spidarView.character(i), bones: spidarView.characterJoints(i).map((j) => j.pos), person: spidarView.characterPerson(i) })), n);
    let worst = 0;
    let count = 0;
    for (const c of all) {
      const sk = skeleton(c.f);
      c.person.joints.forEach((ends, j) => ends.forEach((p) => {
        worst = Math.max(worst, d3(p, sk[j]), d3(p, c.bones[j]));
        count++;
      }));
    }
    check(count >= n * (joints.length - 1) * 2 && worst < 0.01, `${what}: the ${count} piece ends of ${n} people meet the drawn figures' joints (worst ${(worst * 1000).toFixed(2)} mm)`);
    return all;
  };
  const all = await jointForJoint('standing and walking');
  check(all.every((c) => c.person.visible), 'the crowd is drawn as people');
  const w = all.findIndex((c) => desc.crowd.states[c.f[7]] !== 'down');
  check(w >= 0, `character ${w} is up`);
  const standing = all[w].person;
  check(standing.high > 1.4 && Math.abs(standing.shoeLow) < 0.03, `standing, its person reaches ${standing.high.toFixed(2)} m high, its shoes' soles at ${standing.shoeLow.toFixed(3)} m`);
  // Pushed over: its person lies on the floor.
  const { t_down } = await ask({ ask: 'push', i: w });
  await page.evaluate(() => spidarView.resume());
  await page.waitForFunction((t) => spidarView.state().t >= t, { timeout: 60000, polling: 50 }, t_down + 0.2);
  const down = await jointForJoint('one down');
  check(desc.crowd.states[down[w].f[7]] === 'down', `the frame says character ${w} is down`);
  const lying = down[w].person;
  // (The pieces are drawn about the figure's joints, which lie down to the floor itself: a piece
  // may sink into it by up to its own thickness, the thigh's 7.5 cm at most.)
  check(lying.high < 0.5 && lying.low > -0.08, `its person lies on the floor: every piece but the shoes between ${lying.low.toFixed(3)} and ${lying.high.toFixed(2)} m high (shoes down to ${lying.shoeLow.toFixed(3)} m)`);
  // The shoes turn at the ankles as a lying person's feet do: none goes into the floor by more
  // than 1 cm, lying face down or on the back (a shoe that kept pointing the body's forward way
  // went 15 cm into it face down).
  check(lying.shoeLow > -0.01, `its shoes stay on the floor: their lowest point ${lying.shoeLow.toFixed(3)} m high`);
  // Seen from the side with the eye 0.55 m up looking level: the red (down) person is all below
  // the horizon.
  const sk = skeleton(down[w].f);
  const mid = sk[0];
  const EYE = 0.55;
  // From the side no other person stands in front of it: of four directions, the one whose line
  // of sight passes farthest from every other character (one in the way hid it entirely once).
  const others = down.filter((_, i) => i !== w).map((c) => skeleton(c.f)[0]);
  const clearance = ([dx, dz]) => Math.min(...others.map((o) => {
    const [ox, oz] = [o[0] - mid[0], o[2] - mid[2]];
    const along = Math.max(0, Math.min(3, ox * dx + oz * dz));
    return Math.hypot(ox - along * dx, oz - along * dz);
  }));
  const [dx, dz] = [[1, 0], [-1, 0], [0, 1], [0, -1]].reduce((a, b) => (clearance(b) > clearance(a) ? b : a));
  await page.evaluate((p, t) => spidarView.orbitTo(p, t), [mid[0] + 3 * dx, EYE, mid[2] + 3 * dz + 0.01], [mid[0], EYE, mid[2]]);
  await page.evaluate(() => spidarView.rendered());
  const [floor, horizon, above] = await page.evaluate((ps) => ps.map((p) => spidarView.project(p)),
    [[mid[0], 0, mid[2]], [mid[0], EYE, mid[2]], [mid[0], 1.4, mid[2]]]);
  const band = (y0, y1) => ({ x: 0, y: y0, w: 800, h: y1 - y0 });
  const [onFloor, over] = [await classPixels(page, 'red', band(horizon.y + 2, floor.y + 40)), await classPixels(page, 'red', band(above.y, horizon.y - 2))];
  check(onFloor.n > 200 && over.n < onFloor.n * 0.02, `seen from the side the person lies on the floor: ${onFloor.n} red pixels below ${EYE} m, ${over.n} above`);
  if (rest[0]) await screenshot(page, rest[0]);
  // The toggle: the figure's bones instead.
  await page.evaluate(() => spidarView.setBodies(false));
  check(!(await page.evaluate((w) => spidarView.characterPerson(w).visible, w)), 'the toggle draws the figures\' bones instead of people');
  await page.close();
}

const modes = { screen, people, headset, crowd: crowdPeople };
if (!modes[mode]) {
  process.stdout.write(`RESULT failed: unknown mode ${mode}\n`);
  process.exit(1);
}
run((b) => modes[mode](b));
