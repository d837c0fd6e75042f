// Bodies drawn as people: the boxing scene's virtual human and avatar as shaded humanoid meshes
// built here from the scene description (no downloaded assets). Each piece rides on the pose of
// the simulated solid it stands for (its collision shape's), and is built between the joints the
// description puts on that solid, so the pieces meet where the simulation's joints are: the
// person moves joint for joint with the simulated body. Legs (the model is an upper body) stand
// on the floor under the hips by two-bone inverse kinematics. The eyes look where the scene says
// the body looks (`gaze`, when the scene sends it), else straight ahead of the head.
import * as THREE from 'three';
import { litMaterial } from './materials.js';

const SEGS = 18;
const UP = new THREE.Vector3(0, 1, 0);
const v = (a) => new THREE.Vector3().fromArray(a);

// A tapered limb from a to b (radius ra at a, rb at b) with a ball at a, as one geometry.
function limbGeometry(a, b, ra, rb) {
  const d = new THREE.Vector3().subVectors(b, a);
  const len = d.length();
  const g = new THREE.CylinderGeometry(rb, ra, len, SEGS, 1, true);
  g.translate(0, len / 2, 0);
  const q = new THREE.Quaternion().setFromUnitVectors(UP, d.clone().normalize());
  g.applyQuaternion(q);
  g.translate(a.x, a.y, a.z);
  return g;
}

function ball(at, r, sx = 1, sy = 1, sz = 1) {
  const g = new THREE.SphereGeometry(r, SEGS, 12);
  g.scale(sx, sy, sz);
  g.translate(at.x, at.y, at.z);
  return g;
}

export class Humanoids {
  // `desc`: the scene description; `meshes`: the World's shape meshes (their poses are followed).
  constructor(desc, root, meshes) {
    this.meshes = meshes;
    this.people = (desc.humanoids || []).map((h) => this.build(h, desc, root));
    this.gaze = (desc.gaze || []).map((g, i) => ({ ...g, index: i }));
    this.gazeAt = desc.layout.gaze_at;
    this.gazeFloats = desc.layout.gaze_floats || 9;
    this.shown = true;
    this.tmp = [new THREE.Vector3(), new THREE.Vector3(), new THREE.Vector3(), new THREE.Vector3()];
    this.q = new THREE.Quaternion();
  }

