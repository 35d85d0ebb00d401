export {
  WebGLRenderer, Scene, PerspectiveCamera, BufferGeometry, BufferAttribute, Mesh, MeshStandardMaterial,
  HemisphereLight, DirectionalLight, Color, Box3, Vector3, DoubleSide, FrontSide, SRGBColorSpace, GridHelper, REVISION
} from 'three';
export { OrbitControls } from 'three/examples/jsm/controls/OrbitControls.js';
