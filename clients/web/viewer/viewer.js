// craftscan's 3D viewer (clients/web/API.md, "The 3D viewer"): a fused point
// cloud and/or a triangle mesh in millimetres with the station's +Z up,
// orbit/pan/zoom with the mouse, levels of detail for large clouds.
// Bundled by esbuild into an IIFE that defines the global `CraftscanViewer`
// (clients/web/viewer/CMakeLists.txt); the same bundle is served as
// /assets/viewer.bundle.js and inlined into every report.html, so it must
// work from file:// without network: it fetches nothing unless loadPly is
// given a URL.
//
//   const v = CraftscanViewer.create(container, {background: "#1d2125"});
//   await v.loadPly("/api/sessions/ID/files/fused.ply");  // → {points, triangles}
//   v.setData({cloud: {positions, colors}, mesh: {positions, colors, indices}});
//   v.setMode("both");  v.resetView();  v.stats();  v.dispose();
//
// Colours are 8-bit sRGB (as the station writes them); positions float32 mm.
import {
  BufferAttribute,
  BufferGeometry,
  Color,
  DirectionalLight,
  DoubleSide,
  HemisphereLight,
  Mesh,
  MeshStandardMaterial,
  PerspectiveCamera,
  Points,
  PointsMaterial,
  Scene,
  Vector3,
  WebGLRenderer,
} from 'three';
import { OrbitControls } from 'three/examples/jsm/controls/OrbitControls.js';
import { PLYLoader } from 'three/examples/jsm/loaders/PLYLoader.js';

export const version = '1';

// Clouds above this many points are drawn decimated (at most this many)
// while the camera moves and whole when it rests. While moving, the number
// drawn adapts to the frame rate (a software renderer or a weak GPU draws
// fewer, down to MIN_LOD_POINTS) so that turning stays fluid.
const DEFAULT_LOD_POINTS = 300000;
const MIN_LOD_POINTS = 30000;
const LOD_SLOW_FPS = 30;  // below: draw fewer while moving (turning stays at 30 fps or more)
const LOD_FAST_FPS = 50;  // above: draw more (up to lodPoints)
// The camera rests once it has not changed for this long (ms).
const REST_DELAY_MS = 200;
// Orbit damping time constant (s): the glide after a drag decays by e every
// DAMPING_TAU_S whatever the frame rate (OrbitControls' own factor is per frame,
// which at a software renderer's 5 fps glides for 20 s).
const DAMPING_TAU_S = 0.07;
// resetView: a three-quarter view, this far round from the front and up.
const FIT_AZIMUTH_DEG = -35;
const FIT_ELEVATION_DEG = 25;
const CLAY = 0xc9b9a6;  // meshes without vertex colours

const MODES = ['cloud', 'mesh', 'both'];

/** Creates a viewer filling `container` (an element; give it a size). Throws when WebGL is not available. */
export function create(container, options) {
  return new Viewer(container, options || {});
}

/** Decodes base64 text (whitespace ignored) into a fresh Uint8Array (its buffer is 4-aligned). */
export function base64ToBytes(text) {
  const binary = atob(String(text).replace(/\s+/g, ''));
  const bytes = new Uint8Array(binary.length);
  for (let i = 0; i < binary.length; i++) bytes[i] = binary.charCodeAt(i);
  return bytes;
}

// --- colours -------------------------------------------------------------------

// 8-bit sRGB → linear, 16-bit normalised: three.js lights and blends in
// linear space and converts the output back to sRGB, so a point's pixel
// shows the colour the file gave it.
let srgbLut = null;
function srgbToLinear16() {
  if (!srgbLut) {
    srgbLut = new Uint16Array(256);
    for (let i = 0; i < 256; i++) {
      const c = i / 255;
      const l = c <= 0.04045 ? c / 12.92 : Math.pow((c + 0.055) / 1.055, 2.4);
      srgbLut[i] = Math.round(l * 65535);
    }
  }
  return srgbLut;
}

function linearColorAttribute(colorsSrgb8) {
  const lut = srgbToLinear16();
  const out = new Uint16Array(colorsSrgb8.length);
  for (let i = 0; i < out.length; i++) out[i] = lut[colorsSrgb8[i]];
  return new BufferAttribute(out, 3, true);
}

