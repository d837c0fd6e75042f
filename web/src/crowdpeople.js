// The crowd drawn as people: every character's drawn figure (the joints the frame carries) clothed
// in shaded procedural pieces like the boxing scene's humanoids: a chest and hips shaped across
// the body's width, tapered arms and legs with rounded joints, a head with a face, hands, shoes.
// Each piece spans exactly the two joints of its bone (a bone's length is fixed: the skeleton only
// turns), turned about the bone so its width lies across the body (the character's body rotation
// gives the forward side), so the person moves joint for joint with the drawn figure and lies
// where the figure lies. Clothes take the character's state colour; skin and shoes keep theirs.
// One instanced mesh per piece: a thousand characters stay a few dozen draw calls.
//
// Never moves a joint: the pieces follow the frame's joints, whatever they are.
import * as THREE from 'three';
import { litMaterial } from './materials.js';

const SEGS = 12;
const SKIN = new THREE.Color(0xd9a27e);
const SHOE = new THREE.Color(0x2a2a2a);
const HAIR = new THREE.Color(0x2b211c);
const STATE = 7;
const PUSH = 8;
const HEAD_FLOATS = 9;
const PUSH_FLASH_N = 2.0;
// The ankle's range (rad): the foot turns up toward the shin's front by 20 degrees at most and
// points along the shin at most.
const FLEX_UP = 0.35;
const POINT = Math.PI / 2;

// A tapered limb along +y from 0 to len (radius r0 at 0, r1 at len) with a ball at 0.
function limb(len, r0, r1) {
  const c = new THREE.CylinderGeometry(r1, r0, len, SEGS, 1, true).translate(0, len / 2, 0);
  const b = new THREE.SphereGeometry(r0, SEGS, 8);
  return merge([c, b]);
}

// An ellipsoid centred at (0, y, 0) with half-axes a (across), b (along the bone), c (forward).
function ellipsoid(y, a, b, c) {
  return new THREE.SphereGeometry(1, SEGS + 4, 10).scale(a, b, c).translate(0, y, 0);
}

// Merges non-indexed copies of geometries (positions and normals) into one.
function merge(gs) {
  const parts = gs.map((g) => (g.index ? g.toNonIndexed() : g));
  const n = parts.reduce((s, g) => s + g.attributes.position.count, 0);
  const pos = new Float32Array(3 * n);
  const nor = new Float32Array(3 * n);
  let at = 0;
  for (const g of parts) {
    pos.set(g.attributes.position.array, 3 * at);
    nor.set(g.attributes.normal.array, 3 * at);
    at += g.attributes.position.count;
  }
  const out = new THREE.BufferGeometry();
  out.setAttribute('position', new THREE.BufferAttribute(pos, 3));
  out.setAttribute('normal', new THREE.BufferAttribute(nor, 3));
  return out;
}

// The piece drawn along the bone ending at joint `name` (length len), and whether it is skin.
function piece(name, len) {
  if (name === 'spine') return { g: ellipsoid(len * 0.5, 0.15, len * 0.75, 0.1) }; // hips
  if (name === 'neck') return { g: merge([ellipsoid(len * 0.55, 0.17, len * 0.58, 0.11), ellipsoid(len * 0.9, 0.2, 0.06, 0.09)]) }; // chest, shoulders
  if (name === 'head') {
    // The neck, and the head on the head joint: a face (nose) on the forward side, hair on top.
    const neck = new THREE.CylinderGeometry(0.045, 0.05, len, SEGS, 1, true).translate(0, len / 2, 0);
    const head = ellipsoid(len, 0.08, 0.105, 0.095);
    const nose = new THREE.ConeGeometry(0.012, 0.03, 8).rotateX(Math.PI / 2).translate(0, len - 0.01, 0.098);
    return { g: merge([neck, head, nose]), skin: true, hair: ellipsoid(len + 0.02, 0.083, 0.095, 0.09) };
  }
  if (/shoulder/.test(name)) return { g: limb(len, 0.05, 0.055) };
  if (/elbow/.test(name)) return { g: limb(len, 0.052, 0.043) };
  if (/hand/.test(name)) return { g: merge([limb(len, 0.043, 0.033), ellipsoid(len + 0.03, 0.035, 0.05, 0.022)]), skinEnd: true };
  if (/hip/.test(name)) return { g: new THREE.SphereGeometry(0.075, SEGS, 8).translate(0, len, 0) };
  if (/knee/.test(name)) return { g: limb(len, 0.075, 0.058) };
  if (/ankle/.test(name)) {
    // The shin, and a shoe on the ankle pointing forward, in the ankle's frame (the pieces'
    // frame moved to the bone's end, turned at the ankle: see `footAt`).
    // (Its sole at the ankle's height below it: the keyframe set's 4 cm.)
    const shoe = new THREE.BoxGeometry(0.095, 0.06, 0.22).translate(0, 0.01, 0.05);
    return { g: limb(len, 0.058, 0.046), shoe };
  }
  return { g: limb(len, 0.045, 0.04) };
}

