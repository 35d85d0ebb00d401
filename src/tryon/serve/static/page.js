// The shopper's page: a body from height, weight and gender (or from 1-4 photos with the
// height: POST /v1/bodies/photos), every size of a garment draped on it (POST /v1/bodies,
// POST /v1/fits, GET /v1/fits/{id}?wait=...), the
// recommended size with its reason, and each size in 3D coloured by strain, ease or
// contact pressure. URL parameters fill the form (height_cm, weight_kg, gender, garment,
// fabric); auto=1 submits it, mode=strain|ease|pressure picks the colouring.
import * as THREE from '/static/three-bundle.min.js';
import { makeMesh, toLinear, turbo } from '/static/meshes.js';

const $ = (id) => document.getElementById(id);
const params = new URLSearchParams(location.search);
const status = (text) => { $('status').textContent = text; };
const MODES = { strain: 'strain', ease: 'ease', pressure: 'pressure' };
let mode = MODES[params.get('mode')] || 'strain';
let fit = null, shown = null, viewer = null, drawnOnce = false;

async function api(path, body) {
  const r = await fetch(path, body ? { method: 'POST', headers: { 'content-type': 'application/json' }, body: JSON.stringify(body) } : {});
  const data = await r.json().catch(() => ({}));
  if (!r.ok) throw new Error(data.detail || `${r.status} ${r.statusText}`);
  return data;
}

async function catalog() {
  const c = await api('/v1/catalog');
  $('garment').innerHTML = c.garments.map((g) => `<option value="${g.name}">${g.label}${g.learned ? '' : ' (simulated: minutes)'}</option>`).join('');
  $('fabric').innerHTML = c.fabrics.map((f) => `<option value="${f}">${f}</option>`).join('');
  for (const key of ['height_cm', 'weight_kg', 'gender', 'garment', 'fabric']) if (params.get(key)) $(key).value = params.get(key);
  $('fabric').value = params.get('fabric') || 'gray-interlock';
}

function makeViewer() {
  const container = $('view');
  const renderer = new THREE.WebGLRenderer({ antialias: true, preserveDrawingBuffer: true });
  renderer.setPixelRatio(window.devicePixelRatio || 1);
  renderer.setSize(container.clientWidth, container.clientHeight);
  renderer.outputColorSpace = THREE.SRGBColorSpace;
  container.appendChild(renderer.domElement);
  const scene = new THREE.Scene();
  scene.background = new THREE.Color(0.96, 0.96, 0.95);
  scene.add(new THREE.HemisphereLight(0xffffff, 0x8a8070, 1.6));
  const sun = new THREE.DirectionalLight(0xffffff, 1.8);
  sun.position.set(1.5, -3, 4);
  scene.add(sun);
  const camera = new THREE.PerspectiveCamera(30, container.clientWidth / container.clientHeight, 0.01, 100);
  camera.up.set(0, 0, 1);
  const controls = new THREE.OrbitControls(camera, renderer.domElement);
  const v = { renderer, scene, camera, controls, meshes: [], render: () => renderer.render(scene, camera) };
  controls.addEventListener('change', v.render);
  window.addEventListener('resize', () => {
    camera.aspect = container.clientWidth / container.clientHeight;
    camera.updateProjectionMatrix();
    renderer.setSize(container.clientWidth, container.clientHeight);
    v.render();
  });
  return v;
}

async function loadScene(url) {
  const meta = await (await fetch(url)).json();
  const buffer = await (await fetch(url.replace(/[^/]*$/, meta.bin))).arrayBuffer();
  const arr = (name) => {
    const s = meta.layout[name];
    return s ? new (s.type === 'uint32' ? Uint32Array : Float32Array)(buffer, s.offset, s.count) : null;
  };
  return { meta, garment: [arr('garment_positions'), arr('garment_faces')], body: [arr('body_positions'), arr('body_faces')],
           values: { strain: arr('strain'), pressure: arr('pressure'), ease: arr('ease') } };
}

function colour(s) {
  const max = s.meta.scales[mode], values = s.values[mode];
  const out = s.garmentMesh.geometry.getAttribute('color');
  const stops = [...Array(11).keys()].map((i) => `rgb(${turbo(i / 10).map((x) => Math.round(255 * x))})`);
  if (!values) {  // a prediction has no contact pressure until the simulator refines it
    const plain = toLinear(s.meta.colors.cloth);
    for (let i = 0; i < out.count; i++) out.array.set(plain, 3 * i);
    out.needsUpdate = true;
    $('legend').querySelector('.bar').style.background = 'none';
    $('legend').querySelector('.ticks').textContent = `${s.meta.units[mode]}: shown once this size is refined`;
    return;
  }
  for (let i = 0; i < values.length; i++) out.array.set(toLinear(turbo(values[i] / max)), 3 * i);
  out.needsUpdate = true;
  $('legend').querySelector('.bar').style.background = `linear-gradient(to right, ${stops.join(',')})`;
  $('legend').querySelector('.ticks').textContent = `${s.meta.units[mode]}: 0 to ${max.toFixed(max >= 10 ? 0 : 1)}`;
}

function drawnShare() {  // the share of the canvas that is not background: a drawn scene is not blank
  const gl = viewer.renderer.getContext();
  const w = gl.drawingBufferWidth, h = gl.drawingBufferHeight;
  const px = new Uint8Array(4 * w * h);
  gl.readPixels(0, 0, w, h, gl.RGBA, gl.UNSIGNED_BYTE, px);
  let drawn = 0;
  for (let i = 0; i < px.length; i += 16) if (Math.abs(px[i] - 245) > 12 || Math.abs(px[i + 2] - 242) > 12) drawn++;
  return drawn / (px.length / 16);
}