// Without colours a cloud is tinted by height along `up` (blue low, sand high).
function heightColorAttribute(positions, up) {
  const n = positions.length / 3;
  let lo = Infinity;
  let hi = -Infinity;
  for (let i = 0; i < n; i++) {
    const h = positions[3 * i] * up.x + positions[3 * i + 1] * up.y + positions[3 * i + 2] * up.z;
    if (h < lo) lo = h;
    if (h > hi) hi = h;
  }
  const span = hi > lo ? hi - lo : 1;
  const a = new Color(0x3b6ea8);
  const b = new Color(0xe8c27a);
  const c = new Color();
  const out = new Float32Array(positions.length);
  for (let i = 0; i < n; i++) {
    const h = positions[3 * i] * up.x + positions[3 * i + 1] * up.y + positions[3 * i + 2] * up.z;
    c.copy(a).lerp(b, (h - lo) / span);
    out[3 * i] = c.r;
    out[3 * i + 1] = c.g;
    out[3 * i + 2] = c.b;
  }
  return new BufferAttribute(out, 3);
}

// --- input checks ----------------------------------------------------------------

function fail(message) {
  throw new Error('craftscan viewer: ' + message);
}

function checkPositions(positions, what) {
  if (!(positions instanceof Float32Array)) fail(what + '.positions must be a Float32Array');
  if (positions.length % 3 !== 0) fail(what + '.positions length ' + positions.length + ' is not a multiple of 3');
  for (let i = 0; i < positions.length; i++) {
    if (!Number.isFinite(positions[i])) fail(what + ': position ' + Math.floor(i / 3) + ' is not finite');
  }
}

function checkColors(colors, positions, what) {
  if (colors == null) return;
  if (!(colors instanceof Uint8Array)) fail(what + '.colors must be a Uint8Array or null');
  if (colors.length !== positions.length)
    fail(what + '.colors has ' + colors.length / 3 + ' entries for ' + positions.length / 3 + ' points');
}

function checkIndices(indices, vertexCount) {
  if (!(indices instanceof Uint32Array)) fail('mesh.indices must be a Uint32Array');
  if (indices.length % 3 !== 0) fail('mesh.indices length ' + indices.length + ' is not a multiple of 3');
  for (let i = 0; i < indices.length; i++) {
    if (indices[i] >= vertexCount) fail('mesh index ' + indices[i] + ' out of range (' + vertexCount + ' vertices)');
  }
}

// --- PLY -----------------------------------------------------------------------

const PLY_SIZES = {
  char: 1, int8: 1, uchar: 1, uint8: 1, short: 2, int16: 2, ushort: 2, uint16: 2,
  int: 4, int32: 4, uint: 4, uint32: 4, float: 4, float32: 4, double: 8, float64: 8,
};