export class CrowdPeople {
  constructor(desc, root) {
    const c = desc.crowd;
    this.L = desc.layout;
    this.n = c.characters;
    this.joints = c.joints;
    this.colours = c.colours.map((h) => new THREE.Color(h));
    this.flashColour = new THREE.Color(0xffffff);
    const mesh = (g, fixed) => {
      const m = new THREE.InstancedMesh(g, litMaterial({ roughness: 0.7 }), Math.max(this.n, 1));
      m.count = this.n;
      m.frustumCulled = false;
      m.instanceMatrix.setUsage(THREE.DynamicDrawUsage);
      for (let i = 0; i < this.n; i++) m.setColorAt(i, fixed ?? this.colours[0]);
      m.userData.fixed = fixed ?? null;
      root.add(m);
      return m;
    };
    this.pieces = [];
    this.joints.forEach((j, k) => {
      if (j.parent === null) return;
      const len = Math.hypot(...j.offset_m);
      const p = piece(j.name, len);
      const meshes = [mesh(p.g, p.skin ? SKIN : null)];
      if (p.hair) meshes.push(mesh(p.hair, HAIR));
      if (p.shoe) {
        meshes.push(mesh(p.shoe, SHOE));
        meshes[meshes.length - 1].userData.shoe = true;
      }
      this.pieces.push({ joint: k, parent: j.parent, len, meshes });
    });
    this.meshes = this.pieces.flatMap((p) => p.meshes);
    this.shown = new Float32Array(this.n).fill(-1);
    this.m = new THREE.Matrix4();
    this.a = new THREE.Vector3();
    this.b = new THREE.Vector3();
    this.x = new THREE.Vector3();
    this.y = new THREE.Vector3();
    this.z = new THREE.Vector3();
    this.fwd = new THREE.Vector3();
    this.footY = new THREE.Vector3();
    this.footZ = new THREE.Vector3();
    this.footM = new THREE.Matrix4();
    this.q = new THREE.Quaternion();
    this.colour = new THREE.Color();
    this.visible = true;
  }

  setVisible(on) {
    this.visible = on;
    for (const m of this.meshes) m.visible = on;
  }

