// The headset: the same page in a WebXR immersive session (three.js's WebXR support). The world is
// drawn at true scale from the headset's two eyes; a short registration ties the headset's floor
// frame to the scene (the person holds the controllers on both grips and presses a trigger: the
// two controllers' positions are mapped onto the two grips' drawn positions by a turn about the
// vertical and a shift), after which the grips, and the avatar's fists that follow them, are drawn
// where the person's hands are. A headset draws 72 to 120 pictures a second and the world's frames
// come at their own rate (after every world step for a small scene, 60 a second at the least):
// the bodies are interpolated between the two newest frames the page has, one world frame
// interval behind the newest (no later: with frames faster than the display that is the newest
// frame); the grips, which the rig measures, are extrapolated along their velocity (from the
// hands of every frame that came, by their ticks' times: the receiving worker keeps them) to the
// time the picture is shown, at most MAX_LEAD_MS ahead of their tick.
//
// This file never changes how the page draws outside a session, and never writes the frames it is
// given (it blends into its own buffer).
import * as THREE from 'three';

const UP = new THREE.Vector3(0, 1, 0);
// Grips drawn at most this far ahead of the tick they were measured at (a display frame and a
// half at 60 Hz): a hand that stops suddenly is drawn past where it stopped by its speed times the
// lead, for no longer than the lead (docs/view.md: what the extrapolation costs on the simulated
// user's punches).
export const MAX_LEAD_MS = 25;
// The grips' velocity over at least this much of their newest history (encoder steps average out).
const VELOCITY_WINDOW_MS = 8;
// Hand positions kept for the velocity.
const HISTORY = 16;
// Registration refused when the controllers' distance apart differs from the grips' by more.
const REGISTER_TOLERANCE_M = 0.05;

// Blends frames: between the two newest (bodies) and ahead of the newest (grips).
export class Interpolator {
  constructor() {
    this.prev = null;
    this.latest = null;
    // The world's frame interval (ms): 1000 / the scene description's frame_hz.
    this.frameMs = 1000 / 60;
    this.out = null;
    // The newest frames' hand positions by their tick's wall-clock time: { wallMs, p: [6] }.
    this.history = [];
    // Pictures drawn, not yet judged: when shown (wall clock, ms), the grips as drawn and as the
    // newest frame had them; and the judged ones' distances from the measured hands, not yet
    // reported (mm: { err, still }).
    this.shown = [];
    this.judged = [];
  }

  // The next judged picture's grip distances from the measured hands, or null.
  takeJudged() {
    return this.judged.shift() ?? null;
  }

  // Judges the pictures shown within the history: the measured hands then (between the two
  // frames whose ticks bracket the showing) against the grips drawn.
  judge() {
    const H = this.history;
    const n = H.length;
    if (n < 2) return;
    let k = 0;
    while (this.shown.length && this.shown[0].wallMs <= H[n - 1].wallMs) {
      const s = this.shown.shift();
      if (s.wallMs < H[0].wallMs) continue; // shown before the frames kept: not judged
      while (H[k + 1].wallMs < s.wallMs) k++;
      const [a, b] = [H[k], H[k + 1]];
      const u = (s.wallMs - a.wallMs) / (b.wallMs - a.wallMs);
      let err = 0;
      let still = 0;
      for (let h = 0; h < 2; h++) {
        let e = 0;
        let e0 = 0;
        for (let i = 3 * h; i < 3 * h + 3; i++) {
          const truth = a.p[i] + (b.p[i] - a.p[i]) * u;
          e += (s.drawn[i] - truth) ** 2;
          e0 += (s.still[i] - truth) ** 2;
        }
        err = Math.max(err, Math.sqrt(e));
        still = Math.max(still, Math.sqrt(e0));
      }
      this.judged.push({ err: 1000 * err, still: 1000 * still });
      if (this.judged.length > 64) this.judged.shift();
    }
  }