// The header as far as the checks need it; throws a clear message for what
// PLYLoader would misread silently (it returns empty or NaN geometry).
function readPlyHeader(buffer) {
  const head = new Uint8Array(buffer, 0, Math.min(buffer.byteLength, 65536));
  let text = '';
  for (let i = 0; i < head.length; i++) text += String.fromCharCode(head[i]);
  if (!/^ply\r?\n/.test(text)) throw new Error('not a PLY file (no "ply" magic line)');
  const end = /end_header(\r\n|\r|\n)/.exec(text);
  if (!end) throw new Error('PLY header has no end_header line');
  const header = { format: '', elements: [], length: end.index + end[0].length };
  for (const raw of text.slice(0, end.index).split(/\r\n|\r|\n/)) {
    const w = raw.trim().split(/\s+/);
    if (w[0] === 'format') {
      header.format = w[1];
    } else if (w[0] === 'element') {
      const count = Number(w[2]);
      if (!Number.isInteger(count) || count < 0) throw new Error("PLY element '" + w[1] + "' has a bad count");
      header.elements.push({ name: w[1], count, properties: [] });
    } else if (w[0] === 'property') {
      const e = header.elements[header.elements.length - 1];
      if (!e) throw new Error('PLY property before any element');
      if (w[1] === 'list') {
        if (!PLY_SIZES[w[2]] || !PLY_SIZES[w[3]]) throw new Error('PLY list property with unknown types');
        e.properties.push({ list: true, name: w[4], countSize: PLY_SIZES[w[2]], itemSize: PLY_SIZES[w[3]] });
      } else {
        if (!PLY_SIZES[w[1]]) throw new Error("PLY property type '" + w[1] + "' unknown");
        e.properties.push({ list: false, name: w[2], size: PLY_SIZES[w[1]] });
      }
    }
  }
  if (!['ascii', 'binary_little_endian', 'binary_big_endian'].includes(header.format))
    throw new Error("PLY format '" + header.format + "' unsupported");
  const vertex = header.elements.find((e) => e.name === 'vertex');
  if (!vertex) throw new Error('PLY file has no vertex element');
  for (const axis of ['x', 'y', 'z'])
    if (!vertex.properties.some((p) => p.name === axis)) throw new Error('PLY vertices have no ' + axis);
  if (header.format !== 'ascii') {
    // Lower bound of the body (lists counted with 3 items, triangles): a
    // truncated file is refused instead of read past its end.
    let need = header.length;
    for (const e of header.elements) {
      let stride = 0;
      for (const p of e.properties) stride += p.list ? p.countSize + 3 * p.itemSize : p.size;
      need += e.count * stride;
    }
    if (buffer.byteLength < need)
      throw new Error('PLY file is truncated (' + buffer.byteLength + ' bytes, the header needs at least ' + need + ')');
  }
  return header;
}

// {positions, colorAttribute (linear, or null), indices (or null)}
function parsePly(buffer) {
  const header = readPlyHeader(buffer);
  const vertexCount = header.elements.find((e) => e.name === 'vertex').count;
  const face = header.elements.find((e) => e.name === 'face');
  let geometry;
  try {
    geometry = new PLYLoader().parse(buffer);
  } catch (e) {
    throw new Error('PLY body unreadable (' + (e && e.message ? e.message : e) + ')');
  }
  const position = geometry.getAttribute('position');
  if (!position || position.count !== vertexCount)
    throw new Error('PLY body has ' + (position ? position.count : 0) + ' readable vertices, the header says ' + vertexCount);
  const positions = position.array instanceof Float32Array ? position.array : new Float32Array(position.array);
  for (let i = 0; i < positions.length; i++)
    if (!Number.isFinite(positions[i])) throw new Error('PLY vertex ' + Math.floor(i / 3) + ' is not a finite number');
  const color = geometry.getAttribute('color') || null;
  let indices = null;
  if (geometry.index && geometry.index.count > 0) {
    indices = geometry.index.array instanceof Uint32Array ? geometry.index.array : new Uint32Array(geometry.index.array);
    checkIndices(indices, vertexCount);
  } else if (face && face.count > 0) {
    throw new Error('PLY faces could not be read');
  }
  geometry.dispose();
  return { positions, colorAttribute: color, indices };
}

// --- the viewer ------------------------------------------------------------------

function isSoftwareRenderer(renderer) {
  const gl = renderer.getContext();
  const info = gl.getExtension('WEBGL_debug_renderer_info');
  const name = String(gl.getParameter(info ? info.UNMASKED_RENDERER_WEBGL : gl.RENDERER));
  return /swiftshader|llvmpipe|softpipe|software/i.test(name);
}

// antialias null: multisampled unless the context turns out to be a software renderer.
function makeRenderer(antialias) {
  const renderer = new WebGLRenderer({ antialias: antialias !== false, powerPreference: 'high-performance' });
  if (antialias === null && isSoftwareRenderer(renderer)) {
    renderer.dispose();
    renderer.forceContextLoss();
    return new WebGLRenderer({ antialias: false, powerPreference: 'high-performance' });
  }
  return renderer;
}

function vec3(value, fallback, what) {
  if (value == null) return fallback.clone();
  if (!Array.isArray(value) || value.length !== 3 || !value.every(Number.isFinite)) fail(what + ' must be [x, y, z]');
  const v = new Vector3(value[0], value[1], value[2]);
  if (v.lengthSq() === 0) fail(what + ' must not be zero');
  return v.normalize();
}

