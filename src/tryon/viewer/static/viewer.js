// tryon web viewer: body and garment of a drape or animation, fit-map colouring, orbit
// controls and a frame slider. Reads scene.json (layout) and scene.bin (float32 / uint32
// arrays) written by tryon.viewer.export. URL parameters: mode=strain|pressure|plain,
// frame=N|last. Served with `tryon view --live`, the page also offers pose sliders
// (live.json) and shows the garment a network predicts for each pose (live?ANGLE=DEG...);
// URL parameters named like the sliders (arm_elevation.L=120) set their start.
import * as THREE from './three-bundle.min.js';
import { makeMesh, toLinear, turbo } from './meshes.js';

const statusEl = document.getElementById('status');
const params = new URLSearchParams(location.search);

function view(buffer, spec, Type) {
  return new Type(buffer, spec.offset, spec.count);
}

async function main() {
  const meta = await (await fetch('scene.json')).json();
  const buffer = await (await fetch('scene.bin')).arrayBuffer();
  document.getElementById('title').textContent = meta.title;
  document.getElementById('info').innerHTML = meta.info.map((l) => `<div>${l}</div>`).join('');

  const g = meta.garment, b = meta.body;
  const gPos = view(buffer, g.positions, Float32Array);
  const gFaces = view(buffer, g.faces, Uint32Array);
  const bPos = view(buffer, b.positions, Float32Array);
  const bFaces = view(buffer, b.faces, Uint32Array);
  const strain = view(buffer, g.strain, Float32Array);
  const pressure = g.pressure ? view(buffer, g.pressure, Float32Array) : null;
  const nG = g.vertices * 3, nB = b.vertices * 3;

  const scene = new THREE.Scene();
  scene.background = new THREE.Color(0.96, 0.96, 0.95);
  scene.add(new THREE.HemisphereLight(0xffffff, 0x8a8070, 1.6));
  const sun = new THREE.DirectionalLight(0xffffff, 1.8);
  sun.position.set(1.5, -3, 4);
  scene.add(sun);
  const back = new THREE.DirectionalLight(0xffffff, 0.6);
  back.position.set(-2, 3, 2);
  scene.add(back);

  const body = makeMesh(bPos.slice(0, nB), bFaces, meta.colors.skin, false);
  const garment = makeMesh(gPos.slice(0, nG), gFaces, meta.colors.cloth, true);
  scene.add(body, garment);

  const container = document.getElementById('view');
  const renderer = new THREE.WebGLRenderer({ antialias: true, preserveDrawingBuffer: true });
  renderer.setPixelRatio(window.devicePixelRatio || 1);
  renderer.setSize(container.clientWidth, container.clientHeight);
  renderer.outputColorSpace = THREE.SRGBColorSpace;
  container.appendChild(renderer.domElement);

  const box = new THREE.Box3().setFromBufferAttribute(body.geometry.getAttribute('position'));
  const center = box.getCenter(new THREE.Vector3());
  const size = box.getSize(new THREE.Vector3());
  const camera = new THREE.PerspectiveCamera(30, container.clientWidth / container.clientHeight, 0.01, 100);
  camera.up.set(0, 0, 1);
  const dist = 1.15 * size.z / (2 * Math.tan((camera.fov * Math.PI) / 360));
  camera.position.set(center.x + 0.35 * dist, center.y - dist, center.z + 0.1 * dist);
  const shift = () => camera.setViewOffset(container.clientWidth, container.clientHeight, -0.12 * container.clientWidth, 0,
    container.clientWidth, container.clientHeight);  // the body clear of the panel
  shift();
  const controls = new THREE.OrbitControls(camera, renderer.domElement);
  controls.target.copy(center);
  controls.update();

  const slider = document.getElementById('frame');
  const timeEl = document.getElementById('time');
  const modeEl = document.getElementById('mode');
  if (!pressure) modeEl.querySelector('option[value="pressure"]').disabled = true;
  if (params.get('mode')) modeEl.value = params.get('mode');
  else if (meta.predicted) modeEl.value = 'plain';   // a network's noise would read as strain
  slider.max = String(meta.frames - 1);
  slider.value = params.get('frame') === 'last' ? String(meta.frames - 1) : (params.get('frame') || '0');

  function legend(mode) {
    const el = document.getElementById('legend');
    if (mode === 'plain') { el.style.display = 'none'; return; }
    el.style.display = '';
    const max = mode === 'strain' ? meta.strain_max : meta.pressure_max;
    const stops = [];
    for (let i = 0; i <= 10; i++) { const c = turbo(i / 10).map((x) => Math.round(255 * x)); stops.push(`rgb(${c})`); }
    el.querySelector('.bar').style.background = `linear-gradient(to right, ${stops.join(',')})`;
    el.querySelector('.ticks').innerHTML = [0, 0.5, 1].map((f) => `<span>${(f * max).toFixed(max >= 10 ? 0 : 1)}</span>`).join('');
    el.querySelector('.label').textContent = mode === 'strain' ? 'strain %' : 'contact pressure kPa';
  }

  let liveStrain = null;  // the strain of the live pose, when the sliders drive the scene
  function colour(frame) {
    const mode = modeEl.value;
    const attr = garment.geometry.getAttribute('color');
    const out = attr.array;
    if (mode === 'plain') {
      const cloth = toLinear(meta.colors.cloth);
      for (let i = 0; i < g.vertices; i++) out.set(cloth, 3 * i);
    } else {
      const values = mode !== 'strain' ? pressure
        : (liveStrain || strain.subarray(frame * g.vertices, (frame + 1) * g.vertices));
      const max = mode === 'strain' ? meta.strain_max : meta.pressure_max;
      for (let i = 0; i < g.vertices; i++) out.set(toLinear(turbo(values[i] / max)), 3 * i);
    }
    attr.needsUpdate = true;
    legend(mode);
  }

  function show(frame) {
    const gp = garment.geometry.getAttribute('position');
    gp.array.set(gPos.subarray(frame * nG, (frame + 1) * nG));
    gp.needsUpdate = true;
    garment.geometry.computeVertexNormals();
    if (b.frames > 1) {
      const bp = body.geometry.getAttribute('position');
      bp.array.set(bPos.subarray(frame * nB, (frame + 1) * nB));
      bp.needsUpdate = true;
      body.geometry.computeVertexNormals();
    }
    colour(frame);
    timeEl.textContent = `${meta.times[frame].toFixed(2)} s`;
    render();
  }

  function render() { renderer.render(scene, camera); }

  let playing = false;
  document.getElementById('play').addEventListener('click', (e) => {
    playing = !playing;
    e.target.textContent = playing ? 'pause' : 'play';
    const tick = () => {
      if (!playing) return;
      slider.value = String((Number(slider.value) + 1) % meta.frames);
      show(Number(slider.value));
      setTimeout(() => requestAnimationFrame(tick), 1000 / 30);
    };
    tick();
  });
  slider.addEventListener('input', () => show(Number(slider.value)));
  modeEl.addEventListener('change', () => colour(Number(slider.value)) || render());
  document.getElementById('show-body').addEventListener('change', (e) => { body.visible = e.target.checked; render(); });
  document.getElementById('show-garment').addEventListener('change', (e) => { garment.visible = e.target.checked; render(); });
  controls.addEventListener('change', render);
  window.addEventListener('resize', () => {
    camera.aspect = container.clientWidth / container.clientHeight;
    shift();
    camera.updateProjectionMatrix();
    renderer.setSize(container.clientWidth, container.clientHeight);
    render();
  });
  show(Number(slider.value));
  const live = await fetch('live.json').then((r) => (r.ok ? r.json() : null)).catch(() => null);
  if (live) {
    await startLive(live, { garment, body, nG, nB, nV: g.vertices, colour, render, modeEl,
      setStrain: (s) => { liveStrain = s; } });
    return;
  }
  statusEl.textContent = `ready: ${g.vertices} garment vertices, ${meta.frames} frames (three.js r${THREE.REVISION})`;
  document.body.dataset.ready = '1';
}

