// The crowd: every character as its drawn figure, the 16-joint humanoid of its keyframe set posed
// as the world computes it (interpolated from the keyframes, legs stood on the feet, placed on its
// rigid body): the frame carries each joint's position in the scene, so the page draws the world's
// figure as it is, a bone from each joint to its parent, tinted by the character's control state.
// One instanced mesh per bone, so a thousand characters are a score of draw calls. Drawn as people
// (crowdpeople.js) the same figure is clothed; the bones are then hidden (the toggle `b`).
import * as THREE from 'three';
import { litMaterial } from './materials.js';
import { CSS2DObject } from 'three/addons/renderers/CSS2DRenderer.js';
import { CrowdPeople } from './crowdpeople.js';

const LABELLED_MAX = 24; // characters get a state label when the crowd is no bigger than this
const PUSH_FLASH_N = 2.0;
// A character's numbers in a frame (world/src/look.rs): body position xyz, rotation xyzw, control
// state, push force, then per joint its position xyz.
const STATE = 7;
const PUSH = 8;
const HEAD_FLOATS = 9;
const JOINT_FLOATS = 3;

// How thick each bone is drawn (m), by the name of the joint it ends at.
function boneRadius(name) {
  if (/spine|neck/.test(name)) return 0.1;
  if (/hip/.test(name)) return 0.07;
  if (/knee|ankle/.test(name)) return 0.055;
  if (/shoulder/.test(name)) return 0.05;
  return 0.04;
}

// What is drawn at a joint itself (m; none: 0): the head, and the hands and feet.
function endRadius(name) {
  if (/head/.test(name)) return 0.11;
  if (/hand/.test(name)) return 0.045;
  if (/ankle/.test(name)) return 0.06;
  return 0;
}

export class Crowd {
  constructor(desc, root) {
    const c = desc.crowd;
    this.L = desc.layout;
    this.n = c.characters;
    this.joints = c.joints;
    this.states = c.states;
    this.colours = c.colours.map((h) => new THREE.Color(h));
    this.flashColour = new THREE.Color(0xffffff);
    this.head = this.joints.findIndex((j) => /head/.test(j.name));
    const mesh = (g) => {
      const m = new THREE.InstancedMesh(g, litMaterial({ roughness: 0.7 }), Math.max(this.n, 1));
      m.count = this.n;
      m.frustumCulled = false;
      m.instanceMatrix.setUsage(THREE.DynamicDrawUsage);
      for (let i = 0; i < this.n; i++) m.setColorAt(i, this.colours[0]);
      root.add(m);
      return m;
    };
    // Bones: a capsule from the parent joint (its origin) up its y axis to the joint, turned each
    // frame onto the segment between the two joints the frame carries. A bone's length is fixed
    // (the skeleton is rigid: every pose only turns joints), so its geometry is built once.
    this.bones = [];
    this.ends = [];
    this.joints.forEach((j, k) => {
      if (j.parent !== null) {
        const len = Math.hypot(...j.offset_m);
        const r = Math.min(boneRadius(j.name), len / 2);
        const g = new THREE.CapsuleGeometry(r, Math.max(len - 2 * r, 0.001), 4, 10);
        g.translate(0, len / 2, 0);
        this.bones.push({ joint: k, parent: j.parent, len, mesh: mesh(g) });
      }
      const e = endRadius(j.name);
      if (e > 0) this.ends.push({ joint: k, mesh: mesh(new THREE.SphereGeometry(e, 16, 12)) });
    });
    this.meshes = [...this.bones.map((b) => b.mesh), ...this.ends.map((e) => e.mesh)];
    this.people = new CrowdPeople(desc, root);
    this.asPeople = true;
    this.last = null;
    this.m = new THREE.Matrix4();
    this.a = new THREE.Vector3();
    this.b = new THREE.Vector3();
    this.d = new THREE.Vector3();
    this.q = new THREE.Quaternion();
    this.one = new THREE.Vector3(1, 1, 1);
    this.up = new THREE.Vector3(0, 1, 0);
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

  // People (true) or the figure's bones.
  setPeople(on) {
    this.asPeople = on;
    this.people.setVisible(on);
    for (const m of this.meshes) m.visible = !on;
    if (on && this.last) this.people.apply(this.last);
  }

  apply(f) {
    this.last = f;
    if (this.asPeople) this.people.apply(f);
    const L = this.L;
    const CF = L.character_floats;
    for (let i = 0; i < this.n; i++) {
      const o = L.characters_at + i * CF;
      const at = (j, v) => v.set(f[o + HEAD_FLOATS + JOINT_FLOATS * j], f[o + HEAD_FLOATS + JOINT_FLOATS * j + 1],
        f[o + HEAD_FLOATS + JOINT_FLOATS * j + 2]);
      for (const bone of this.bones) {
        at(bone.parent, this.a);
        at(bone.joint, this.b);
        const len = this.d.subVectors(this.b, this.a).length();
        if (len > 1e-9) this.q.setFromUnitVectors(this.up, this.d.divideScalar(len));
        else this.q.identity();
        this.m.compose(this.a, this.q, this.one);
        bone.mesh.setMatrixAt(i, this.m);
      }
      this.q.identity();
      for (const e of this.ends) {
        this.m.compose(at(e.joint, this.a), this.q, this.one);
        e.mesh.setMatrixAt(i, this.m);
      }
      const state = f[o + STATE] | 0;
      const shown = state + (f[o + PUSH] > PUSH_FLASH_N ? 0.5 : 0);
      if (shown !== this.shown[i]) {
        this.shown[i] = shown;
        this.colour.copy(this.colours[state] ?? this.colours[0]);
        if (shown !== state) this.colour.lerp(this.flashColour, 0.6);
        for (const m of this.meshes) m.setColorAt(i, this.colour);
        this.coloursChanged = true;
      }
      const lab = this.labels[i];
      if (lab) {
        // Above the drawn head, wherever the figure lies.
        if (this.head >= 0) at(this.head, lab.obj.position).y += 0.3;
        else lab.obj.position.set(f[o], f[o + 1] + 0.95, f[o + 2]);
        if (state !== lab.state) {
          lab.state = state;
          lab.div.textContent = this.states[state] ?? '?';
          lab.div.dataset.state = this.states[state] ?? '';
          lab.div.classList.toggle('active', state !== 0);
        }
      }
    }
    for (const m of this.meshes) {
      m.instanceMatrix.needsUpdate = true;
      if (this.coloursChanged && m.instanceColor) m.instanceColor.needsUpdate = true;
    }
    this.coloursChanged = false;
  }

  // World positions of character i's joints as drawn, read back from the meshes' instance
  // matrices (a bone's far end is its joint, its origin its parent; a drawn end sits on its
  // joint): for tests.
  drawnJoints(i) {
    const out = this.joints.map(() => null);
    const m = new THREE.Matrix4();
    for (const bone of this.bones) {
      bone.mesh.getMatrixAt(i, m);
      out[bone.joint] = new THREE.Vector3(0, bone.len, 0).applyMatrix4(m).toArray();
      if (out[bone.parent] === null) out[bone.parent] = new THREE.Vector3().setFromMatrixPosition(m).toArray();
    }
    for (const e of this.ends) {
      if (out[e.joint] !== null) continue;
      e.mesh.getMatrixAt(i, m);
      out[e.joint] = new THREE.Vector3().setFromMatrixPosition(m).toArray();
    }
    return out;
  }
}