function styled(tag, css, text) {
  const e = document.createElement(tag);
  e.style.cssText = css;
  if (text != null) e.textContent = text;
  return e;
}

const BUTTON_CSS =
  'font:12px/1.2 system-ui,sans-serif;padding:4px 9px;margin-left:4px;border-radius:4px;cursor:pointer;' +
  'border:1px solid rgba(255,255,255,.25);background:rgba(0,0,0,.35);color:#e6e6e6';

class Viewer {
  constructor(container, options) {
    if (!container || typeof container.appendChild !== 'function') fail('create() needs a container element');
    this._options = {
      background: options.background || '#1d2125',
      lodPoints: options.lodPoints > 0 ? Math.floor(options.lodPoints) : DEFAULT_LOD_POINTS,
      pointSize: options.pointSize > 0 ? options.pointSize : 0,  // mm; 0: from the density
      continuous: !!options.continuous,  // render every frame even at rest (benchmarks)
      ui: options.ui !== false,
      // MSAA: true, false, or (left out) on unless the renderer is a
      // software one (SwiftShader, llvmpipe), where it costs 3-4x per frame.
      antialias: typeof options.antialias === 'boolean' ? options.antialias : null,
    };
    this._up = vec3(options.up, new Vector3(0, 0, 1), 'up');
    // Where the camera sits after resetView (seen from the centre), made
    // orthogonal to up: the station's cameras look along +y.
    this._front = vec3(options.front, new Vector3(0, -1, 0), 'front');
    this._mode = options.mode && MODES.includes(options.mode) ? options.mode : null;
    this._container = container;
    this._disposed = false;
    this._cloud = null;  // {points: Points, count, baseSize}
    this._mesh = null;  // {mesh: Mesh, triangles}
    this._frameTimes = [];
    this._frames = 0;
    this._drawnPoints = 0;
    this._interacting = false;
    this._userMoved = false;
    this._lastChange = -Infinity;
    this._lastFrame = 0;
    this._lod = false;
    this._lodCount = this._options.lodPoints;  // drawn while moving (adapts)
    this._lodSince = 0;
    this._lodAdapted = 0;
    this._dirty = true;

    this._root = styled('div', 'position:relative;width:100%;height:100%;min-height:120px;overflow:hidden;' +
      'background:' + this._options.background);
    this._root.className = 'craftscan-viewer';
    container.appendChild(this._root);
    this._message = styled('div', 'position:absolute;left:0;right:0;top:45%;text-align:center;padding:0 16px;' +
      'font:14px/1.4 system-ui,sans-serif;color:#c9d1d9;pointer-events:none;display:none');
    try {
      this._renderer = makeRenderer(this._options.antialias);
    } catch (e) {
      this._root.appendChild(this._message);
      this._showMessage('3D view unavailable: this browser cannot create a WebGL context.', true);
      fail('WebGL is not available (' + (e && e.message ? e.message : e) + ')');
    }
    const renderer = this._renderer;
    renderer.setPixelRatio(Math.min(window.devicePixelRatio || 1, 2));
    renderer.domElement.style.cssText = 'display:block;width:100%;height:100%;outline:none;touch-action:none';
    renderer.domElement.addEventListener('webglcontextlost', (e) => {
      e.preventDefault();
      this._showMessage('3D view lost its WebGL context (the GPU was reset); reload the page.', true);
    });
    this._root.appendChild(renderer.domElement);
    this._root.appendChild(this._message);

    this._scene = new Scene();
    this._scene.background = new Color(this._options.background);
    this._camera = new PerspectiveCamera(40, 1, 0.1, 10000);
    this._camera.up.copy(this._up);
    this._scene.add(this._camera);
    // A sky/ground fill along up and a headlight that follows the camera.
    const hemi = new HemisphereLight(0xffffff, 0x5a5148, 1.4);
    hemi.position.copy(this._up);
    this._scene.add(hemi);
    const head = new DirectionalLight(0xffffff, 1.9);
    head.position.set(-0.35, 0.5, 0.8);
    head.target.position.set(0, 0, -1);
    this._camera.add(head);
    this._camera.add(head.target);

    this._controls = new OrbitControls(this._camera, renderer.domElement);
    this._controls.enableDamping = true;
    this._controls.screenSpacePanning = true;
    this._controls.addEventListener('start', () => {
      this._interacting = true;
      this._userMoved = true;
    });
    this._controls.addEventListener('end', () => {
      this._interacting = false;
    });
    this._controls.addEventListener('change', () => {
      this._lastChange = performance.now();
      this._dirty = true;
    });

    if (this._options.ui) this._buildUi();
    this._resize();
    if (typeof ResizeObserver === 'function') {
      this._resizeObserver = new ResizeObserver(() => this._resize());
      this._resizeObserver.observe(this._root);
    }
    this._onFrame = (t) => this._frame(t);
    this._raf = requestAnimationFrame(this._onFrame);
    this._updateUi();
  }