  // A new frame came (`frame`: the page's { f, seq, t, stamp, arrivedMs }) at page time `nowMs`;
  // `L`: the layout.
  // `hands`: every frame's hands that came, when the page has them (its receiving worker's:
  // [{ wallMs, p }], oldest first), else null: the frames pushed here make the history.
  push(frame, nowMs, L, hands = null) {
    if (this.latest && frame === this.latest.frame) return;
    // The two newest frames' numbers are kept as copies (the page's frame buffers are used again),
    // in two arrays used in turn.
    const spare = this.prev && this.prev.f.length === frame.f.length ? this.prev.f : new Float32Array(frame.f.length);
    spare.set(frame.f);
    this.prev = this.latest;
    this.latest = { frame, f: spare, at: frame.arrivedMs ?? nowMs };
    if (hands && hands.length >= 2) {
      this.history = hands;
      this.judge();
      return;
    }
    const wallMs = frame.stamp && frame.stamp.wallMs > 0 ? frame.stamp.wallMs : null;
    if (wallMs === null || !L) return;
    const last = this.history[this.history.length - 1];
    if (last && wallMs <= last.wallMs) return;
    const p = [];
    for (let h = 0; h < 2; h++) for (let i = 0; i < 3; i++) p.push(frame.f[L.hands_at + h * L.hand_floats + i]);
    this.history.push({ wallMs, p });
    if (this.history.length > HISTORY) this.history.shift();
    this.judge();
  }

  // The grips' velocity (m/ms, six numbers) over the newest history, or null.
  velocity() {
    const n = this.history.length;
    if (n < 2) return null;
    const b = this.history[n - 1];
    let a = this.history[0];
    for (let k = n - 2; k >= 0; k--) if (b.wallMs - this.history[k].wallMs >= VELOCITY_WINDOW_MS) { a = this.history[k]; break; }
    const dt = b.wallMs - a.wallMs;
    if (!(dt > 0.5)) return null;
    return b.p.map((x, i) => (x - a.p[i]) / dt);
  }

  // The frame to draw at page time `nowMs` for a picture shown at page time `showMs`, and how far
  // ahead of their tick the grips are drawn (ms).
  at(nowMs, desc, showMs = nowMs) {
    const L = desc.layout;
    const cur = this.latest.f;
    if (!this.out || this.out.length !== cur.length) this.out = new Float32Array(cur.length);
    const out = this.out;
    out.set(cur);
    if (this.prev && this.prev.f.length === cur.length) {
      const old = this.prev.f;
      // Bodies at the world time one frame interval before the newest's, moved on by the time
      // since it came: between the two newest frames.
      const gapS = this.latest.frame.t - this.prev.frame.t;
      const since = Math.max(0, nowMs - this.latest.at);
      const alpha = gapS > 0 ? Math.min(1, Math.max(0, 1 + (since - this.frameMs) / (1000 * gapS))) : 1;
      if (alpha < 1) {
        for (let k = 0; k < desc.shapes.length; k++) blendPose(old, cur, L.shapes_at + k * L.shape_floats, alpha, out);
        // The crowd: each character's body pose and its drawn joints (after its state and push).
        const chars = desc.crowd ? desc.crowd.characters : 0;
        for (let i = 0; i < chars; i++) {
          const o = L.characters_at + i * L.character_floats;
          blendPose(old, cur, o, alpha, out);
          for (let j = o + 9; j < o + L.character_floats; j++) out[j] = old[j] + (cur[j] - old[j]) * alpha;
        }
      }
    }
    // Grips: along their velocity, from their tick to the picture's showing.
    const st = this.latest.frame.stamp;
    const v = this.velocity();
    if (!v || !st || !(st.wallMs > 0)) return { f: out, leadMs: 0 };
    const showWallMs = performance.timeOrigin + showMs;
    const lead = Math.min(MAX_LEAD_MS, Math.max(0, showWallMs - st.wallMs));
    const drawn = [];
    const still = [];
    for (let h = 0; h < 2; h++) {
      const o = L.hands_at + h * L.hand_floats;
      for (let i = 0; i < 3; i++) {
        out[o + i] = cur[o + i] + v[3 * h + i] * lead;
        drawn.push(out[o + i]);
        still.push(cur[o + i]);
      }
    }
    this.shown.push({ wallMs: showWallMs, drawn, still });
    if (this.shown.length > 64) this.shown.shift();
    return { f: out, leadMs: lead };
  }
}

