// The report viewer's page script (see report_viewer.h): three.js (r111, Debian's libjs-three)
// and its OrbitControls are inlined before it; the models' arrays sit in octet-stream script
// elements, decoded when a model is first shown. Uses the page's el(), fmt() and errors.
#include "pipeline/runner/report_viewer.h"

namespace ibmr {

const char* const kViewerScript = R"JS(
function viewerSection(V, parent) {
  const style = document.createElement('style');
  style.textContent = '.viewer-wrap{position:relative;display:inline-block}canvas.viewer{border:1px solid #ccc;cursor:grab}' +
      '.viewer-tip{position:absolute;pointer-events:none;background:#fff;border:1px solid #888;padding:2px 6px;font-size:12px;display:none;white-space:nowrap}' +
      '.viewer-buttons button{margin:0 6px 6px 0}.viewer-buttons button.active{font-weight:bold;background:#dde8f6}';
  document.head.appendChild(style);
  el('h2', {}, parent, 'The model: drag to turn, scroll to zoom, right-drag to pan');
  if (!V.models.length) {
    el('p', {class: 'note'}, parent, 'No model in this workspace (texture/mesh.glb, surfels/mesh.ply, dense/fused.ply, hull/hull.ply, ' +
       'volume/*/volume.json): nothing to show.');
    return Promise.resolve('none');
  }
  if (typeof THREE === 'undefined' || !THREE.OrbitControls) {
    el('p', {class: 'note'}, parent, 'The viewer needs three.js, which was not inlined: install Debian\'s libjs-three and write the report again.');
    return Promise.resolve('nothree');
  }
  const bar = el('div', {class: 'viewer-buttons'}, parent);
  const wrap = el('div', {class: 'viewer-wrap'}, parent);
  const canvas = el('canvas', {class: 'viewer', width: 960, height: 600}, wrap);
  const tip = el('div', {class: 'viewer-tip'}, wrap);
  const note = el('p', {class: 'note'}, parent);
  const problems = el('p', {class: 'note'}, parent);
  const legend = el('p', {class: 'note'}, parent);
  let renderer;
  try {
    renderer = new THREE.WebGLRenderer({canvas: canvas, antialias: true, preserveDrawingBuffer: true});
  } catch (e) {
    note.textContent = 'WebGL is not available in this browser (' + e.message + '): the model cannot be shown.';
    return Promise.resolve('nowebgl');
  }
  const background = 0xf4f4f4;
  renderer.setClearColor(background);
  const scene = new THREE.Scene();
  const camera = new THREE.PerspectiveCamera(40, canvas.width / canvas.height, 0.001, 1000);
  if (V.up) camera.up.set(V.up[0], V.up[1], V.up[2]);
  scene.add(camera);
  scene.add(new THREE.AmbientLight(0xffffff, 0.55));
  const light = new THREE.DirectionalLight(0xffffff, 0.6);
  light.position.set(0.3, 0.6, 1);
  camera.add(light);  // a headlight: the side the user looks at is lit
  const controls = new THREE.OrbitControls(camera, canvas);
  const render = () => renderer.render(scene, camera);
  controls.addEventListener('change', render);

  function bytes(id) {
    const text = atob(document.getElementById(id).textContent);
    const out = new Uint8Array(text.length);
    for (let i = 0; i < text.length; ++i) out[i] = text.charCodeAt(i);
    return out;
  }
  const floats = id => new Float32Array(bytes(id).buffer);
  function texture(uri) {
    return new Promise((resolve, reject) => {
      const image = new Image();
      image.onload = () => {
        const t = new THREE.Texture(image);
        t.generateMipmaps = false;  // any size, no resize to a power of two
        t.minFilter = THREE.LinearFilter;
        t.wrapS = t.wrapT = THREE.ClampToEdgeWrapping;
        t.needsUpdate = true;
        resolve(t);
      };
      image.onerror = () => reject(new Error('a texture image does not decode'));
      image.src = uri;
    });
  }
  async function meshPart(part, pointSize) {
    const g = new THREE.BufferGeometry();
    g.setAttribute('position', new THREE.BufferAttribute(floats(part.position), 3));
    if (part.color) g.setAttribute('color', new THREE.BufferAttribute(bytes(part.color), 3, true));
    if (pointSize) {
      return new THREE.Points(g, new THREE.PointsMaterial({size: pointSize, vertexColors: THREE.VertexColors}));
    }
    g.setIndex(new THREE.BufferAttribute(new Uint32Array(bytes(part.index).buffer), 1));
    if (part.texture) {
      g.setAttribute('uv', new THREE.BufferAttribute(floats(part.uv), 2));
      return new THREE.Mesh(g, new THREE.MeshBasicMaterial({map: await texture(part.texture), side: THREE.DoubleSide}));
    }
    g.computeVertexNormals();
    return new THREE.Mesh(g, new THREE.MeshLambertMaterial({
        color: part.color ? 0xffffff : 0xb8b8b8, vertexColors: part.color ? THREE.VertexColors : THREE.NoColors, side: THREE.DoubleSide}));
  }
  async function plane(p) {
    const c = p.corners;
    const center = [0, 1, 2].map(k => (c[k] + c[3 + k] + c[6 + k] + c[9 + k]) / 4);
    const g = new THREE.BufferGeometry();
    g.setAttribute('position', new THREE.BufferAttribute(new Float32Array(c.map((v, i) => v - center[i % 3])), 3));
    g.setAttribute('uv', new THREE.BufferAttribute(new Float32Array([0, 1, 1, 1, 1, 0, 0, 0]), 2));  // image top at v = 1
    g.setIndex([0, 1, 2, 0, 2, 3]);
    const m = new THREE.Mesh(g, new THREE.MeshBasicMaterial({map: await texture(p.texture), transparent: true, depthWrite: false,
                                                             side: THREE.DoubleSide}));
    m.position.set(center[0], center[1], center[2]);  // three.js sorts transparent quads back to front by position
    return m;
  }
  async function build(m) {
    const group = new THREE.Group();
    if (m.kind === 'planes') {
      for (const p of m.planes) group.add(await plane(p));
    } else {
      const pointSize = m.kind === 'points' ? 3 * m.bounds.radius / Math.sqrt(Math.max(m.shown, 1)) : 0;
      for (const part of m.parts) group.add(await meshPart(part, pointSize));
    }
    return group;
  }

  // Cameras: training grey, held-out coloured by their best score (red lowest, green highest).
  const cameraGroup = new THREE.Group();
  const scored = V.cameras.filter(c => c.heldout && typeof c.score === 'number').map(c => c.score);
  const lo = scored.length ? Math.min(...scored) : 0, hi = scored.length ? Math.max(...scored) : 1;
  function cameraColor(c) {
    if (c.flagged) return new THREE.Color(0xff7f0e);  // disagrees with the other views (view_agreement.json)
    if (!c.heldout) return new THREE.Color(0x8a8a8a);
    if (typeof c.score !== 'number') return new THREE.Color(0x7b4173);
    const t = hi > lo ? (c.score - lo) / (hi - lo) : 1;
    return new THREE.Color().setHSL(0.33 * t, 0.9, 0.42);
  }
  function addFrustums(center, radius) {
    const distances = V.cameras.map(c => Math.hypot(c.center[0] - center[0], c.center[1] - center[1], c.center[2] - center[2]))
                               .sort((a, b) => a - b);
    const size = distances.length ? 0.08 * distances[Math.floor(distances.length / 2)] : radius;
    for (const c of V.cameras) {
      const p = [];
      const corner = k => [0, 1, 2].map(i => c.center[i] + size * c.corners[3 * k + i]);
      for (let k = 0; k < 4; ++k) p.push(...c.center, ...corner(k), ...corner(k), ...corner((k + 1) % 4));
      const g = new THREE.BufferGeometry();
      g.setAttribute('position', new THREE.BufferAttribute(new Float32Array(p), 3));
      cameraGroup.add(new THREE.LineSegments(g, new THREE.LineBasicMaterial({color: cameraColor(c)})));
    }
    scene.add(cameraGroup);
  }
  const heldout = V.cameras.filter(c => c.heldout).length;
  const flagged = V.cameras.filter(c => c.flagged).map(c => c.name);
  legend.textContent = V.cameras.length ? 'Cameras' + (V.cameras_from ? ' (' + V.cameras_from + ')' : '') + ': ' +
      (V.cameras.length - heldout) + ' training views in grey, ' + heldout + ' held-out views coloured by the best held-out ' + V.metric +
      ' of any model, red ' + fmt(lo) + ' dB to green ' + fmt(hi) + ' dB; hover a camera for its name and score.' +
      (flagged.length ? ' In orange, ' + flagged.length + ' view(s) whose depth disagrees with the other views (a likely wrong pose): ' +
       flagged.join(', ') + '.' : '')
      : 'No cameras to show' + (V.cameras_error ? ': ' + V.cameras_error : ' (no sparse model in the workspace).');
  canvas.addEventListener('mousemove', e => {
    const rect = canvas.getBoundingClientRect();
    const x = e.clientX - rect.left, y = e.clientY - rect.top;
    let best = null, bestDistance = 12;
    for (const c of V.cameras) {
      const s = new THREE.Vector3(c.center[0], c.center[1], c.center[2]).project(camera);
      if (s.z > 1) continue;
      const d = Math.hypot((s.x + 1) / 2 * rect.width - x, (1 - s.y) / 2 * rect.height - y);
      if (d < bestDistance) { best = c; bestDistance = d; }
    }
    tip.style.display = best ? 'block' : 'none';
    if (!best) return;
    tip.textContent = best.name + (!best.heldout ? ': training view' : typeof best.score === 'number'
        ? ': held out, best ' + best.model + ' ' + fmt(best.score) + ' dB ' + V.metric : ': held out, not scored') +
        (best.flagged ? '; flagged: disagrees with the other views (view_agreement.json)' : '');
    tip.style.left = (x + 14) + 'px';
    tip.style.top = (y + 8) + 'px';
  });

  const built = {};
  const buttons = [];
  let shown = null, placed = false;
  function describe(m) {
    if (m.error) return m.name + ' (' + m.source + ') could not be shown: ' + m.error;
    return m.name + ' (' + m.source + '): ' + fmt(m.elements, 0) + ' ' + m.unit + (m.decimated
        ? ', ' + (m.kind === 'points' ? 'subsampled' : 'decimated') + ' to ' + fmt(m.shown, 0) + ' for this page (report.max_' +
          (m.kind === 'points' ? 'points' : 'faces') + ' = ' + fmt(m.kind === 'points' ? V.max_points : V.max_faces, 0) +
          '; ibmr report --max-' + (m.kind === 'points' ? 'points' : 'faces') + ')' : '') + '.';
  }
  const listProblems = () => {
    problems.textContent = V.models.filter(m => m.error).map(describe).join(' ');
  };
  async function show(i) {
    const m = V.models[i];
    buttons.forEach((b, k) => b.classList.toggle('active', k === i));
    note.textContent = describe(m);
    if (m.error) return false;
    if (!built[i]) built[i] = build(m);
    let group;
    try {
      group = await built[i];
    } catch (e) {
      m.error = e.message;
      note.textContent = describe(m);
      buttons[i].textContent = m.name + ' (unreadable)';
      listProblems();
      return false;
    }
    if (shown) scene.remove(shown);
    shown = group;
    scene.add(group);
    const center = m.bounds.center, radius = m.bounds.radius;
    controls.target.set(center[0], center[1], center[2]);
    if (!placed) {  // the first view sees the whole model
      placed = true;
      addFrustums(center, radius);
      // From the first camera's side, raised 25 degrees above it (a ring of cameras is seen as one).
      const from = V.cameras.length ? new THREE.Vector3(...V.cameras[0].center).sub(controls.target) : new THREE.Vector3(1, 0, 1);
      from.normalize().add(camera.up.clone().multiplyScalar(0.47));
      const distance = radius / Math.sin(camera.fov * Math.PI / 360) * 1.5;
      camera.position.copy(controls.target).add(from.normalize().multiplyScalar(distance));
      camera.near = distance / 1000;
      camera.far = distance * 100;
      camera.updateProjectionMatrix();
    }
    controls.update();
    render();
    return true;
  }
  V.models.forEach((m, i) => {
    const b = el('button', {type: 'button', title: describe(m)}, bar, m.name + (m.error ? ' (unreadable)' : ''));
    b.addEventListener('click', () => show(i));
    buttons.push(b);
  });
  listProblems();

  // The page's check: the first model that loads, drawn alone (cameras hidden), read back.
  return (async () => {
    for (let i = 0; i < V.models.length; ++i) {
      if (!(await show(i))) continue;
      cameraGroup.visible = false;
      render();
      const gl = renderer.getContext();
      const w = gl.drawingBufferWidth, h = gl.drawingBufferHeight;
      const pixels = new Uint8Array(w * h * 4);
      gl.readPixels(0, 0, w, h, gl.RGBA, gl.UNSIGNED_BYTE, pixels);
      cameraGroup.visible = true;
      render();
      let painted = 0;
      for (let p = 0; p < pixels.length; p += 4) {
        if (Math.abs(pixels[p] - 0xf4) + Math.abs(pixels[p + 1] - 0xf4) + Math.abs(pixels[p + 2] - 0xf4) > 24) ++painted;
      }
      return painted > 100 ? 'drawn' : 'blank';
    }
    note.textContent = 'No model could be shown.';
    return 'unreadable';
  })();
}
)JS";

}  // namespace ibmr
