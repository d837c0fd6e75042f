// Two cameras: the user's eye (first person, from the rig file's eye point, looking through the
// rig frame at what the scene puts in front of the user; for the rig's screen, full-screen
// capable) and an orbit camera for an observer (drag to turn, wheel to zoom, right-drag to pan).
// When the rig file places its screen, the user's eye is the off-axis view through that screen
// (stereo.js), life-size and co-located with the grips.
import * as THREE from 'three';
import { OrbitControls } from 'three/addons/controls/OrbitControls.js';
import { ScreenView } from './stereo.js';

export class Cameras {
  constructor(canvas) {
    this.eye = new THREE.PerspectiveCamera(70, 1, 0.02, 200);
    this.orbit = new THREE.PerspectiveCamera(50, 1, 0.02, 300);
    this.controls = new OrbitControls(this.orbit, canvas);
    this.controls.enableDamping = true;
    this.active = 'orbit';
    this.focus = new THREE.Vector3(0, 1.2, -1);
    this.screen = new ScreenView();
    this.hasScreen = false;
  }

  // The rig's screen (the `rig` message's `display`, or null: none) seen from `eyeM`, drawn in
  // `format` (null: the screen's own stereo format).
  setDisplay(display, eyeM, format) {
    this.hasScreen = !!display;
    if (display) this.screen.set(display, eyeM, format);
  }

  // Whether the user's eye is drawn through the rig's screen now.
  get onScreen() {
    return this.active === 'eye' && this.hasScreen;
  }

  // Places both cameras for a scene: the eye at `eyeM` looking at the focus; the orbit camera to
  // the side (boxing) or behind and above the user (a crowd).
  // A scene with a person per seat (spar) has an eye per seat: `?seat=N` picks whose.
  place(desc, eyeM) {
    const seat = desc.eyes && desc.eyes.length
      ? desc.eyes[Number(new URLSearchParams(location.search).get('seat')) || 0] ?? desc.eyes[0] : null;
    this.focus.fromArray(seat ? seat.focus_m : desc.focus_m);
    const eye = seat ? seat.eye_m : eyeM ?? [desc.link_offset_m[0], 1.45 + desc.link_offset_m[1], 0.4 + desc.link_offset_m[2]];
    this.eye.position.fromArray(eye);
    this.eye.lookAt(this.focus);
    if (desc.crowd) {
      this.controls.target.set(0, 0.8, -2.2);
      this.orbit.position.set(0.0, 3.8, 3.2);
    } else {
      // From the side, halfway between the user and what they face.
      const mid = new THREE.Vector3().fromArray(eye).lerp(this.focus, 0.5);
      this.controls.target.copy(mid).setY(this.focus.y - 0.15);
      this.orbit.position.set(mid.x + 2.6, this.focus.y + 0.25, mid.z);
    }
    this.controls.update();
  }

  use(name) {
    this.active = name === 'eye' ? 'eye' : 'orbit';
    this.controls.enabled = this.active === 'orbit';
  }

  get camera() {
    if (this.onScreen) return this.screen.mono;
    return this.active === 'eye' ? this.eye : this.orbit;
  }

  render(renderer, scene) {
    if (this.onScreen) this.screen.render(renderer, scene);
    else renderer.render(scene, this.camera);
  }

  resize(w, h) {
    for (const c of [this.eye, this.orbit]) { c.aspect = w / Math.max(h, 1); c.updateProjectionMatrix(); }
  }

  update() {
    if (this.active === 'orbit') this.controls.update();
  }
}

export function toggleFullScreen() {
  if (document.fullscreenElement) document.exitFullscreen();
  else document.documentElement.requestFullscreen?.();
}
