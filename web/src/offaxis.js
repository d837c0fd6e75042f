// The off-axis (generalised perspective) camera of the rig's screen: from an eye point through
// the screen's rectangle, so a point is drawn where the ray from the eye to it crosses the
// screen (life-size, and where the grips are). The frustum's near rectangle is the screen's, seen
// from the eye and scaled to the near plane; the camera looks along the screen's normal. It is
// the projection Kooima's "Generalized Perspective Projection" describes.
import * as THREE from 'three';

export class OffAxisCamera extends THREE.PerspectiveCamera {
  constructor(near = 0.02, far = 200) {
    super(60, 1, near, far);
    this.right = new THREE.Vector3(1, 0, 0);
    this.up = new THREE.Vector3(0, 1, 0);
    this.normal = new THREE.Vector3(0, 0, 1);
    this.m = new THREE.Matrix4();
    this.va = new THREE.Vector3();
    this.vb = new THREE.Vector3();
    this.vc = new THREE.Vector3();
  }

  // Places the camera at `eye` looking through the rectangle whose lower-left, lower-right and
  // upper-left corners are `ll`, `lr`, `ul` (Vector3, the scene frame).
  frame(eye, ll, lr, ul) {
    const { right, up, normal, va, vb, vc } = this;
    right.subVectors(lr, ll).normalize();
    up.subVectors(ul, ll).normalize();
    normal.crossVectors(right, up).normalize();
    // Square `up` onto `right` (the rig file's check allows a corner a little off 90 degrees).
    up.crossVectors(normal, right).normalize();
    va.subVectors(ll, eye);
    vb.subVectors(lr, eye);
    vc.subVectors(ul, eye);
    const d = -va.dot(normal); // the eye's distance from the screen's plane
    const k = this.near / Math.max(d, 1e-6);
    const l = right.dot(va) * k;
    const r = right.dot(vb) * k;
    const b = up.dot(va) * k;
    const t = up.dot(vc) * k;
    this.projectionMatrix.makePerspective(l, r, t, b, this.near, this.far);
    this.projectionMatrixInverse.copy(this.projectionMatrix).invert();
    this.position.copy(eye);
    this.m.makeBasis(right, up, normal);
    this.quaternion.setFromRotationMatrix(this.m);
    this.updateMatrixWorld(true);
  }

  // The frustum is the screen's: a resize changes nothing (the pixels stretch to the screen).
  updateProjectionMatrix() {}
}