  // --- API (clients/web/API.md) ---

  /** Loads a PLY (URL or ArrayBuffer): with faces it becomes the mesh, without the cloud. → {points, triangles} */
  async loadPly(source) {
    let name = 'PLY data';
    try {
      if (this._disposed) fail('loadPly after dispose()');
      let buffer;
      if (source instanceof ArrayBuffer) {
        buffer = source;
      } else if (ArrayBuffer.isView(source)) {
        buffer = source.buffer.slice(source.byteOffset, source.byteOffset + source.byteLength);
      } else if (typeof source === 'string' || source instanceof URL) {
        name = String(source);
        const response = await fetch(name);
        if (!response.ok) throw new Error('HTTP ' + response.status + ' ' + response.statusText);
        buffer = await response.arrayBuffer();
      } else {
        throw new Error('loadPly needs a URL or an ArrayBuffer');
      }
      const ply = parsePly(buffer);
      if (this._disposed) fail('disposed while loading');
      if (ply.indices) {
        this._setMesh(ply.positions, ply.colorAttribute, ply.indices);
      } else {
        this._setCloud(ply.positions, ply.colorAttribute);
      }
      this._dataChanged();
      return { points: ply.positions.length / 3, triangles: ply.indices ? ply.indices.length / 3 : 0 };
    } catch (e) {
      const message = String(e && e.message ? e.message : e).replace(/^craftscan viewer: /, '');
      const error = new Error('craftscan viewer: cannot load ' + name + ': ' + message);
      this._showMessage(error.message, true);
      throw error;
    }
  }

  /** Replaces the shown data (either part may be absent or null). Throws for malformed arrays. */
  setData(data) {
    if (this._disposed) fail('setData after dispose()');
    const cloud = data && data.cloud;
    const mesh = data && data.mesh;
    if (cloud) {
      checkPositions(cloud.positions, 'cloud');
      checkColors(cloud.colors, cloud.positions, 'cloud');
    }
    if (mesh) {
      checkPositions(mesh.positions, 'mesh');
      checkColors(mesh.colors, mesh.positions, 'mesh');
      checkIndices(mesh.indices, mesh.positions.length / 3);
    }
    if (cloud) {
      this._setCloud(cloud.positions, cloud.colors ? linearColorAttribute(cloud.colors) : null);
    } else {
      this._removeCloud();
    }
    if (mesh) {
      this._setMesh(mesh.positions, mesh.colors ? linearColorAttribute(mesh.colors) : null, mesh.indices);
    } else {
      this._removeMesh();
    }
    this._dataChanged();
    return { points: this._cloud ? this._cloud.count : 0, triangles: this._mesh ? this._mesh.triangles : 0 };
  }

  /** "cloud", "mesh" or "both". */
  setMode(mode) {
    if (!MODES.includes(mode)) fail("setMode: '" + mode + "' is not cloud, mesh or both");
    this._mode = mode;
    this._applyMode();
  }

