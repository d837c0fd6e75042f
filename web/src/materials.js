// The lit surfaces' material, chosen once for the page: physically based (three.js's
// MeshStandardMaterial, with a specular highlight) on a GPU; Lambert (the same diffuse light, no
// highlight) on a software renderer, where the standard material's per-pixel work is most of a
// picture's cost (docs/view.md, the picture's age). The rig's own parts (web/src/rig.js) keep theirs.
import * as THREE from 'three';

let lambert = false;

// Chooses for every material made after this call (main.js, before it builds any scene).
export function useLambert(on) {
  lambert = !!on;
}

export const lambertShading = () => lambert;

// A lit material: `params` as for MeshStandardMaterial (`roughness` and `metalness` count only there).
export function litMaterial(params = {}) {
  if (!lambert) return new THREE.MeshStandardMaterial(params);
  const { roughness, metalness, ...rest } = params;
  return new THREE.MeshLambertMaterial(rest);
}