  build(h, desc, root) {
    const cloth = new THREE.Color(h.colour);
    const skin = new THREE.Color(h.skin);
    const mat = (c, rough = 0.65) => litMaterial({ color: c, roughness: rough });
    const person = { name: h.name, pieces: [], ends: [], legs: null, head: null, forward: v(h.forward), feet: null };
    // Joint points per shape: name -> point in that shape's frame.
    const at = new Map();
    const put = (shape, name, p) => { if (!at.has(shape)) at.set(shape, new Map()); at.get(shape).set(name, v(p)); };
    for (const j of h.joints) { put(j.parent_shape, j.name, j.at_parent_m); put(j.child_shape, j.name, j.at_child_m); }
    const own = (shape) => [...(at.get(shape) || new Map()).entries()];
    for (const s of h.segments) {
      const group = new THREE.Group();
      root.add(group);
      const pts = at.get(s.shape) || new Map();
      const shapeDesc = desc.shapes[s.shape];
      const centre = new THREE.Vector3();
      const material = mat(s.part === 'forearm' || s.part === 'head' ? skin : s.part === 'hand' ? new THREE.Color(shapeDesc.colour) : cloth);
      const add = (g, m = material) => { const mesh = new THREE.Mesh(g, m); group.add(mesh); return mesh; };
      const byName = (re) => own(s.shape).filter(([n]) => re.test(n)).map(([, p]) => p);
      if (s.part === 'upper_arm' || s.part === 'forearm') {
        // From this solid's own joint to its child's.
        const joints = own(s.shape);
        const prox = joints.find(([n]) => n.startsWith(s.part))[1];
        const dist = joints.find(([n]) => !n.startsWith(s.part));
        const r = shapeDesc.radius_m;
        const b = dist ? dist[1] : prox.clone().add(new THREE.Vector3(0, -0.25, 0));
        add(limbGeometry(prox, b, r * 0.95, r * 0.8));
        add(ball(prox, r * 0.95));
      } else if (s.part === 'chest') {
        const bottom = byName(/^chest/)[0] || centre;
        const neck = byName(/^head/)[0] || bottom.clone().add(new THREE.Vector3(0, 0.34, 0));
        const shoulders = byName(/^upper_arm/);
        const halfW = shoulders.length === 2 ? shoulders[0].distanceTo(shoulders[1]) / 2 : 0.17;
        const mid = bottom.clone().lerp(neck, 0.5);
        add(ball(mid, 1, halfW * 0.92, neck.distanceTo(bottom) * 0.55, 0.115));
        for (const p of shoulders) add(ball(p, 0.06));
      } else if (s.part === 'waist') {
        add(ball(centre, 1, 0.15, 0.11, 0.11), mat(cloth.clone().multiplyScalar(0.55)));
      } else if (s.part === 'head') {
        const f = person.forward;
        const neck = byName(/^head/)[0] || new THREE.Vector3(0, -0.16, 0);
        add(limbGeometry(neck.clone().add(new THREE.Vector3(0, -0.05, 0)), centre.clone().add(new THREE.Vector3(0, -0.06, 0)), 0.05, 0.045));
        add(ball(centre, 1, 0.08, 0.108, 0.095));
        // Hair: a cap over the top and back, clear of the face (tilted away from the forward side).
        const hair = new THREE.SphereGeometry(1, SEGS, 8, 0, Math.PI * 2, 0, Math.PI * 0.45);
        hair.scale(0.087, 0.116, 0.1);
        hair.rotateX(0.45 * Math.sign(-f.z || 1));
        hair.translate(centre.x, centre.y + 0.008, centre.z - f.z * 0.008);
        add(hair, mat(0x2b211c, 0.9));
        // A nose and two eyes on the face (the body's forward side).
        const nose = new THREE.ConeGeometry(0.012, 0.03, 8);
        nose.rotateX(-Math.PI / 2 * Math.sign(-f.z || 1));
        nose.translate(centre.x + f.x * 0.098, centre.y - 0.012, centre.z + f.z * 0.098);
        add(nose);
        const eyes = [-1, 1].map((side) => {
          const eye = new THREE.Group();
          eye.position.set(centre.x + side * 0.032, centre.y + 0.018, centre.z + f.z * 0.078);
          const white = new THREE.Mesh(new THREE.SphereGeometry(0.014, 12, 8), mat(0xf4f1ea, 0.3));
          const pupil = new THREE.Mesh(new THREE.SphereGeometry(0.0075, 10, 6), mat(0x1b1410, 0.2));
          pupil.position.copy(f).multiplyScalar(0.0105);
          eye.add(white, pupil);
          group.add(eye);
          return eye;
        });
        person.head = { group, shape: s.shape, eyes, centre };
      } else if (s.part === 'hand') {
        add(ball(centre, shapeDesc.radius_m || 0.055, 1.0, 0.95, 1.15));
      }
      group.userData.shape = s.shape;
      person.pieces.push({ group, shape: s.shape, material, part: s.part, side: s.side });
      for (const [name, p] of pts) person.ends.push({ name, group, at: p, parent: [...h.joints].find((j) => j.name === name).parent_shape === s.shape });
      if (s.part === 'waist') person.waist = group;
    }
    // Legs: thighs and shins moved every frame between the hips and feet on the floor.
    const trousers = mat(cloth.clone().multiplyScalar(0.35), 0.8);
    const shoe = mat(0x202020, 0.6);
    const unitLimb = new THREE.CylinderGeometry(0.06, 0.07, 1, SEGS, 1, false).translate(0, 0.5, 0);
    person.legs = [-1, 1].map((side) => {
      const thigh = new THREE.Mesh(unitLimb, trousers);
      const shin = new THREE.Mesh(unitLimb, trousers);
      const foot = new THREE.Mesh(new THREE.BoxGeometry(0.1, 0.07, 0.26), shoe);
      const knee = new THREE.Mesh(new THREE.SphereGeometry(0.065, 12, 8), trousers);
      for (const m of [thigh, shin, foot, knee]) root.add(m);
      return { side, thigh, shin, foot, knee, planted: null };
    });
    return person;
  }

  setShown(shown) {
    this.shown = shown;
    for (const p of this.people) {
      for (const piece of p.pieces) piece.group.visible = shown;
      for (const l of p.legs) for (const m of [l.thigh, l.shin, l.foot, l.knee]) m.visible = shown;
    }
  }

  // Hides the pieces within `r` of `p` (the avatar's own head, seen from the user's eye), or none.
  hideNear(p, r) {
    for (const person of this.people) {
      for (const piece of person.pieces) piece.group.visible = this.shown && !person.hidden && (!p || piece.group.position.distanceTo(p) > r);
    }
  }

  // Hides (or shows) one actor's person (`avatar`).
  hideActor(name, hidden) {
    for (const p of this.people) if (p.name === name) p.hidden = hidden;
  }

