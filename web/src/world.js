// The scene graph of one scene description: its moving shapes (with a flash on the part hit), its
// scenery, the behaviour labels, the contact proxies the rig renders against, and the contacts
// with their force arrows. Built once; `apply` only moves transforms and sets visibilities.
import * as THREE from 'three';
import { litMaterial } from './materials.js';
import { CSS2DObject } from 'three/addons/renderers/CSS2DRenderer.js';
import { shapeMesh } from './shapes.js';

const FLASH_N = 1.0; // a contact force above this flashes the part
const FLASH_DECAY_PER_S = 4.0;
const MAX_PROXIES = 16;

export class World {
  constructor(desc, root) {
    this.desc = desc;
    this.L = desc.layout;
    this.group = new THREE.Group();
    root.add(this.group);
    this.meshes = desc.shapes.map((s) => {
      const mat = litMaterial({ color: s.colour, roughness: 0.6, metalness: 0.0 });
      const m = shapeMesh(s, mat);
      m.name = s.name;
      m.userData.flash = 0;
      this.group.add(m);
      return m;
    });
    for (const s of desc.statics) {
      const m = shapeMesh(s, litMaterial({ color: s.colour }));
      m.position.fromArray(s.pos_m);
      m.quaternion.fromArray(s.quat);
      this.group.add(m);
    }
    this.labels = desc.labels.map((l) => {
      const div = document.createElement('div');
      div.className = 'label';
      div.dataset.label = l.name;
      const obj = new CSS2DObject(div);
      const anchor = this.meshes[l.shape];
      obj.position.set(0, 0.22, 0);
      if (anchor) anchor.add(obj);
      return { def: l, div, state: -1 };
    });
    // Proxies: faint wireframes, one sphere, capsule and plane per slot.
    const wire = new THREE.MeshBasicMaterial({ color: 0xffe08a, wireframe: true, transparent: true, opacity: 0.25 });
    this.proxyGroup = new THREE.Group();
    this.group.add(this.proxyGroup);
    this.proxies = [];
    const unitSphere = new THREE.SphereGeometry(1, 12, 8);
    const unitCyl = new THREE.CylinderGeometry(1, 1, 1, 12, 1, true);
    const plane = new THREE.PlaneGeometry(1.2, 1.2, 4, 4);
    for (let i = 0; i < MAX_PROXIES; i++) {
      const sphere = new THREE.Mesh(unitSphere, wire);
      const capA = new THREE.Mesh(unitSphere, wire);
      const capB = new THREE.Mesh(unitSphere, wire);
      const cyl = new THREE.Mesh(unitCyl, wire);
      const pl = new THREE.Mesh(plane, wire);
      for (const m of [sphere, capA, capB, cyl, pl]) { m.visible = false; this.proxyGroup.add(m); }
      this.proxies.push({ sphere, capA, capB, cyl, pl });
    }
    // Contacts: a point and an arrow each.
    this.contacts = [];
    const dot = new THREE.SphereGeometry(0.012, 8, 6);
    const dotMat = new THREE.MeshBasicMaterial({ color: 0xffffff });
    for (let i = 0; i < desc.layout.max_contacts; i++) {
      const p = new THREE.Mesh(dot, dotMat);
      const a = new THREE.ArrowHelper(new THREE.Vector3(0, 1, 0), new THREE.Vector3(), 0.1, 0xffd040, 0.04, 0.025);
      p.visible = false; a.visible = false;
      this.group.add(p); this.group.add(a);
      this.contacts.push({ p, a });
    }
    // Shapes that are solids of a body drawn as a person: not drawn while people are.
    for (const h of desc.humanoids || []) for (const seg of h.segments) this.meshes[seg.shape].userData.person = true;
    this.people = false;
    this.v1 = new THREE.Vector3();
    this.v2 = new THREE.Vector3();
    this.up = new THREE.Vector3(0, 1, 0);
    this.white = new THREE.Color(0xfff2b0);
  }

  // Hides the shapes within `r` of `p` (the user's own head, seen from their eye), or none, and
  // those of a hidden actor.
  hideNear(p, r) {
    for (const m of this.meshes) {
      m.visible = !m.userData.actorHidden && !(this.people && m.userData.person) && (!p || m.position.distanceTo(p) > r);
    }
  }