// The pose sliders of `tryon view --live`: every change asks the server for the posed
// scene (one request at a time; the latest slider values win).
async function startLive(live, s) {
  document.getElementById('frame-row').style.display = 'none';
  s.modeEl.querySelector('option[value="pressure"]').disabled = true;
  // a network's millimetres of noise read as several % of strain on centimetre edges: show the fabric unless asked
  if (s.modeEl.value === 'pressure' || !params.get('mode')) s.modeEl.value = 'plain';
  const box = document.getElementById('live');
  const title = document.createElement('div');
  title.className = 'live-title';
  title.textContent = `pose (${live.method}, live)`;
  box.replaceChildren(title);
  const inputs = live.controls.map((c) => {
    const row = document.createElement('label');
    row.className = 'live-row';
    const name = document.createElement('span');
    name.textContent = c.label;
    const input = document.createElement('input');
    Object.assign(input, { type: 'range', min: String(c.min), max: String(c.max), step: 'any' });
    input.value = String(params.has(c.name) ? Number(params.get(c.name)) : c.value);  // the range clamps it
    const deg = document.createElement('span');
    deg.className = 'deg';
    const label = () => { deg.textContent = `${Number(input.value).toFixed(0)}°`; };
    label();
    row.append(name, input, deg);
    box.appendChild(row);
    input.addEventListener('input', () => { label(); ask(); });
    return [c.name, input];
  });
  let busy = false, again = false;
  async function ask() {  // true when the scene shows the sliders' pose
    if (busy) { again = true; return false; }
    busy = true;
    let shown = false;
    try {
      do {
        again = false;
        const query = inputs.map(([name, input]) => `${encodeURIComponent(name)}=${input.value}`).join('&');
        const response = await fetch(`live?${query}`);
        if (!response.ok) {
          const why = (await response.text()).replace(/<[^>]*>/g, ' ').replace(/\s+/g, ' ').trim();
          throw new Error(`live pose: ${response.status}: ${why.slice(0, 300)}`);
        }
        const a = new Float32Array(await response.arrayBuffer());
        if (a.length !== s.nG + s.nB + s.nV + 1) throw new Error('live pose: the server sent another mesh than this page shows');
        for (const [mesh, from, n] of [[s.garment, 0, s.nG], [s.body, s.nG, s.nB]]) {
          const attr = mesh.geometry.getAttribute('position');
          attr.array.set(a.subarray(from, from + n));
          attr.needsUpdate = true;
          mesh.geometry.computeVertexNormals();
        }
        s.setStrain(a.subarray(s.nG + s.nB, s.nG + s.nB + s.nV));
        s.colour(0);
        s.render();
        statusEl.textContent = `ready: live, ${a[a.length - 1].toFixed(1)} ms per pose (${s.nV} garment vertices)`;
        shown = true;
      } while (again);
    } catch (err) {
      statusEl.textContent = `error: ${err.message}`;
      shown = false;
    } finally {
      busy = false;
    }
    if (again) setTimeout(ask, 200);  // a slider moved while a request failed: try its pose once more
    return shown;
  }
  if (await ask()) document.body.dataset.ready = '1';
}

main().catch((err) => { statusEl.textContent = `error: ${err.message}`; console.error(err); });