  apply(f) {
    const L = this.L;
    const CF = L.character_floats;
    for (let i = 0; i < this.n; i++) {
      const o = L.characters_at + i * CF;
      const at = (j, v) => v.set(f[o + HEAD_FLOATS + 3 * j], f[o + HEAD_FLOATS + 3 * j + 1], f[o + HEAD_FLOATS + 3 * j + 2]);
      // The body's forward side (+z of the figure) in the scene.
      this.q.set(f[o + 3], f[o + 4], f[o + 5], f[o + 6]);
      this.fwd.set(0, 0, 1).applyQuaternion(this.q);
      for (const p of this.pieces) {
        at(p.parent, this.a);
        at(p.joint, this.b);
        this.y.subVectors(this.b, this.a);
        const len = this.y.length();
        if (len > 1e-9) this.y.divideScalar(len); else this.y.set(0, 1, 0);
        // Forward across the bone: the body's forward less its part along the bone.
        this.z.copy(this.fwd).addScaledVector(this.y, -this.fwd.dot(this.y));
        if (this.z.lengthSq() < 1e-8) this.z.set(0, 0, 1).addScaledVector(this.y, -this.y.z);
        this.z.normalize();
        this.x.crossVectors(this.y, this.z);
        this.m.makeBasis(this.x, this.y, this.z).setPosition(this.a);
        for (const m of p.meshes) m.setMatrixAt(i, m.userData.shoe ? this.footAt(this.b) : this.m);
      }
      const state = f[o + STATE] | 0;
      const shown = state + (f[o + PUSH] > PUSH_FLASH_N ? 0.5 : 0);
      if (shown !== this.shown[i]) {
        this.shown[i] = shown;
        for (const m of this.meshes) {
          this.colour.copy(m.userData.fixed ?? this.colours[state] ?? this.colours[0]);
          if (shown !== state) this.colour.lerp(this.flashColour, 0.6);
          m.setColorAt(i, this.colour);
        }
        this.coloursChanged = true;
      }
    }
    for (const m of this.meshes) {
      m.instanceMatrix.needsUpdate = true;
      if (this.coloursChanged && m.instanceColor) m.instanceColor.needsUpdate = true;
    }
    this.coloursChanged = false;
  }

  // The shoe's frame at the ankle `ankle`, from the shin's (x across, y along the shin away from
  // the knee, z forward): the foot turned about the ankle's axis (x) by the least angle, within
  // the ankle's range (FLEX_UP toward the shin's front, POINT toward its line), that keeps its
  // toes from pointing below level; where none does, as far as the range lets. Standing the toes
  // point level or up: unturned. A person lying face down has the tops of the feet on the floor,
  // the toes along the shins: a shoe that kept pointing the body's forward way went into it.
  footAt(ankle) {
    const { x, y, z } = this;
    let t = 0;
    if (z.y < 0) {
      // The toes' height along z cos u + y sin u is zero at t1 and t1 +- pi.
      const t1 = Math.atan(-z.y / y.y);
      t = Infinity;
      for (let k = -1; k <= 1; k++) {
        const u = t1 + k * Math.PI;
        if (u >= -FLEX_UP && u <= POINT && Math.abs(u) < Math.abs(t)) t = u;
      }
      if (t === Infinity) {
        const toes = (u) => z.y * Math.cos(u) + y.y * Math.sin(u);
        t = toes(POINT) >= toes(-FLEX_UP) ? POINT : -FLEX_UP;
      }
    }
    const [c, s] = [Math.cos(t), Math.sin(t)];
    this.footY.copy(y).multiplyScalar(c).addScaledVector(z, -s);
    this.footZ.copy(z).multiplyScalar(c).addScaledVector(y, s);
    return this.footM.makeBasis(x, this.footY, this.footZ).setPosition(ankle);
  }

  // For tests: character i's joints as its pieces draw them (scene frame), each joint from the
  // pieces that start and end there; and the lowest and highest point of all its pieces but the
  // shoes, and of its shoes (the drawn figure has no foot joint: a shoe points the body's forward
  // way, turned at the ankle no further than level).
  drawn(i) {
    const ends = this.joints.map(() => []);
    const m = new THREE.Matrix4();
    const v = new THREE.Vector3();
    let low = Infinity;
    let high = -Infinity;
    let shoeLow = Infinity;
    for (const p of this.pieces) {
      p.meshes[0].getMatrixAt(i, m);
      ends[p.parent].push(new THREE.Vector3().setFromMatrixPosition(m).toArray());
      ends[p.joint].push(new THREE.Vector3(0, p.len, 0).applyMatrix4(m).toArray());
      for (const mesh of p.meshes) {
        mesh.getMatrixAt(i, m);
        const pos = mesh.geometry.attributes.position;
        for (let k = 0; k < pos.count; k++) {
          v.fromBufferAttribute(pos, k).applyMatrix4(m);
          if (mesh.userData.shoe) { shoeLow = Math.min(shoeLow, v.y); continue; }
          low = Math.min(low, v.y);
          high = Math.max(high, v.y);
        }
      }
    }
    return { joints: ends, low, high, shoeLow, visible: this.visible };
  }
}
