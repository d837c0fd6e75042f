// The spar bout's live view, run by tools/tests/spar_cli.rs (which runs `spidar world --scene
// spar --view` and two simulated rigs as processes): `node spar.mjs URL`. Both bodies are drawn
// (as their shapes and as people), where the world's frames put them; they follow the rigs (seat
// 0's gloves stay near its user's hands, which the frames carry; both seats' gloves move as their
// users punch); each seat's eye looks at the other body.
import { check, log, open, state, untilTime, pause, pixels, around, run, RED, BLUE, COLOURED } from './harness.mjs';

const [url] = process.argv.slice(2);
const dist = (a, b) => Math.hypot(...a.map((x, i) => x - b[i]));
const sleep = (ms) => new Promise((r) => setTimeout(r, ms));

// Pixels of a class (harness.mjs: BLUE, seat 0's body; COLOURED, any clear colour) in `rect`.
const count = async (page, cls, rect = null) => (await pixels(page, cls, rect)).n;

// The names of a seat's shapes of one part (`hand`, `head`), left first, from the description's
// humanoids.
function parts(desc, seat, part) {
  const h = desc.humanoids.find((x) => x.name === `seat ${seat}`);
  return h.segments.filter((s) => s.part === part).sort((a, b) => a.side - b.side).map((s) => desc.shapes[s.shape].name);
}

await run(async (browser) => {
  const p = await open(browser, url, 'camera=orbit');
  const desc = await p.evaluate(() => spidarView.desc());
  check(desc.name === 'spar', `the view shows the spar scene (${desc.name})`);
  check(desc.humanoids.map((h) => h.name).join(',') === 'seat 0,seat 1', 'both seats are described as people');
  check(desc.eyes.length === 2, 'an eye per seat');
  const hands = [0, 1].map((s) => parts(desc, s, 'hand'));
  const heads = [0, 1].map((s) => parts(desc, s, 'head')[0]);
  check(hands[0].length === 2 && hands[1].length === 2, 'two gloves per seat');

  // 1. Over two seconds of the bout: every drawn glove is where the world's frame puts it; seat
  // 0's gloves near its user's hands (the frame's tracked hands); both seats' gloves move.
  const t0 = (await state(p)).t;
  const seen = [[], []];
  let near = 0; let far = 0; let worstMesh = 0; let worstRig = 0;
  for (let k = 0; k < 20; k++) {
    await untilTime(p, t0 + 0.1 * (k + 1));
    const s = await p.evaluate((names) => ({
      shapes: names.map((n) => spidarView.shape(n)),
      words: spidarView.frameWords(),
      L: spidarView.desc().layout,
    }), [...hands[0], ...hands[1]]);
    for (const [i, sh] of s.shapes.entries()) {
      worstMesh = Math.max(worstMesh, dist(sh.pos, sh.frame.slice(0, 3)));
      seen[i < 2 ? 0 : 1].push(sh.pos);
    }
    // The frame's hands are seat 0's rig's (scene frame): the glove is pulled to them by the
    // coupling spring; a contact may hold it off.
    const valid = s.words[s.L.globals_at + 3];
    for (let h = 0; h < 2; h++) {
      if (!(valid & (1 << h))) continue;
      const o = s.L.hands_at + h * s.L.hand_floats;
      const d = dist(s.shapes[h].pos, s.words.slice(o, o + 3));
      if (d < 0.12) near++; else far++;
      worstRig = Math.max(worstRig, d);
    }
  }
  check(worstMesh < 1e-4, `every glove mesh is at its frame position (worst ${worstMesh.toExponential(1)} m)`);
  // Blocks and clinches hold a glove off its hand for a while (the spring pulls, the contact pushes).
  check(near >= 0.5 * (near + far) && near > 10 && worstRig < 0.4, `seat 0's gloves follow its rig's hands: within 12 cm in ${near} of ${near + far} frames, never beyond ${(worstRig * 100).toFixed(0)} cm`);
  for (const s of [0, 1]) {
    const pts = seen[s];
    let moved = 0;
    for (const a of pts) for (const b of pts) moved = Math.max(moved, dist(a, b));
    check(moved > 0.05, `seat ${s}'s gloves move as its user boxes (${(moved * 100).toFixed(1)} cm)`);
  }

  // 2. Both bodies drawn from the orbit camera: red (seat 1) at its head, blue (seat 0) at its.
  await pause(p);
  const H = await p.evaluate((n) => n.map((x) => spidarView.shape(x)), heads);
  const waists = await p.evaluate((n) => n.map((x) => spidarView.shape(x).pos), [0, 1].map((s) => parts(desc, s, 'waist')[0]));
  check(waists[1][2] < waists[0][2] - 0.5, `seat 1 stands in front of seat 0 (waists at z ${waists[1][2].toFixed(2)} and ${waists[0][2].toFixed(2)} m)`);
  // A head that was just hit flashes (near white, then back to its colour): drawn, in any colour.
  for (const seat of [0, 1]) {
    const n = await count(p, COLOURED, around(H[seat].screen, 30));
    check(n > 150, `seat ${seat}'s head is drawn (${n} coloured pixels within 30 px of it)`);
  }
  const red = await count(p, RED);
  const bl = await count(p, BLUE);
  check(red > 2000 && bl > 2000, `both bodies are drawn in their colours (${red} red pixels, ${bl} blue)`);
  const people = await p.evaluate(() => { spidarView.setBodies(true); return [spidarView.personJoints('seat 0'), spidarView.personJoints('seat 1')]; });
  check(people.every((j) => j && Object.keys(j).length >= 8), 'both seats are drawn as people too');

  // 3. Each person's eye: the other's head in the middle of the picture, in its colour.
  for (const seat of [0, 1]) {
    const e = await open(browser, url, `camera=eye&seat=${seat}`);
    await e.evaluate(() => spidarView.rendered());
    await pause(e);
    const other = await e.evaluate((n) => spidarView.shape(n), heads[1 - seat]);
    const sc = other.screen;
    check(sc.z < 1 && Math.abs(sc.x - 400) < 200 && Math.abs(sc.y - 300) < 250, `from seat ${seat}'s eye seat ${1 - seat}'s head is in view (${sc.x.toFixed(0)}, ${sc.y.toFixed(0)})`);
    const n = await count(e, COLOURED, around(sc, 40));
    const colour = seat === 0 ? await count(e, RED) : await count(e, BLUE);
    check(n > 300 && colour > 3000, `from seat ${seat}'s eye seat ${1 - seat}'s head is drawn (${n} coloured pixels within 40 px) and its body in its colour (${colour} pixels)`);
    await e.close();
    await sleep(100);
  }
  log('spar view checked');
});
