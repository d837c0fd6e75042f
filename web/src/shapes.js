// Geometry for the world's collision shapes: spheres, capsules (axis along y), boxes and planes,
// as three.js meshes built once from the scene description.
import * as THREE from 'three';
import { litMaterial } from './materials.js';

export function shapeMesh(s, material) {
  let g;
  switch (s.kind) {
    case 'sphere': g = new THREE.SphereGeometry(s.radius_m, 24, 16); break;
    case 'capsule': g = new THREE.CapsuleGeometry(s.radius_m, 2 * s.half_length_m, 8, 20); break;
    case 'box': g = new THREE.BoxGeometry(2 * s.half_extents_m[0], 2 * s.half_extents_m[1], 2 * s.half_extents_m[2]); break;
    case 'plane': return floorMesh();
    default: return new THREE.Group();
  }
  const m = new THREE.Mesh(g, material);
  m.castShadow = false;
  return m;
}

// A half-space bounded by y = 0 in its frame: a large floor with a grid on it.
export function floorMesh() {
  const group = new THREE.Group();
  const floor = new THREE.Mesh(
    new THREE.PlaneGeometry(60, 60),
    litMaterial({ color: 0x5a5c58, roughness: 0.95 }),
  );
  floor.rotation.x = -Math.PI / 2;
  floor.position.y = -0.001;
  group.add(floor);
  const grid = new THREE.GridHelper(60, 60, 0x777a74, 0x6a6c68);
  group.add(grid);
  return group;
}
