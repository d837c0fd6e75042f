// The reaction study's page in a real browser, run by tests/tests/hil/study.rs (which serves
// `spidar study reactions` for one participant): `node study.mjs URL`. A scripted participant
// gives a wrong id, then a good one, watches each clip and presses an answer; the test checks what
// the page drew and hands the Rust test what it was shown and what it answered.
import { ask, check, log, open, pixels, run, RED } from './harness.mjs';

const [url] = process.argv.slice(2);
const study = (page) => page.evaluate(() => spidarView.study());
const phase = (page, p, index = null) => page.waitForFunction((p, index) => {
  const s = spidarView.study();
  return s && s.state.phase === p && (index === null || s.state.index === index);
}, { timeout: 30000, polling: 20 }, p, index);

run(async (browser) => {
  const page = await open(browser, url, '');
  await phase(page, 'welcome');

  // Nothing but the virtual human and the scenery drawn, from the user's eye, no HUD.
  const view = await page.evaluate(() => ({
    camera: spidarView.state().camera,
    hud: getComputedStyle(document.getElementById('hud')).display,
    grips: spidarView.grips().map((g) => g.visible),
    avatar: spidarView.desc().shapes.filter((s) => s.name.startsWith('avatar/')).map((s) => spidarView.shape(s.name).pos[1]),
  }));
  check(view.camera === 'eye' && view.hud === 'none', `the study is seen from the user's eye without the HUD (${view.camera}, hud ${view.hud})`);
  check(view.grips.every((v) => !v), 'the user\'s grips are not drawn');
  check(view.avatar.length > 0 && view.avatar.every((y) => y < -50), `the avatar's ${view.avatar.length} shapes are not in the clip (far below the floor)`);
  const red = await pixels(page, RED);
  check(red.n > 500, `the virtual human is on the screen (${red.n} red pixels)`);

  // An id the CSV cannot hold is refused with a note; a good one starts the clips.
  await page.type('[data-study=participant]', 'P 07');
  await page.click('[data-study=start]');
  await page.waitForFunction(() => spidarView.study().state.note !== '', { timeout: 10000 });
  const note = await page.$eval('[data-study=note]', (e) => e.textContent);
  check(note.includes('1 to 40 letters'), `a bad participant id is refused: ${note}`);
  await page.$eval('[data-study=participant]', (e) => { e.value = ''; });
  await page.type('[data-study=participant]', 'P07');
  await page.click('[data-study=start]');

  const of = (await study(page)).state.of;
  for (let i = 0; i < of; i++) {
    await phase(page, 'ask', i);
    const s = (await study(page)).state;
    // The scripted participant: right on some, wrong on others, by the clip's id.
    const answer = (s.clip * 3 + i) % 4;
    await page.click(`[data-study=answer][data-answer="${answer}"]`);
    log(`clip ${s.clip} (${i + 1} of ${of}): answered ${s.choices[answer]}`);
  }
  await phase(page, 'done');
  const r = await study(page);
  check(r.shown.length === of && r.answers.length === of, `${of} clips shown and ${r.answers.length} answered`);
  const least = Math.min(...r.shown.map((c) => c.frames));
  check(least >= 5, `every clip played: at least ${least} frames drawn of each`);
  const thanks = await page.$eval('[data-study=done]', (e) => e.textContent);
  check(thanks.includes('P07'), `the participant is thanked: ${thanks}`);
  await ask({ ask: 'subject', shown: r.shown, answers: r.answers });
});