  apply(f) {
    for (const p of this.people) {
      const show = this.shown && !p.hidden;
      for (const piece of p.pieces) {
        const m = this.meshes[piece.shape];
        piece.group.position.copy(m.position);
        piece.group.quaternion.copy(m.quaternion);
        piece.group.visible = show;
        const flash = m.userData.flash || 0;
        if (piece.flash !== flash) {
          piece.flash = flash;
          piece.material.emissive.setRGB(1, 0.95, 0.7).multiplyScalar(flash * 0.8);
        }
      }
      this.legs(p, show);
      this.eyes(p, f);
    }
  }

  // Two-bone legs from the hips (on the waist) to feet planted under them, knees forward.
  legs(p, show) {
    const [hip, fwd, d, knee] = this.tmp;
    const THIGH = 0.44;
    const SHIN = 0.44;
    p.waist.updateMatrixWorld();
    for (const l of p.legs) {
      for (const m of [l.thigh, l.shin, l.foot, l.knee]) m.visible = show;
      hip.set(0.09 * l.side, -0.07, 0).applyMatrix4(p.waist.matrixWorld);
      fwd.copy(p.forward).applyQuaternion(p.waist.quaternion).setY(0).normalize();
      if (!l.planted) l.planted = new THREE.Vector3(hip.x, 0.035, hip.z).addScaledVector(fwd, l.side * 0.08);
      const foot = l.planted;
      d.subVectors(foot, hip);
      const reach = Math.min(d.length(), THIGH + SHIN - 1e-4);
      // The knee: off the hip-foot line, toward the front, by the triangle's height.
      const a = (THIGH * THIGH - SHIN * SHIN + reach * reach) / (2 * reach);
      const hgt = Math.sqrt(Math.max(THIGH * THIGH - a * a, 0));
      const dir = d.clone().normalize();
      const bend = fwd.clone().addScaledVector(dir, -fwd.dot(dir)).normalize();
      knee.copy(hip).addScaledVector(dir, a).addScaledVector(bend, hgt);
      place(l.thigh, hip, knee);
      place(l.shin, knee, foot);
      l.knee.position.copy(knee);
      l.foot.position.copy(foot).addScaledVector(fwd, 0.06);
      l.foot.quaternion.setFromUnitVectors(new THREE.Vector3(0, 0, 1), fwd);
    }
  }

  // The eyes turn toward the point looked at that the frame's gaze gives for this body's head
  // (eyes xyz, direction xyz, point xyz; at most 35 degrees from straight ahead), else look
  // straight ahead.
  eyes(p, f) {
    if (!p.head) return;
    const g = this.gaze.find((x) => x.head_shape === p.head.shape);
    const [target, local] = this.tmp;
    for (const eye of p.head.eyes) {
      if (!g || this.gazeAt === undefined) { eye.quaternion.identity(); continue; }
      const o = this.gazeAt + this.gazeFloats * g.index;
      target.set(f[o + 6], f[o + 7], f[o + 8]);
      p.head.group.updateMatrixWorld();
      local.copy(target);
      p.head.group.worldToLocal(local).sub(eye.position).normalize();
      const ahead = p.forward;
      const angle = Math.acos(Math.min(1, Math.max(-1, local.dot(ahead))));
      // Beyond 35 degrees, turned exactly 35 degrees toward it (a straight-line blend of the two
      // directions turns less: 33.9 degrees for a point 80 degrees off).
      if (angle > 0.61) {
        local.addScaledVector(ahead, -Math.cos(angle));
        const across = local.length();
        if (across < 1e-6) local.copy(ahead); // straight behind: no side to turn to
        else local.multiplyScalar(Math.sin(0.61) / across).addScaledVector(ahead, Math.cos(0.61));
      }
      eye.quaternion.setFromUnitVectors(ahead, local);
    }
  }

  // For tests: every joint as drawn, from each of the two pieces that meet there (world frame),
  // and where each eye looks.
  joints(name) {
    const p = this.people.find((x) => x.name === name);
    if (!p) return null;
    const out = {};
    for (const e of p.ends) {
      e.group.updateMatrixWorld();
      const w = e.group.localToWorld(e.at.clone()).toArray();
      out[e.name] = out[e.name] || {};
      out[e.name][e.parent ? 'parent' : 'child'] = w;
    }
    return out;
  }

  eyeDirections(name) {
    const p = this.people.find((x) => x.name === name);
    if (!p || !p.head) return null;
    return p.head.eyes.map((eye) => {
      eye.updateMatrixWorld();
      const at = new THREE.Vector3().setFromMatrixPosition(eye.matrixWorld);
      const dir = p.forward.clone().transformDirection(eye.matrixWorld);
      return { at: at.toArray(), dir: dir.toArray() };
    });
  }
}

function place(mesh, a, b) {
  const d = new THREE.Vector3().subVectors(b, a);
  mesh.position.copy(a);
  mesh.quaternion.setFromUnitVectors(UP, d.clone().normalize());
  mesh.scale.set(1, d.length(), 1);
}
