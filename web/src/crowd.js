// The crowd: every character as the humanoid skeleton of its keyframe set, posed each frame from
// the joint rotations the world interpolated, placed by its rigid body, tinted by its control
// state. One instanced mesh per bone, so a thousand characters are a dozen draw calls.
import * as THREE from 'three';
import { CSS2DObject } from 'three/addons/renderers/CSS2DRenderer.js';

const LABELLED_MAX = 24; // characters get a state label when the crowd is no bigger than this
const PUSH_FLASH_N = 2.0;

export class Crowd {
  constructor(desc, root) {
    const c = desc.crowd;
    this.L = desc.layout;
    this.n = c.characters;
    this.joints = c.joints;
    this.states = c.states;
    this.colours = c.colours.map((h) => new THREE.Color(h));
    this.flashColour = new THREE.Color(0xffffff);
    const J = this.joints.length;
    const children = this.joints.map(() => 0);
    this.joints.forEach((j) => { if (j.parent !== null) children[j.parent]++; });
    // Bones: [frame joint, geometry], the geometry already placed in that joint's frame.
    const bones = [];
    const up = new THREE.Vector3(0, 1, 0);
    const segment = (from, to, r) => {
      const a = new THREE.Vector3().fromArray(from);
      const b = new THREE.Vector3().fromArray(to);
      const d = b.clone().sub(a);
      const len = d.length();
      const g = new THREE.CapsuleGeometry(r, Math.max(len - 2 * r, 0.001), 4, 10);
      g.applyQuaternion(new THREE.Quaternion().setFromUnitVectors(up, d.normalize()));
      g.translate((a.x + b.x) / 2, (a.y + b.y) / 2, (a.z + b.z) / 2);
      return g;
    };
    this.joints.forEach((j, k) => {
      if (j.parent !== null) {
        const trunk = j.parent === 0 || /spine|neck/.test(j.name);
        bones.push([j.parent, segment([0, 0, 0], j.offset_m, trunk && !/shoulder|hip/.test(j.name) ? 0.09 : 0.045)]);
      }
      if (children[k] === 0) {
        if (/neck|head/.test(j.name)) {
          const g = new THREE.SphereGeometry(0.11, 16, 12);
          g.translate(0, 0.12, 0);
          bones.push([k, g]);
        } else {
          const len = /knee|leg|shin/.test(j.name) ? 0.31 : 0.26;
          bones.push([k, segment([0, 0, 0], [0, -len, 0], 0.04)]);
        }
      }
    });
    this.bones = bones.map(([frame, g]) => {
      const mesh = new THREE.InstancedMesh(g, new THREE.MeshStandardMaterial({ roughness: 0.7 }), Math.max(this.n, 1));
      mesh.count = this.n;
      mesh.frustumCulled = false;
      mesh.instanceMatrix.setUsage(THREE.DynamicDrawUsage);
      for (let i = 0; i < this.n; i++) mesh.setColorAt(i, this.colours[0]);
      root.add(mesh);
      return { frame, mesh };
    });
    this.world = Array.from({ length: J }, () => new THREE.Matrix4());
    this.body = new THREE.Matrix4();
    this.local = new THREE.Matrix4();
    this.p = new THREE.Vector3();
    this.q = new THREE.Quaternion();
    this.one = new THREE.Vector3(1, 1, 1);
    this.colour = new THREE.Color();
    this.shown = new Float32Array(this.n).fill(-1); // state (+ 0.5 while pushed) last coloured
    this.labels = [];
    if (this.n <= LABELLED_MAX) {
      for (let i = 0; i < this.n; i++) {
        const div = document.createElement('div');
        div.className = 'label';
        div.dataset.character = String(i);
        const obj = new CSS2DObject(div);
        root.add(obj);
        this.labels.push({ obj, div, state: -1 });
      }
    }
  }

  apply(f) {
    const L = this.L;
    const J = this.joints.length;
    const CF = L.character_floats;
    for (let i = 0; i < this.n; i++) {
      const o = L.characters_at + i * CF;
      this.p.set(f[o], f[o + 1], f[o + 2]);
      this.q.set(f[o + 3], f[o + 4], f[o + 5], f[o + 6]);
      this.body.compose(this.p, this.q, this.one);
      for (let j = 0; j < J; j++) {
        const jt = this.joints[j];
        const q = o + 12 + 4 * j;
        this.p.fromArray(jt.offset_m);
        if (jt.parent === null) this.p.x += f[o + 7], this.p.y += f[o + 8], this.p.z += f[o + 9];
        this.q.set(f[q], f[q + 1], f[q + 2], f[q + 3]);
        this.local.compose(this.p, this.q, this.one);
        this.world[j].multiplyMatrices(jt.parent === null ? this.body : this.world[jt.parent], this.local);
      }
      for (const b of this.bones) b.mesh.setMatrixAt(i, this.world[b.frame]);
      const state = f[o + 10] | 0;
      const shown = state + (f[o + 11] > PUSH_FLASH_N ? 0.5 : 0);
      if (shown !== this.shown[i]) {
        this.shown[i] = shown;
        this.colour.copy(this.colours[state] ?? this.colours[0]);
        if (shown !== state) this.colour.lerp(this.flashColour, 0.6);
        for (const b of this.bones) b.mesh.setColorAt(i, this.colour);
        this.coloursChanged = true;
      }
      const lab = this.labels[i];
      if (lab) {
        lab.obj.position.set(f[o], f[o + 1] + 0.95, f[o + 2]);
        if (state !== lab.state) {
          lab.state = state;
          lab.div.textContent = this.states[state] ?? '?';
          lab.div.dataset.state = this.states[state] ?? '';
          lab.div.classList.toggle('active', state !== 0);
        }
      }
    }
    for (const b of this.bones) {
      b.mesh.instanceMatrix.needsUpdate = true;
      if (this.coloursChanged && b.mesh.instanceColor) b.mesh.instanceColor.needsUpdate = true;
    }
    this.coloursChanged = false;
  }

  // World positions of character i's joints as drawn (read back from the bones' instance
  // matrices): for tests.
  drawnJoints(i) {
    const out = [];
    const m = new THREE.Matrix4();
    const v = new THREE.Vector3();
    for (let j = 0; j < this.joints.length; j++) {
      const b = this.bones.find((x) => x.frame === j);
      if (!b) { out.push(null); continue; }
      b.mesh.getMatrixAt(i, m);
      v.setFromMatrixPosition(m);
      out.push([v.x, v.y, v.z]);
    }
    return out;
  }
}
