// The playback bar of a replay (`spidar replay FILE`): play/pause, a seek slider with the time
// shown, the speed, and how the recording ends when it was cut short. Shown only when the server
// says it plays a recording (a `playback` message); the commands go back over the page's
// WebSocket as small JSON messages. Every control has a data-pb key, which the browser tests use.

export const SPEEDS = [0.25, 0.5, 1, 2, 4];

const fmt = (t) => (Number.isFinite(t) ? t.toFixed(2) : '-');

export class Playback {
  constructor(el, send) {
    this.el = el;
    this.send = send;
    this.state = null;
    this.shownT = null;
    this.dragging = false;
    this.lastSeek = 0;
    el.innerHTML = `
      <button data-pb="play">play</button>
      <input data-pb="slider" type="range" min="0" max="1" step="0.001" value="0">
      <span data-pb="time">-</span>
      <select data-pb="speed">${SPEEDS.map((x) => `<option value="${x}">${x}x</option>`).join('')}</select>
      <span data-pb="note"></span>`;
    this.k = {};
    for (const e of el.querySelectorAll('[data-pb]')) this.k[e.dataset.pb] = e;
    this.k.speed.value = '1';
    this.k.play.onclick = () => this.send({ cmd: this.state && this.state.playing ? 'pause' : 'play' });
    this.k.speed.onchange = () => this.send({ cmd: 'speed', x: Number(this.k.speed.value) });
    // While dragging: a seek at most every 100 ms; the last one when let go.
    this.k.slider.oninput = () => {
      this.dragging = true;
      const now = performance.now();
      if (now - this.lastSeek >= 100) this.seek(Number(this.k.slider.value));
    };
    this.k.slider.onchange = () => {
      this.dragging = false;
      this.seek(Number(this.k.slider.value));
    };
    document.title = 'spidar: replay';
  }

  seek(t) {
    this.lastSeek = performance.now();
    this.send({ cmd: 'seek', t_s: t });
  }

  // The replay's state (a `playback` message).
  setState(p) {
    this.state = p;
    this.el.style.display = '';
    const k = this.k;
    k.play.textContent = p.playing ? 'pause' : p.at_end ? 'replay' : 'play';
    k.play.classList.toggle('on', p.playing);
    k.slider.min = String(p.first_s);
    k.slider.max = String(p.last_s);
    if (!this.dragging && this.shownT === null) k.slider.value = String(p.t_s);
    if (document.activeElement !== k.speed) k.speed.value = String(p.speed);
    k.note.textContent = p.complete ? p.file : `${p.file}: ${p.ends}`;
    k.note.className = p.complete ? '' : 'bad';
    this.setTime(this.shownT);
  }

  // The time of the frame drawn.
  setTime(t) {
    this.shownT = t;
    if (!this.state) return;
    const shown = t ?? this.state.frame_t_s;
    this.k.time.textContent = `${fmt(shown)} / ${fmt(this.state.last_s)} s`;
    if (!this.dragging && t !== null) this.k.slider.value = String(t);
  }
}