  /** Frames the whole model: from the front turned FIT_AZIMUTH_DEG about up, FIT_ELEVATION_DEG above the horizon. */
  resetView() {
    const box = this._bounds();
    if (!box) return;
    const center = box.min.clone().add(box.max).multiplyScalar(0.5);
    const radius = Math.max(box.max.clone().sub(box.min).length() / 2, 1e-3);
    const camera = this._camera;
    const halfV = (camera.fov * Math.PI) / 360;
    const halfH = Math.atan(Math.tan(halfV) * camera.aspect);
    const distance = (radius / Math.sin(Math.min(halfV, halfH))) * 1.02;
    const front = this._front.clone().addScaledVector(this._up, -this._front.dot(this._up));
    if (front.lengthSq() < 1e-9) front.set(1, 0, 0).addScaledVector(this._up, -this._up.x);
    if (front.lengthSq() < 1e-9) front.set(0, 1, 0).addScaledVector(this._up, -this._up.y);
    front.normalize().applyAxisAngle(this._up, (FIT_AZIMUTH_DEG * Math.PI) / 180);
    const el = (FIT_ELEVATION_DEG * Math.PI) / 180;
    const dir = front.multiplyScalar(Math.cos(el)).addScaledVector(this._up, Math.sin(el));
    camera.position.copy(center).addScaledVector(dir, distance);
    camera.near = Math.max(radius / 200, 1e-3);
    camera.far = distance + radius * 40;
    camera.updateProjectionMatrix();
    this._controls.target.copy(center);
    this._controls.minDistance = radius * 0.05;
    this._controls.maxDistance = radius * 30;
    this._controls.update();
    this._userMoved = false;
    this._dirty = true;
  }

  /** {fps, points, triangles, drawnPoints} (+ moving, frames: rendered frames since create). */
  stats() {
    this._trimFrameTimes(performance.now());
    return {
      fps: this._frameTimes.length,
      points: this._cloud ? this._cloud.count : 0,
      triangles: this._mesh ? this._mesh.triangles : 0,
      drawnPoints: this._drawnPoints,
      moving: this._isMoving(performance.now()),
      frames: this._frames,
    };
  }

  dispose() {
    if (this._disposed) return;
    this._disposed = true;
    cancelAnimationFrame(this._raf);
    if (this._resizeObserver) this._resizeObserver.disconnect();
    this._removeCloud();
    this._removeMesh();
    this._controls.dispose();
    this._renderer.dispose();
    this._renderer.forceContextLoss();
    this._root.remove();
  }

  // --- internals ---

  _setCloud(positions, colorAttribute) {
    this._removeCloud();
    const count = positions.length / 3;
    let pos = positions;
    let color = colorAttribute || heightColorAttribute(positions, this._up);
    if (count > this._options.lodPoints) {
      // Shuffled once (seeded, so every load looks the same): any prefix is
      // then an even sample, and the decimated draw is just a shorter range.
      const shuffled = shuffle(pos, color.array, count);
      pos = shuffled.positions;
      color = new BufferAttribute(shuffled.colors, 3, color.normalized);
    }
    const geometry = new BufferGeometry();
    geometry.setAttribute('position', new BufferAttribute(pos, 3));
    geometry.setAttribute('color', color);
    geometry.computeBoundingBox();
    geometry.computeBoundingSphere();
    const size = geometry.boundingBox.getSize(new Vector3());
    // Spacing of `count` points spread over the box's surface; a splat a
    // little larger than that closes the surface.
    const area = Math.max(2 * (size.x * size.y + size.y * size.z + size.z * size.x), 1e-6);
    const spacing = Math.sqrt(area / Math.max(count, 1));
    // PointsMaterial's size is in pixels at distance (viewport height / 2):
    // divided by tan(fov / 2) it is a size in mm.
    const baseSize = (this._options.pointSize || 1.3 * spacing) / Math.tan((this._camera.fov * Math.PI) / 360);
    const material = new PointsMaterial({ size: baseSize, vertexColors: true, sizeAttenuation: true });
    const points = new Points(geometry, material);
    this._scene.add(points);
    this._cloud = { points, count, baseSize };
    this._lod = false;
  }

