// The rig: its frame (the box through the string anchors), the user's two grips at their measured
// positions, the eight strings from the anchors to the grips coloured by tension (grey at the
// minimum, red at the maximum), and the force each hand feels as an arrow. Toggled from the HUD:
// each hand's force-feasible workspace (the cells where the force limit can be rendered in every
// direction, sent with the rig) as translucent points in the hand's colour (key `w`), and the
// strings that come near another hand's string (magenta) or a forearm (orange), as the frame's
// header flags mark them (key `n`, on by default).
import * as THREE from 'three';
import { arrowLength } from './world.js';

const HANDS = 2;
const STRINGS = 4;
const GRIP_COLOURS = [0xf2c14e, 0x63c7d6];
const NEAR_STRING = 0xff2bd6;
const NEAR_FOREARM = 0xff8c00;

export class Rig {
  constructor(root) {
    this.group = new THREE.Group();
    root.add(this.group);
    this.info = null;
    this.grips = [0, 1].map((h) => {
      const m = new THREE.Mesh(new THREE.SphereGeometry(1, 20, 14),
        new THREE.MeshStandardMaterial({ color: GRIP_COLOURS[h], roughness: 0.4, emissive: GRIP_COLOURS[h], emissiveIntensity: 0.25 }));
      m.scale.setScalar(0.04);
      m.visible = false;
      this.group.add(m);
      return m;
    });
    this.arrows = [0, 1].map((h) => {
      const a = new THREE.ArrowHelper(new THREE.Vector3(0, 1, 0), new THREE.Vector3(), 0.1, GRIP_COLOURS[h], 0.05, 0.03);
      a.visible = false;
      this.group.add(a);
      return a;
    });
    const g = new THREE.BufferGeometry();
    this.strPos = new Float32Array(HANDS * STRINGS * 2 * 3);
    this.strCol = new Float32Array(HANDS * STRINGS * 2 * 3);
    g.setAttribute('position', new THREE.BufferAttribute(this.strPos, 3).setUsage(THREE.DynamicDrawUsage));
    g.setAttribute('color', new THREE.BufferAttribute(this.strCol, 3).setUsage(THREE.DynamicDrawUsage));
    this.strings = new THREE.LineSegments(g, new THREE.LineBasicMaterial({ vertexColors: true }));
    this.strings.frustumCulled = false;
    this.strings.visible = false;
    this.group.add(this.strings);
    this.frame = null;
    this.showStrings = true;
    this.c = new THREE.Color();
    this.lo = new THREE.Color(0x9aa0a6);
    this.hi = new THREE.Color(0xff3b2f);
    this.nearString = new THREE.Color(NEAR_STRING);
    this.nearForearm = new THREE.Color(NEAR_FOREARM);
    this.v = new THREE.Vector3();
    this.workspaces = [];
    this.showWorkspace = false;
    this.showNear = true;
    this.near = new Array(HANDS * STRINGS).fill(null);
    this.last = null; // the frame applied last, to recolour when the near strings are toggled
  }

  // Each hand's feasible cells as a point cloud (built once per rig geometry).
  buildWorkspaces(info) {
    for (const w of this.workspaces) { this.group.remove(w); w.geometry.dispose(); w.material.dispose(); }
    this.workspaces = (info.workspace || []).map((ws, h) => {
      const pos = new Float32Array(ws.cells.length * 3);
      const [nx, ny] = ws.n;
      ws.cells.forEach((c, k) => {
        const i = c % nx;
        const j = Math.floor(c / nx) % ny;
        const l = Math.floor(c / (nx * ny));
        pos[k * 3] = ws.origin_m[0] + i * ws.step_m;
        pos[k * 3 + 1] = ws.origin_m[1] + j * ws.step_m;
        pos[k * 3 + 2] = ws.origin_m[2] + l * ws.step_m;
      });
      const g = new THREE.BufferGeometry();
      g.setAttribute('position', new THREE.BufferAttribute(pos, 3));
      const m = new THREE.PointsMaterial({ color: GRIP_COLOURS[h], size: ws.step_m * 0.5, transparent: true, opacity: 0.18, depthWrite: false });
      const p = new THREE.Points(g, m);
      p.visible = this.showWorkspace;
      p.userData.cells = ws.cells.length;
      this.group.add(p);
      return p;
    });
  }