// Position lerp and quaternion nlerp of the pose at `o` (xyz, xyzw).
function blendPose(a, b, o, t, out) {
  for (let i = 0; i < 3; i++) out[o + i] = a[o + i] + (b[o + i] - a[o + i]) * t;
  const dot = a[o + 3] * b[o + 3] + a[o + 4] * b[o + 4] + a[o + 5] * b[o + 5] + a[o + 6] * b[o + 6];
  const s = dot < 0 ? -1 : 1;
  let len = 0;
  for (let i = 3; i < 7; i++) {
    out[o + i] = a[o + i] * (1 - t) + s * b[o + i] * t;
    len += out[o + i] * out[o + i];
  }
  len = Math.sqrt(len) || 1;
  for (let i = 3; i < 7; i++) out[o + i] /= len;
}

// The rotation about the vertical and the shift that carry the two points `from` (headset floor
// frame) onto `to` (scene): the turn lines up their horizontal directions, the shift their
// midpoints. Null when the points are too close to tell a direction.
export function registration(from, to) {
  const dF = new THREE.Vector3().subVectors(from[1], from[0]);
  const dT = new THREE.Vector3().subVectors(to[1], to[0]);
  if (Math.hypot(dF.x, dF.z) < 0.05 || Math.hypot(dT.x, dT.z) < 0.05) return null;
  const angle = Math.atan2(-dT.z, dT.x) - Math.atan2(-dF.z, dF.x);
  const q = new THREE.Quaternion().setFromAxisAngle(UP, angle);
  const midF = new THREE.Vector3().addVectors(from[0], from[1]).multiplyScalar(0.5);
  const midT = new THREE.Vector3().addVectors(to[0], to[1]).multiplyScalar(0.5);
  const pos = midT.sub(midF.applyQuaternion(q));
  return { position: pos, quaternion: q, spreadM: Math.abs(dF.length() - dT.length()) };
}

export class Headset {
  // `renderer`: the page's WebGLRenderer; `scene`: the scene the origin is added to; `grips()`:
  // the drawn grips' scene positions ([left, right], null when not shown); `onChange()`: called
  // when a session starts or ends.
  constructor(renderer, scene, { grips, onChange }) {
    this.renderer = renderer;
    this.grips = grips;
    this.onChange = onChange;
    this.session = null;
    this.supported = false;
    this.registered = false;
    this.message = '';
    // The headset's floor frame in the scene: the camera and the controllers ride on it.
    this.origin = new THREE.Group();
    this.origin.name = 'headset origin';
    scene.add(this.origin);
    this.camera = new THREE.PerspectiveCamera(70, 1, 0.02, 200);
    this.origin.add(this.camera);
    this.interp = new Interpolator();
    this.hands = {}; // handedness -> the controller's grip (a Group in the floor frame)
    const marker = new THREE.Mesh(new THREE.TorusGeometry(0.06, 0.004, 6, 24),
      new THREE.MeshBasicMaterial({ color: 0xd0d0ff, transparent: true, opacity: 0.7 }));
    this.markers = [];
    for (let i = 0; i < 2; i++) {
      const g = renderer.xr.getControllerGrip(i);
      g.addEventListener('connected', (e) => { this.hands[e.data.handedness] = g; });
      g.addEventListener('disconnected', (e) => { if (this.hands[e.data.handedness] === g) delete this.hands[e.data.handedness]; });
      const m = marker.clone();
      g.add(m);
      this.markers.push(m);
      this.origin.add(g);
      const c = renderer.xr.getController(i);
      c.addEventListener('selectstart', () => this.register());
      this.origin.add(c);
    }
    this.button = document.createElement('button');
    this.button.id = 'xr-button';
    this.button.textContent = 'Headset';
    Object.assign(this.button.style, { position: 'absolute', right: '8px', bottom: '8px', display: 'none',
      font: 'inherit', background: '#33373e', color: '#e8e8e8', border: '1px solid #555', borderRadius: '3px', padding: '4px 10px' });
    this.button.addEventListener('click', () => (this.session ? this.session.end() : this.enter()));
    document.body.appendChild(this.button);
    if (navigator.xr) {
      navigator.xr.isSessionSupported('immersive-vr').then((ok) => {
        this.supported = ok;
        this.button.style.display = ok ? '' : 'none';
      }).catch(() => {});
    }
  }

