// The heads-up display: the rig's lifecycle, rate, lateness p99, force per hand, faults, the
// world link's state, the scene's counters (hits given and taken), and the camera buttons. Every
// number sits in an element with a data-hud key, which the browser tests read.

const fmtDur = (s) => (!Number.isFinite(s) ? '-' : s < 1e-3 ? `${(s * 1e6).toFixed(1)} us` : `${(s * 1e3).toFixed(2)} ms`);

export class Hud {
  constructor(el, { onCamera, onFullScreen, onToggle }) {
    this.el = el;
    el.innerHTML = `
      <div class="title"><span data-hud="scene">spidar</span> <span data-hud="connection" class="bad">connecting</span></div>
      <div class="row">rig <span data-hud="rig_state">-</span> &middot; <span data-hud="rate_hz">-</span> Hz &middot; late p99 <span data-hud="lateness_p99">-</span></div>
      <div class="row">force L <span data-hud="force_l">-</span> N &middot; R <span data-hud="force_r">-</span> N</div>
      <div class="row">faults <span data-hud="faults">-</span> &middot; device errors <span data-hud="device_errors">-</span> &middot; stale <span data-hud="stale_ticks">-</span> &middot; misses <span data-hud="misses">-</span></div>
      <div class="row">world link <span data-hud="link">-</span> &middot; <span data-hud="step_rate">-</span> steps/s &middot; t <span data-hud="t">-</span> s</div>
      <div class="row" data-hud="counters"></div>
      <div class="row" id="legend"></div>
      <div class="row">viewers <span data-hud="viewers">-</span> &middot; frames <span data-hud="frame_rate">-</span>/s &middot; picture age p99 <span data-hud="picture_age">-</span></div>
      <div class="row"><button data-cam="eye">user's eye</button><button data-cam="orbit">orbit</button><button data-full>full screen</button></div>
      <div class="row"><button data-toggle="workspace" title="key w: where each hand can be pushed with the force limit in every direction">workspace</button><button data-toggle="near" class="on" title="key n: strings near another hand's string (magenta) or a forearm (orange)">near strings</button></div>`;
    this.k = {};
    for (const e of el.querySelectorAll('[data-hud]')) this.k[e.dataset.hud] = e;
    for (const b of el.querySelectorAll('[data-cam]')) b.onclick = () => onCamera(b.dataset.cam);
    el.querySelector('[data-full]').onclick = onFullScreen;
    for (const b of el.querySelectorAll('[data-toggle]')) b.onclick = () => onToggle && onToggle(b.dataset.toggle);
    this.counterEls = [];
  }

  setScene(desc) {
    this.k.scene.textContent = `spidar \u00b7 ${desc.name}`;
    const c = this.k.counters;
    c.innerHTML = '';
    const title = desc.crowd ? 'crowd' : desc.name.startsWith('boxing') ? 'virtual human' : 'scene';
    c.append(`${title}: `);
    this.counterEls = desc.counters.map((name, i) => {
      const span = document.createElement('span');
      span.dataset.counter = name;
      const wrap = document.createElement('span');
      wrap.append(`${i ? ' \u00b7 ' : ''}${name} `, span);
      c.append(wrap);
      return span;
    });
    const legend = this.el.querySelector('#legend');
    legend.innerHTML = '';
    if (desc.crowd) {
      legend.append('states:');
      desc.crowd.states.forEach((s, i) => {
        const sw = document.createElement('span');
        sw.style.background = desc.crowd.colours[i];
        legend.append(sw, s);
      });
    }
  }

  setConnection(state) {
    this.k.connection.textContent = state;
    this.k.connection.className = state === 'connected' ? 'ok' : 'bad';
  }

  // Shows a toggle's state on its button.
  setToggle(name, on) {
    const b = this.el.querySelector(`[data-toggle="${name}"]`);
    if (b) b.classList.toggle('on', on);
  }

  setCamera(name) {
    for (const b of this.el.querySelectorAll('[data-cam]')) b.classList.toggle('on', b.dataset.cam === name);
  }

  setStatus(s) {
    const k = this.k;
    const r = s.rig;
    k.rig_state.textContent = r ? r.state : 'no rig status';
    k.rig_state.className = r && r.state === 'active' ? 'ok' : 'bad';
    k.rate_hz.textContent = r ? r.rate_hz.toFixed(1) : '-';
    k.lateness_p99.textContent = r ? fmtDur(r.lateness_p99_s) : '-';
    k.force_l.textContent = r ? r.force_abs_n[0].toFixed(2) : '-';
    k.force_r.textContent = r ? r.force_abs_n[1].toFixed(2) : '-';
    k.faults.textContent = r ? String(r.faults) : '-';
    k.faults.className = r && r.faults > 0 ? 'bad' : '';
    k.device_errors.textContent = r ? String(r.device_errors) : '-';
    k.stale_ticks.textContent = r ? String(r.stale_ticks) : '-';
    k.misses.textContent = r ? String(r.misses) : '-';
    k.link.textContent = s.ended ? 'world stopped' : s.link.state;
    k.link.className = s.link.state === 'up' && !s.ended ? 'ok' : 'bad';
    k.step_rate.textContent = s.step_rate_hz.toFixed(1);
    k.t.textContent = s.t_s.toFixed(1);
    k.viewers.textContent = String(s.viewers);
    const age = s.picture_age && (s.picture_age.headset || s.picture_age.screen);
    k.picture_age.textContent = age ? `${age.p99_ms.toFixed(1)} ms` : '-';
    s.counters.forEach((c, i) => {
      const e = this.counterEls[i];
      if (e) e.textContent = Number.isInteger(c.value) ? String(c.value) : c.value.toFixed(1);
    });
  }

  setFrameRate(hz) {
    this.k.frame_rate.textContent = hz.toFixed(0);
  }
}