async function showSize(entry) {
  if (!entry || !entry.scene_url) return;
  viewer = viewer || makeViewer();
  const s = await loadScene(entry.scene_url);
  for (const m of viewer.meshes) viewer.scene.remove(m);
  const body = makeMesh(s.body[0], s.body[1], s.meta.colors.skin, false);
  s.garmentMesh = makeMesh(s.garment[0], s.garment[1], [1, 1, 1], true);
  viewer.meshes = [body, s.garmentMesh];
  viewer.scene.add(body, s.garmentMesh);
  if (!drawnOnce) {
    const box = new THREE.Box3().setFromBufferAttribute(body.geometry.getAttribute('position'));
    const center = box.getCenter(new THREE.Vector3()), size = box.getSize(new THREE.Vector3());
    const dist = 1.1 * size.z / (2 * Math.tan((viewer.camera.fov * Math.PI) / 360));
    viewer.camera.position.set(center.x + 0.35 * dist, center.y - dist, center.z + 0.1 * dist);
    viewer.controls.target.copy(center);
    viewer.controls.update();
    drawnOnce = true;
  }
  shown = s;
  colour(s);
  viewer.render();
  document.querySelectorAll('#sizes button').forEach((b) => b.classList.toggle('on', b.dataset.size === entry.size));
  status(`ready: size ${entry.size} drawn (${fit.status}), ${mode}, ${(100 * drawnShare()).toFixed(0)} % of the view`);
}

function renderModes() {
  $('modes').innerHTML = Object.keys(MODES).map((m) => `<button type="button" data-mode="${m}" class="${m === mode ? 'on' : ''}">${m}</button>`).join('');
  $('modes').querySelectorAll('button').forEach((b) => b.addEventListener('click', () => {
    mode = b.dataset.mode;
    renderModes();
    if (shown) { colour(shown); viewer.render(); status(status_text()); }
  }));
}
const status_text = () => $('status').textContent.replace(/, (strain|ease|pressure),/, `, ${mode},`);

function renderFit(view) {
  fit = view;
  $('progress').firstElementChild.style.width = `${Math.round(100 * view.progress)}%`;
  if (view.status === 'failed') { $('reason').textContent = `Could not fit: ${view.reason}`; return; }
  if (!view.recommended) { $('reason').textContent = `${view.status}…`; return; }
  const refining = view.status === 'predicted' ? ' (refining…)' : '';
  $('recommended').textContent = `Your size: ${view.recommended}${refining}`;
  $('reason').textContent = view.reasons.join('; ');
  const title = (s) => [...s.why_not, s.judged_on === 'prediction' ? 'predicted' + (s.not_refined ? `, not refined: ${s.not_refined}` : '') : s.judged_on].join('; ');
  $('sizes').innerHTML = view.sizes.map((s) => `<button type="button" data-size="${s.size}" class="${s.fits ? '' : 'nofit'}" title="${title(s)}">${s.size}${s.ease_cm != null ? ` · ${s.ease_cm.toFixed(1)} cm` : ''}</button>`).join('');
  $('sizes').querySelectorAll('button').forEach((b) => b.addEventListener('click', () => showSize(view.sizes.find((s) => s.size === b.dataset.size))));
  const keep = shown && view.sizes.find((s) => s.size === document.querySelector('#sizes button.on')?.dataset.size);
  showSize(keep || view.sizes.find((s) => s.size === view.recommended) || view.sizes[0]);
}

async function submit(e) {
  if (e) e.preventDefault();
  $('go').disabled = true;
  try {
    const photos = [...$('photos').files];
    let body;
    if (photos.length) {  // the body from the shopper's photos, with their height (and weight)
      if (photos.length > 4) throw new Error('give at most 4 photos');
      status(`reading ${photos.length} photo(s)…`);
      const form = new FormData();
      for (const f of photos) form.append('photos', f, f.name);
      form.append('height_cm', $('height_cm').value);
      form.append('gender', $('gender').value);
      if ($('weight_kg').value) form.append('weight_kg', $('weight_kg').value);
      const r = await fetch('/v1/bodies/photos', { method: 'POST', body: form });
      body = await r.json().catch(() => ({}));
      if (!r.ok) throw new Error(body.detail || `${r.status} ${r.statusText}`);
    } else {
      status('fitting the body…');
      body = await api('/v1/bodies', { height_cm: +$('height_cm').value, weight_kg: +$('weight_kg').value, gender: $('gender').value });
    }
    const m = body.measurements;
    $('body').textContent = `your body: chest ${m.chest_cm.toFixed(0)}, waist ${m.waist_cm.toFixed(0)}, hip ${m.hip_cm.toFixed(0)} cm`;
    status('draping every size…');
    let view = await api('/v1/fits', { body_id: body.body_id, garment: $('garment').value, fabric: $('fabric').value });
    renderFit(view);
    while (!['refined', 'simulated', 'failed'].includes(view.status)) {
      view = await api(`/v1/fits/${view.fit_id}?wait=20&after=${view.status}`);
      renderFit(view);
      if (params.get('until') && view.status === params.get('until')) break;
    }
  } catch (err) {
    $('reason').textContent = `Sorry: ${err.message}`;
    status(`error: ${err.message}`);
  } finally {
    $('go').disabled = false;
  }
}

renderModes();
$('form').addEventListener('submit', submit);
catalog().then(() => { if (params.get('auto') === '1') submit(); }).catch((err) => status(`error: ${err.message}`));
