// The rig: its frame (the box through the string anchors), the user's two grips at their measured
// positions, the eight strings from the anchors to the grips coloured by tension (grey at the
// minimum, red at the maximum), and the force each hand feels as an arrow.
import * as THREE from 'three';
import { arrowLength } from './world.js';

const HANDS = 2;
const STRINGS = 4;
const GRIP_COLOURS = [0xf2c14e, 0x63c7d6];

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
    this.v = new THREE.Vector3();
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
  }

  apply(f, L) {
    const valid = f[L.globals_at + 3] | 0;
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
        this.c.copy(this.lo).lerp(this.hi, Math.sqrt(x));
        for (const e of [k - 3, k]) { this.strCol[e] = this.c.r; this.strCol[e + 1] = this.c.g; this.strCol[e + 2] = this.c.b; }
      }
    }
    this.strings.visible = this.showStrings && !!this.info && valid !== 0;
    this.strings.geometry.attributes.position.needsUpdate = true;
    this.strings.geometry.attributes.color.needsUpdate = true;
  }
}
