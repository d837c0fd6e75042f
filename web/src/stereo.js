// The user's-eye view on the rig's screen: one off-axis camera per eye through the screen's
// rectangle, drawn mono, side by side or top and bottom (the frame packings 3D projectors and
// monitors take: each half is stretched to the whole screen, left eye left or on top), or as a
// red-cyan anaglyph (red the left eye) for a check without a 3D display. `project` says where each
// eye's picture puts a point on the page, for tests.
import * as THREE from 'three';
import { OffAxisCamera } from './offaxis.js';

export const FORMATS = ['mono', 'side-by-side', 'top-bottom', 'anaglyph'];

const ANAGLYPH_FRAG = `
  uniform sampler2D left; uniform sampler2D right; varying vec2 vUv;
  void main() {
    vec4 l = texture2D(left, vUv); vec4 r = texture2D(right, vUv);
    gl_FragColor = vec4(l.r, r.g, r.b, 1.0);
    #include <colorspace_fragment>
  }`;
const QUAD_VERT = 'varying vec2 vUv; void main() { vUv = uv; gl_Position = vec4(position.xy, 0.0, 1.0); }';

export class ScreenView {
  constructor() {
    this.mono = new OffAxisCamera();
    this.eyes = [new OffAxisCamera(), new OffAxisCamera()];
    this.format = 'mono';
    this.display = null;
    this.eyeM = new THREE.Vector3();
    this.v = [new THREE.Vector3(), new THREE.Vector3(), new THREE.Vector3(), new THREE.Vector3()];
    this.targets = null;
    this.quad = null;
    this.size = new THREE.Vector2();
  }

  // The rig's screen (`rig` message's `display`, scene frame) and the eye point; `format` one of
  // FORMATS (null: the screen's own).
  set(display, eyeM, format) {
    this.display = display;
    this.eyeM.fromArray(eyeM);
    this.format = FORMATS.includes(format) ? format : FORMATS.includes(display.stereo) ? display.stereo : 'mono';
    const [ll, lr, ul, side] = this.v;
    ll.fromArray(display.lower_left_m);
    lr.fromArray(display.lower_right_m);
    ul.fromArray(display.upper_left_m);
    this.mono.frame(this.eyeM, ll, lr, ul);
    side.subVectors(lr, ll).normalize().multiplyScalar(display.eye_separation_m / 2);
    const e = new THREE.Vector3();
    this.eyes[0].frame(e.copy(this.eyeM).sub(side), ll, lr, ul);
    this.eyes[1].frame(e.copy(this.eyeM).add(side), ll, lr, ul);
  }

  get stereo() {
    return this.format !== 'mono';
  }

  // Each eye's camera and the page rectangle (CSS px, y down) its picture fills.
  views(w, h) {
    switch (this.format) {
      case 'side-by-side': return [{ cam: this.eyes[0], x: 0, y: 0, w: w / 2, h }, { cam: this.eyes[1], x: w / 2, y: 0, w: w / 2, h }];
      case 'top-bottom': return [{ cam: this.eyes[0], x: 0, y: 0, w, h: h / 2 }, { cam: this.eyes[1], x: 0, y: h / 2, w, h: h / 2 }];
      case 'anaglyph': return [{ cam: this.eyes[0], x: 0, y: 0, w, h }, { cam: this.eyes[1], x: 0, y: 0, w, h }];
      default: return [{ cam: this.mono, x: 0, y: 0, w, h }];
    }
  }

  render(renderer, scene) {
    renderer.getSize(this.size);
    const { x: w, y: h } = this.size;
    if (this.format === 'anaglyph') return this.renderAnaglyph(renderer, scene);
    const views = this.views(w, h);
    if (views.length === 1) {
      renderer.render(scene, views[0].cam);
      return;
    }
    renderer.setScissorTest(true);
    for (const v of views) {
      // three's viewport counts from the bottom left.
      renderer.setViewport(v.x, h - v.y - v.h, v.w, v.h);
      renderer.setScissor(v.x, h - v.y - v.h, v.w, v.h);
      renderer.render(scene, v.cam);
    }
    renderer.setScissorTest(false);
    renderer.setViewport(0, 0, w, h);
  }

  renderAnaglyph(renderer, scene) {
    const px = renderer.getDrawingBufferSize(new THREE.Vector2());
    if (!this.targets || this.targets[0].width !== px.x || this.targets[0].height !== px.y) {
      if (this.targets) for (const t of this.targets) t.dispose();
      this.targets = [0, 1].map(() => new THREE.WebGLRenderTarget(px.x, px.y, { samples: 4 }));
      this.quad = new THREE.Mesh(new THREE.PlaneGeometry(2, 2), new THREE.ShaderMaterial({
        uniforms: { left: { value: this.targets[0].texture }, right: { value: this.targets[1].texture } },
        vertexShader: QUAD_VERT,
        fragmentShader: ANAGLYPH_FRAG,
        depthTest: false,
        depthWrite: false,
      }));
      this.quad.frustumCulled = false;
      this.quadScene = new THREE.Scene();
      this.quadScene.add(this.quad);
    }
    for (let k = 0; k < 2; k++) {
      renderer.setRenderTarget(this.targets[k]);
      renderer.render(scene, this.eyes[k]);
    }
    renderer.setRenderTarget(null);
    renderer.render(this.quadScene, this.mono);
  }

  // Where each eye's picture puts scene point `p` on the page (CSS px from the canvas's top left).
  project(p, w, h) {
    const q = new THREE.Vector3();
    return this.views(w, h).map((v, i) => {
      q.set(p[0], p[1], p[2]).project(v.cam);
      return { eye: this.views(w, h).length === 1 ? 'mono' : ['left', 'right'][i], x: v.x + ((q.x + 1) / 2) * v.w, y: v.y + ((1 - q.y) / 2) * v.h };
    });
  }
}