  _setMesh(positions, colorAttribute, indices) {
    this._removeMesh();
    const geometry = new BufferGeometry();
    geometry.setAttribute('position', new BufferAttribute(positions, 3));
    if (colorAttribute) geometry.setAttribute('color', colorAttribute);
    geometry.setIndex(new BufferAttribute(indices, 1));
    geometry.computeVertexNormals();
    geometry.computeBoundingBox();
    geometry.computeBoundingSphere();
    const material = new MeshStandardMaterial({
      vertexColors: !!colorAttribute,
      color: colorAttribute ? 0xffffff : CLAY,
      roughness: 0.85,
      metalness: 0,
      side: DoubleSide,  // trimmed meshes are open: their inside shows through holes
    });
    const mesh = new Mesh(geometry, material);
    this._scene.add(mesh);
    this._mesh = { mesh, triangles: indices.length / 3 };
  }

  _removeCloud() {
    if (!this._cloud) return;
    this._scene.remove(this._cloud.points);
    this._cloud.points.geometry.dispose();
    this._cloud.points.material.dispose();
    this._cloud = null;
  }

  _removeMesh() {
    if (!this._mesh) return;
    this._scene.remove(this._mesh.mesh);
    this._mesh.mesh.geometry.dispose();
    this._mesh.mesh.material.dispose();
    this._mesh = null;
  }

  _dataChanged() {
    this._hideMessage();
    this._applyMode();
    if (!this._userMoved) this.resetView();
    if (!this._cloud && !this._mesh) this._showMessage('No model to show.', false);
    this._dirty = true;
    this._updateUi();
  }

  _effectiveMode() {
    if (this._mode) return this._mode;
    return this._mesh ? 'mesh' : 'cloud';
  }

  _applyMode() {
    const mode = this._effectiveMode();
    if (this._cloud) this._cloud.points.visible = mode !== 'mesh';
    if (this._mesh) this._mesh.mesh.visible = mode !== 'cloud';
    this._dirty = true;
    this._updateUi();
  }

  _bounds() {
    let box = null;
    for (const part of [this._cloud && this._cloud.points, this._mesh && this._mesh.mesh]) {
      if (!part) continue;
      const b = part.geometry.boundingBox;
      box = box ? box.union(b) : b.clone();
    }
    return box;
  }

  _resize() {
    if (this._disposed) return;
    const w = Math.max(1, this._root.clientWidth);
    const h = Math.max(1, this._root.clientHeight);
    this._renderer.setSize(w, h, false);
    this._camera.aspect = w / h;
    this._camera.updateProjectionMatrix();
    this._dirty = true;
  }

  _isMoving(now) {
    return this._interacting || now - this._lastChange < REST_DELAY_MS;
  }

  _trimFrameTimes(now) {
    const times = this._frameTimes;
    let drop = 0;
    while (drop < times.length && times[drop] <= now - 1000) drop++;
    if (drop) times.splice(0, drop);
  }

  _frame(t) {
    if (this._disposed) return;
    this._raf = requestAnimationFrame(this._onFrame);
    const dt = this._lastFrame ? Math.min((t - this._lastFrame) / 1000, 1) : 1 / 60;
    this._lastFrame = t;
    this._controls.dampingFactor = Math.min(0.9, 1 - Math.exp(-dt / DAMPING_TAU_S));
    this._controls.update();
    const now = performance.now();
    const moving = this._isMoving(now);
    const cloud = this._cloud;
    const lod = !!cloud && moving && cloud.count > this._options.lodPoints;
    if (lod && !this._lod) this._lodSince = now;
    this._lod = lod;
    if (cloud) {
      const drawn = lod ? Math.min(this._lodCount, cloud.count) : cloud.count;
      if (cloud.points.geometry.drawRange.count !== drawn) {
        cloud.points.geometry.setDrawRange(0, drawn);
        // Sparser points get larger splats so the surface stays closed,
        // up to twice the size: beyond, the splats would cost as much
        // fill as the points saved.
        cloud.points.material.size = cloud.baseSize * Math.min(2, Math.sqrt(cloud.count / drawn));
        this._dirty = true;
      }
    }
    if (!this._dirty && !moving && !this._options.continuous) return;
    this._renderer.render(this._scene, this._camera);
    this._dirty = false;
    this._frames++;
    this._drawnPoints = cloud && cloud.points.visible ? Math.min(cloud.count, cloud.points.geometry.drawRange.count) : 0;
    this._frameTimes.push(now);
    this._trimFrameTimes(now);
    if (lod) this._adaptLod(now);
  }