  get presenting() {
    return !!this.session && this.renderer.xr.isPresenting;
  }

  // Places the floor frame's origin under the user's eye point, facing the scene's -z (before a
  // registration).
  place(eyeM) {
    if (this.registered || !eyeM) return;
    this.origin.position.set(eyeM[0], 0, eyeM[2]);
    this.origin.quaternion.identity();
  }

  async enter() {
    if (this.session || !navigator.xr) return;
    const session = await navigator.xr.requestSession('immersive-vr', { optionalFeatures: ['local-floor', 'hand-tracking'] });
    this.renderer.xr.enabled = true;
    this.renderer.xr.setReferenceSpaceType('local-floor');
    await this.renderer.xr.setSession(session);
    this.session = session;
    this.button.textContent = 'Leave headset';
    session.addEventListener('end', () => {
      this.session = null;
      this.renderer.xr.enabled = false;
      this.button.textContent = 'Headset';
      this.onChange();
    });
    this.onChange();
  }

  // The controllers' grip positions in the floor frame: [left, right], or null when one is missing.
  controllers() {
    const l = this.hands.left;
    const r = this.hands.right;
    if (!l || !r || !l.visible || !r.visible) return null;
    return [l.position.clone(), r.position.clone()];
  }

  // Registers the floor frame to the scene with the controllers on the grips: true when done;
  // else false with the reason in `message`.
  register() {
    const from = this.controllers();
    const to = this.grips();
    if (!from) { this.message = 'registration: both controllers must be tracked'; return false; }
    if (!to || !to[0] || !to[1]) { this.message = 'registration: both grips must be measured (the rig active)'; return false; }
    const r = registration(from, to.map((p) => new THREE.Vector3().fromArray(p)));
    if (!r) { this.message = 'registration: hold the controllers apart, one on each grip'; return false; }
    if (r.spreadM > REGISTER_TOLERANCE_M) {
      this.message = `registration refused: the controllers are ${(r.spreadM * 100).toFixed(1)} cm more or less apart than the grips; hold one on each grip`;
      return false;
    }
    this.origin.position.copy(r.position);
    this.origin.quaternion.copy(r.quaternion);
    this.origin.updateMatrixWorld(true);
    this.registered = true;
    this.message = 'registered';
    return true;
  }

  // The frame to draw now for a picture shown at `showMs` (page clock) and the grips' lead (ms);
  // `latest` is the newest frame. `judged()`: an earlier picture's grips against the measured hands.
  frame(latest, desc, nowMs, showMs, hands = null) {
    if (desc.frame_hz > 0) this.interp.frameMs = 1000 / desc.frame_hz;
    this.interp.push(latest, nowMs, desc.layout, hands);
    return this.interp.at(nowMs, desc, showMs);
  }

  judged() {
    return this.interp.takeJudged();
  }

  // Where the eyes are (scene frame), for hiding the avatar's own head.
  eyePosition(out) {
    return this.renderer.xr.getCamera().getWorldPosition(out);
  }

  showMarkers(on) {
    for (const m of this.markers) m.visible = on;
  }

  state() {
    return {
      supported: this.supported,
      presenting: this.presenting,
      registered: this.registered,
      message: this.message,
      origin: { position: this.origin.position.toArray(), quaternion: this.origin.quaternion.toArray() },
      frameMs: this.interp.frameMs,
    };
  }
}