  // Hides (or shows) every shape of an actor (`avatar`: at the rig, the user's own hands are there).
  hideActor(actor, hidden) {
    for (const m of this.meshes) if (m.name.startsWith(`${actor}/`)) m.userData.actorHidden = hidden;
  }

  apply(f, dt) {
    const L = this.L;
    for (let k = 0; k < this.meshes.length; k++) {
      const m = this.meshes[k];
      const o = L.shapes_at + k * L.shape_floats;
      m.position.set(f[o], f[o + 1], f[o + 2]);
      m.quaternion.set(f[o + 3], f[o + 4], f[o + 5], f[o + 6]);
      const force = f[L.shape_force_at + k];
      let flash = Math.max(0, m.userData.flash - dt * FLASH_DECAY_PER_S);
      if (force > FLASH_N) flash = 1;
      if (flash !== m.userData.flash && m.material && m.material.emissive) {
        m.material.emissive.copy(this.white).multiplyScalar(flash * 0.8);
      }
      m.userData.flash = flash;
    }
    for (let i = 0; i < this.labels.length; i++) {
      const l = this.labels[i];
      const s = f[L.labels_at + i] | 0;
      if (s !== l.state) {
        l.state = s;
        l.div.textContent = `${l.def.name}: ${l.def.states[s] ?? '?'}`;
        l.div.dataset.state = l.def.states[s] ?? '';
        l.div.classList.toggle('active', s !== 0);
      }
    }
    const nProxies = f[L.globals_at + 2] | 0;
    for (let i = 0; i < MAX_PROXIES; i++) {
      const P = this.proxies[i];
      const o = L.proxies_at + i * L.proxy_floats;
      const kind = i < nProxies ? f[o] | 0 : 0;
      P.sphere.visible = kind === 2;
      P.capA.visible = P.capB.visible = P.cyl.visible = kind === 3;
      P.pl.visible = kind === 1;
      if (kind === 2) {
        P.sphere.position.set(f[o + 1], f[o + 2], f[o + 3]);
        P.sphere.scale.setScalar(f[o + 7]);
      } else if (kind === 3) {
        const r = f[o + 7];
        this.v1.set(f[o + 1], f[o + 2], f[o + 3]);
        this.v2.set(f[o + 4], f[o + 5], f[o + 6]);
        P.capA.position.copy(this.v1); P.capA.scale.setScalar(r);
        P.capB.position.copy(this.v2); P.capB.scale.setScalar(r);
        P.cyl.position.copy(this.v1).add(this.v2).multiplyScalar(0.5);
        this.v2.sub(this.v1);
        const len = this.v2.length();
        P.cyl.scale.set(r, Math.max(len, 1e-6), r);
        if (len > 1e-9) P.cyl.quaternion.setFromUnitVectors(this.up, this.v2.multiplyScalar(1 / len));
      } else if (kind === 1) {
        P.pl.position.set(f[o + 1], f[o + 2], f[o + 3]);
        this.v2.set(f[o + 4], f[o + 5], f[o + 6]);
        P.pl.quaternion.setFromUnitVectors(this.v1.set(0, 0, 1), this.v2.normalize());
      }
    }
    const nContacts = f[L.globals_at + 1] | 0;
    for (let i = 0; i < this.contacts.length; i++) {
      const C = this.contacts[i];
      const on = i < nContacts;
      C.p.visible = on; C.a.visible = on;
      if (!on) continue;
      const o = L.contacts_at + i * L.contact_floats;
      C.p.position.set(f[o], f[o + 1], f[o + 2]);
      C.a.position.copy(C.p.position);
      this.v2.set(f[o + 3], f[o + 4], f[o + 5]);
      const n = this.v2.length();
      if (n > 1e-6) {
        C.a.setDirection(this.v2.multiplyScalar(1 / n));
        C.a.setLength(arrowLength(n), 0.04, 0.025);
      } else {
        C.a.visible = false;
      }
    }
  }
}

// Force arrows grow with the logarithm of the force: 1 N is 5 cm, 100 N is 0.33 m.
export function arrowLength(n) {
  return Math.min(0.6, 0.05 * Math.log2(1 + n) + 0.0);
}
