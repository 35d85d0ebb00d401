// What the viewer (viewer.js) and the service's shop page (tryon.serve page.js) share:
// the colour map and the meshes they draw with three.js.
import * as THREE from './three-bundle.min.js';

// Turbo colour map (Mikhailov 2019), polynomial approximation, t in [0, 1].
export function turbo(t) {
  t = Math.min(1, Math.max(0, t));
  const r = 0.13572138 + t * (4.61539260 + t * (-42.66032258 + t * (132.13108234 + t * (-152.94239396 + t * 59.28637943))));
  const g = 0.09140261 + t * (2.19418839 + t * (4.84296658 + t * (-14.18503333 + t * (4.27729857 + t * 2.82956604))));
  const b = 0.10667330 + t * (12.64194608 + t * (-60.58204836 + t * (110.36276771 + t * (-89.90310912 + t * 27.34824973))));
  return [Math.min(1, Math.max(0, r)), Math.min(1, Math.max(0, g)), Math.min(1, Math.max(0, b))];
}

// three.js shades in linear light: sRGB colours (the colour map, the palette) are decoded first
export function toLinear(rgb) {
  return rgb.map((c) => (c <= 0.04045 ? c / 12.92 : Math.pow((c + 0.055) / 1.055, 2.4)));
}

// A mesh from float32 positions and uint32 faces, in an sRGB colour or (vertexColors) with
// a per-vertex colour attribute to fill, seen from both sides.
export function makeMesh(positions, faces, color, vertexColors) {
  const geometry = new THREE.BufferGeometry();
  geometry.setAttribute('position', new THREE.BufferAttribute(positions, 3));
  geometry.setIndex(new THREE.BufferAttribute(faces, 1));
  if (vertexColors) geometry.setAttribute('color', new THREE.BufferAttribute(new Float32Array(positions.length), 3));
  geometry.computeVertexNormals();
  const material = new THREE.MeshStandardMaterial({
    color: new THREE.Color().setRGB(...color, THREE.SRGBColorSpace), roughness: 0.8, metalness: 0.0,
    side: vertexColors ? THREE.DoubleSide : THREE.FrontSide, vertexColors: !!vertexColors,
  });
  return new THREE.Mesh(geometry, material);
}
