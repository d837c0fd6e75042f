// The reaction study's panel (`spidar study reactions`): the participant's id, then for each clip
// a caption while it plays and the question with Table IV's four answers as buttons. The study's
// state comes from the server as `study` messages (the whole state each time); the id and the
// answers go back over the page's WebSocket. Every control has a data-study key, which the
// browser test presses as a participant would.

const esc = (s) => String(s).replace(/[&<>"]/g, (c) => ({ '&': '&amp;', '<': '&lt;', '>': '&gt;', '"': '&quot;' })[c]);

export class Study {
  constructor(el, send) {
    this.el = el;
    this.send = send;
    this.state = null;
    this.key = null;
    // Each clip shown, in order: its position, id and the frames drawn while it played.
    this.shown = [];
    this.answers = [];
    this.askedAt = null;
    el.style.display = '';
    document.title = 'spidar: reaction study';
  }

  setState(s) {
    this.state = s;
    if (s.phase === 'playing' || s.phase === 'ready') {
      const last = this.shown[this.shown.length - 1];
      if (!last || last.index !== s.index || last.participant !== s.participant) {
        this.shown.push({ participant: s.participant, index: s.index, clip: s.clip, frames: 0 });
      }
    }
    // Drawn again only when the question or the phase changes (an id being typed stays).
    const key = `${s.phase}|${s.participant}|${s.index}|${s.clip}|${s.note}`;
    if (key === this.key) return;
    this.key = key;
    this.render(s);
  }

  // A frame was drawn: counted for the clip playing.
  frameDrawn() {
    const last = this.shown[this.shown.length - 1];
    if (this.state && this.state.phase === 'playing' && last && last.index === this.state.index) last.frames++;
  }

  render(s) {
    const n = `${Math.min(s.index + 1, s.of)} of ${s.of}`;
    if (s.phase === 'welcome') {
      this.el.innerHTML = `
        <div class="big">Which part was attacked?</div>
        <p>You will see the virtual human react to a punch ${s.of} times, each time once. The one who punches
        is not shown. After each, choose which part of the virtual human the punch was aimed at.</p>
        <label>Participant id <input data-study="participant" autocomplete="off" maxlength="40"></label>
        <button data-study="start">start</button>
        <div class="bad" data-study="note">${esc(s.note || '')}</div>`;
      const input = this.el.querySelector('[data-study=participant]');
      const start = () => this.send({ cmd: 'study-begin', participant: input.value.trim() });
      this.el.querySelector('[data-study=start]').onclick = start;
      input.onkeydown = (e) => { if (e.key === 'Enter') start(); };
      input.focus();
    } else if (s.phase === 'ready' || s.phase === 'playing') {
      this.el.innerHTML = `<div data-study="caption">Reaction ${n}: watch the virtual human</div>`;
    } else if (s.phase === 'ask') {
      this.el.innerHTML = `
        <div class="big" data-study="question">Reaction ${n}: which part was attacked?</div>
        <div>(the virtual human's own left and right)</div>
        <div>${s.choices.map((c, i) => `<button data-study="answer" data-answer="${i}">${esc(c)}</button>`).join('')}</div>`;
      this.askedAt = performance.now();
      const asked = { index: s.index, clip: s.clip };
      for (const b of this.el.querySelectorAll('[data-study=answer]')) {
        b.onclick = () => {
          const response_s = (performance.now() - this.askedAt) / 1000;
          for (const o of this.el.querySelectorAll('button')) o.disabled = true;
          b.classList.add('on');
          const answer = Number(b.dataset.answer);
          this.answers.push({ ...asked, answer, response_s });
          this.send({ cmd: 'study-answer', ...asked, answer, response_s });
        };
      }
    } else if (s.phase === 'done') {
      this.el.innerHTML = `<div class="big" data-study="done">Thank you, ${esc(s.participant)}: all ${s.of} answers are recorded.</div>`;
    }
  }

  report() {
    return { state: this.state, shown: this.shown.slice(), answers: this.answers.slice() };
  }
}