  setWorkspaceShown(on) {
    this.showWorkspace = on;
    for (const w of this.workspaces) w.visible = on;
  }

  // Takes effect at once, on the frame shown (a paused page or replay included).
  setNearShown(on) {
    this.showNear = on;
    if (this.last) this.apply(this.last.f, this.last.L);
  }

  // For tests: the workspace clouds (cells, drawn) and each string's highlight (null, 'string' or
  // 'forearm') with its drawn colour.
  report() {
    return {
      workspace: this.workspaces.map((w) => ({ cells: w.userData.cells, visible: w.visible && this.group.visible })),
      showNear: this.showNear,
      near: this.near.slice(),
      colours: Array.from({ length: HANDS * STRINGS }, (_, i) => {
        const k = (i * 2 + 1) * 3;
        return [this.strCol[k], this.strCol[k + 1], this.strCol[k + 2]];
      }),
    };
  }

  setInfo(info) {
    this.info = info;
    if (this.frame) { this.group.remove(this.frame); this.frame.geometry.dispose(); }
    const box = new THREE.Box3();
    for (const hand of info.anchors_m) for (const a of hand) box.expandByPoint(this.v.fromArray(a));
    this.frame = new THREE.Box3Helper(box, 0x8c96a8);
    this.group.add(this.frame);
    for (let h = 0; h < HANDS; h++) {
      this.grips[h].scale.setScalar(info.grip_radius_m[h] || 0.04);
      for (let s = 0; s < STRINGS; s++) this.strPos.set(info.anchors_m[h][s], ((h * STRINGS + s) * 2) * 3);
    }
    this.strings.visible = true;
    this.buildWorkspaces(info);
  }

  apply(f, L) {
    this.last = { f, L };
    const valid = f[L.globals_at + 3] | 0;
    const flags = new Uint32Array(f.buffer, f.byteOffset, 4)[3];
    for (let h = 0; h < HANDS; h++) {
      const o = L.hands_at + h * L.hand_floats;
      const on = (valid >> h) & 1;
      const grip = this.grips[h];
      grip.visible = !!on;
      grip.position.set(f[o], f[o + 1], f[o + 2]);
      const a = this.arrows[h];
      this.v.set(f[o + 3], f[o + 4], f[o + 5]);
      const n = this.v.length();
      a.visible = !!on && n > 0.05;
      if (a.visible) {
        a.position.copy(grip.position);
        a.setDirection(this.v.multiplyScalar(1 / n));
        a.setLength(arrowLength(n) + 0.05, 0.05, 0.03);
      }
      if (!this.info) continue;
      const lo = this.info.tension_min_n[h];
      const hi = this.info.tension_max_n[h];
      for (let s = 0; s < STRINGS; s++) {
        const k = ((h * STRINGS + s) * 2 + 1) * 3;
        this.strPos[k] = f[o]; this.strPos[k + 1] = f[o + 1]; this.strPos[k + 2] = f[o + 2];
        const t = f[L.tensions_at + h * STRINGS + s];
        const x = Number.isFinite(t) && hi > lo ? Math.min(1, Math.max(0, (t - lo) / (hi - lo))) : 0;
        const i = h * STRINGS + s;
        this.near[i] = !on ? null : (flags >> i) & 1 ? 'string' : (flags >> (8 + i)) & 1 ? 'forearm' : null;
        if (this.showNear && this.near[i] === 'string') this.c.copy(this.nearString);
        else if (this.showNear && this.near[i] === 'forearm') this.c.copy(this.nearForearm);
        else this.c.copy(this.lo).lerp(this.hi, Math.sqrt(x));
        for (const e of [k - 3, k]) { this.strCol[e] = this.c.r; this.strCol[e + 1] = this.c.g; this.strCol[e + 2] = this.c.b; }
      }
    }
    this.strings.visible = this.showStrings && !!this.info && valid !== 0;
    this.strings.geometry.attributes.position.needsUpdate = true;
    this.strings.geometry.attributes.color.needsUpdate = true;
  }
}