  // The frame rate of the last second of moving decides how many points
  // the next moving frames draw.
  _adaptLod(now) {
    if (now - this._lodSince < 1000 || now - this._lodAdapted < 500) return;
    this._lodAdapted = now;
    const recent = this._frameTimes.filter((t) => t >= this._lodSince);
    const fps = recent.length < 2 ? recent.length
      : ((recent.length - 1) * 1000) / Math.max(recent[recent.length - 1] - recent[0], 1);
    let count = this._lodCount;
    if (fps < LOD_SLOW_FPS) count = Math.max(MIN_LOD_POINTS, Math.floor(count * Math.max(0.25, fps / 30)));
    else if (fps > LOD_FAST_FPS) count = Math.min(this._options.lodPoints, Math.floor(count * 1.5));
    this._lodCount = count;
  }

  _showMessage(text, isError) {
    this._message.textContent = text;
    this._message.style.color = isError ? '#ff9b8f' : '#c9d1d9';
    this._message.style.display = 'block';
    this._message.setAttribute('role', isError ? 'alert' : 'status');
  }

  _hideMessage() {
    this._message.style.display = 'none';
  }

  _buildUi() {
    const bar = styled('div', 'position:absolute;top:8px;right:8px;display:flex');
    this._buttons = {};
    for (const mode of MODES) {
      const b = styled('button', BUTTON_CSS, mode[0].toUpperCase() + mode.slice(1));
      b.type = 'button';
      b.addEventListener('click', () => this.setMode(mode));
      this._buttons[mode] = b;
      bar.appendChild(b);
    }
    const reset = styled('button', BUTTON_CSS, 'Reset view');
    reset.type = 'button';
    reset.addEventListener('click', () => this.resetView());
    bar.appendChild(reset);
    this._info = styled('div', 'position:absolute;left:10px;bottom:8px;font:12px/1.3 system-ui,sans-serif;' +
      'color:rgba(230,230,230,.75);pointer-events:none');
    this._root.appendChild(bar);
    this._root.appendChild(this._info);
  }

  _updateUi() {
    if (!this._buttons) return;
    const both = !!(this._cloud && this._mesh);
    const mode = this._effectiveMode();
    for (const m of MODES) {
      const b = this._buttons[m];
      b.style.display = both ? '' : 'none';
      b.style.background = m === mode ? 'rgba(255,255,255,.22)' : 'rgba(0,0,0,.35)';
      b.setAttribute('aria-pressed', String(m === mode));
    }
    const parts = [];
    const fmt = (n) => n.toLocaleString('en-US');
    if (this._cloud) parts.push(fmt(this._cloud.count) + ' points');
    if (this._mesh) parts.push(fmt(this._mesh.triangles) + ' triangles');
    this._info.textContent = parts.length ? parts.join(' · ') + ' · mm, drag to turn, right-drag to pan, wheel to zoom' : '';
  }
}

// Fisher–Yates with a fixed-seed xorshift: the same file always gives the
// same order (and the same decimated picture).
function shuffle(positions, colors, count) {
  const order = new Uint32Array(count);
  for (let i = 0; i < count; i++) order[i] = i;
  let s = 0x9e3779b9;
  for (let i = count - 1; i > 0; i--) {
    s ^= s << 13;
    s ^= s >>> 17;
    s ^= s << 5;
    const j = (s >>> 0) % (i + 1);
    const t = order[i];
    order[i] = order[j];
    order[j] = t;
  }
  const outPositions = new Float32Array(count * 3);
  const outColors = new colors.constructor(count * 3);
  for (let i = 0; i < count; i++) {
    const k = order[i] * 3;
    outPositions[3 * i] = positions[k];
    outPositions[3 * i + 1] = positions[k + 1];
    outPositions[3 * i + 2] = positions[k + 2];
    outColors[3 * i] = colors[k];
    outColors[3 * i + 1] = colors[k + 1];
    outColors[3 * i + 2] = colors[k + 2];
  }
  return { positions: outPositions, colors: outColors };
}
