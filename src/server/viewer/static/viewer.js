// pvsd's web viewer: a thin client that walks a scene, asks the server
// which objects may be visible (a session over the WebSocket, x-pvs
// frames), fetches each object's triangles the first time it is in the set
// and draws only those. Geometry of objects that left the set stays in a
// bounded LRU, so walking back costs nothing.
//
// Coordinates: the server sends positions relative to the scene's origin
// (f64, from the mesh messages); the viewer draws in that frame, so a scene
// far from the world's origin keeps f32 precision, and adds the origin back
// to the eye it sends.
//
// `window.pvsd` is the page's face for scripted tests (docs/viewer.md).

import * as THREE from './three-0.170.0.module.min.js';
import { decodeFrame, decodeMeshes } from './protocol.js';

const $ = (id) => document.getElementById(id);
const params = new URLSearchParams(location.search);

// Every uncaught error is kept where a test can read it, and shown.
const errors = [];
function report(message, fatal = true) {
  if (fatal) errors.push(String(message));
  const status = $('status');
  status.textContent = String(message);
  status.classList.toggle('error', fatal);
}
addEventListener('error', (e) => report(e.message));
const consoleError = console.error.bind(console);
console.error = (...args) => { errors.push(args.join(' ')); consoleError(...args); };
addEventListener('unhandledrejection', (e) => report(e.reason?.message ?? e.reason));

/** A request to pvsd; an error answer becomes an Error naming its code. */
async function call(path, init = {}) {
  const res = await fetch(path, init);
  if (!res.ok && res.status !== 304) {
    let message = `${res.status} ${res.statusText}`;
    try {
      const body = await res.json();
      message = `${body.error.code}: ${body.error.message}`;
    } catch { /* not a pvsd error body */ }
    const err = new Error(`${init.method ?? 'GET'} ${path}: ${message}`);
    err.status = res.status;
    throw err;
  }
  return res;
}
const getJson = async (path) => (await call(path)).json();
const postJson = async (path, body) =>
  (await call(path, { method: 'POST', headers: { 'content-type': 'application/json' },
    body: JSON.stringify(body ?? {}) })).json();

/** Method options as the command line writes them: `k=32:variant=fme`. */
function parseOptions(text) {
  const out = {};
  for (const part of text.split(':').map((s) => s.trim()).filter(Boolean)) {
    const eq = part.indexOf('=');
    if (eq < 1) throw new Error(`option '${part}' is not key=value`);
    const value = part.slice(eq + 1);
    out[part.slice(0, eq)] = value !== '' && !Number.isNaN(Number(value)) ? Number(value) : value;
  }
  return out;
}

/** Bytes as people read them. */
function bytes(n) {
  if (n < 1024) return `${n} B`;
  if (n < 1024 ** 2) return `${(n / 1024).toFixed(1)} KiB`;
  return `${(n / 1024 ** 2).toFixed(2)} MiB`;
}

// ---------------------------------------------------------------- geometry

/** The bit of an id picture's pixel that says it shows a see-through triangle. */
const SEE_THROUGH = 1 << 23;

const PALETTE = [0xc9b79c, 0x9fb4c7, 0xb8c99c, 0xc7a59f, 0xa99fc7, 0xc7c19f, 0x9fc7bd, 0xbfbfbf];

/** One object's drawable: a THREE.Mesh with its normal and id materials. */
class Drawable {
  constructor(mesh) {
    const g = new THREE.BufferGeometry();
    // Copies: a view would keep its whole batch's buffer alive.
    g.setAttribute('position', new THREE.BufferAttribute(mesh.positions.slice(), 3));
    g.setIndex(new THREE.BufferAttribute(mesh.indices.slice(), 1));
    const triangles = mesh.indices.length / 3;
    g.addGroup(0, mesh.opaque * 3, 0);
    g.addGroup(mesh.opaque * 3, (triangles - mesh.opaque) * 3, 1);
    g.computeBoundingSphere();
    this.id = mesh.id;
    this.bytes = mesh.bytes;
    this.triangles = triangles;
    this.movable = mesh.movable;
    this.object = new THREE.Mesh(g, Materials.normal(mesh.id));
    // The same order in every picture: ties between coplanar faces of two
    // objects resolve alike whether or not others are drawn.
    this.object.renderOrder = mesh.id;
    this.object.frustumCulled = false;
    this.object.matrixAutoUpdate = false;
  }

  dispose() {
    this.object.geometry.dispose();
  }
}

/** Materials: shared per palette colour, tinted for culled objects, and one per id for pictures. */
const Materials = {
  cache: new Map(),
  normal(id) {
    const key = `n${id % PALETTE.length}`;
    if (!this.cache.has(key)) {
      const color = PALETTE[id % PALETTE.length];
      const solid = new THREE.MeshLambertMaterial({ color, flatShading: true, side: THREE.DoubleSide });
      const through = new THREE.MeshLambertMaterial({ color, flatShading: true, side: THREE.DoubleSide,
        transparent: true, opacity: 0.55 });
      this.cache.set(key, [solid, through]);
    }
    return this.cache.get(key);
  },
  tinted() {
    if (!this.cache.has('tinted')) {
      const m = new THREE.MeshLambertMaterial({ color: 0xe53e3e, flatShading: true, side: THREE.DoubleSide,
        emissive: 0x400000 });
      this.cache.set('tinted', [m, m]);
    }
    return this.cache.get('tinted');
  },
  xray() {
    if (!this.cache.has('xray')) {
      const m = new THREE.MeshBasicMaterial({ color: 0xe53e3e, side: THREE.DoubleSide, transparent: true,
        opacity: 0.18, depthTest: false, depthWrite: false });
      this.cache.set('xray', [m, m]);
    }
    return this.cache.get('xray');
  },
  // The object's id + 1 as its exact colour (0 is the background): a
  // picture read back says which object every pixel shows. See-through
  // triangles set bit 23 as well and, as transparent, are drawn after every
  // opaque one without writing depth: a pixel shows the nearest opaque
  // object, or a see-through one in front of it, in the same order in
  // every picture.
  id(id) {
    const key = `i${id}`;
    if (!this.cache.has(key)) {
      const material = (v, seeThrough) => new THREE.ShaderMaterial({
        uniforms: { color: { value: new THREE.Vector3((v & 255) / 255, ((v >> 8) & 255) / 255, ((v >> 16) & 255) / 255) } },
        vertexShader: 'void main() { gl_Position = projectionMatrix * modelViewMatrix * vec4(position, 1.0); }',
        fragmentShader: 'uniform vec3 color; void main() { gl_FragColor = vec4(color, 1.0); }',
        side: THREE.DoubleSide,
        transparent: seeThrough,
        depthWrite: !seeThrough,
      });
      this.cache.set(key, [material(id + 1, false), material((id + 1) | SEE_THROUGH, true)]);
    }
    return this.cache.get(key);
  },
};

/**
 * The client's geometry: every object it holds, fetched in batches the
 * first time it is wanted, kept in least-recently-wanted order and
 * trimmed to `budget` bytes, never dropping an object that is wanted now.
 * Movable objects are asked again (`If-None-Match`, so an unmoved one
 * costs a 304) at most once a second while they are wanted.
 */
class Geometry {
  constructor(sceneId, three, budget) {
    this.sceneId = sceneId;
    this.three = three;
    this.budget = budget;
    this.held = new Map(); // id -> Drawable, least recently wanted first
    this.pending = new Map(); // id -> Promise
    this.heldBytes = 0;
    this.fetchedBytes = 0;
    this.batch = 1024; // the server's default JSON array limit; halved on a 413
    this.cleared = false;
  }

  /** Resolves once every id in `ids` is held. */
  async want(ids) {
    const missing = ids.filter((id) => !this.held.has(id) && !this.pending.has(id));
    for (let i = 0; i < missing.length; i += this.batch) {
      const batch = missing.slice(i, i + this.batch);
      const done = this.fetch(batch);
      for (const id of batch) this.pending.set(id, done);
    }
    const now = performance.now();
    for (const id of ids) {
      const d = this.held.get(id);
      if (!d) continue;
      this.held.delete(id);
      this.held.set(id, d);
      if (d.movable && now - d.checked > 1000) this.revalidate(d, now).catch((e) => report(e.message, false));
    }
    await Promise.all(ids.map((id) => this.pending.get(id)).filter(Boolean));
  }

  async fetch(ids) {
    try {
      let res;
      try {
        res = await call(`/scenes/${encodeURIComponent(this.sceneId)}/meshes`, {
          method: 'POST', headers: { 'content-type': 'application/json' }, body: JSON.stringify({ ids }),
        });
      } catch (e) {
        // A server with a lower array limit than ours: halve the batches.
        if (e.status !== 413 || ids.length < 2) throw e;
        this.batch = Math.max(1, Math.floor(ids.length / 2));
        const half = Math.ceil(ids.length / 2);
        await Promise.all([this.fetch(ids.slice(0, half)), this.fetch(ids.slice(half))]);
        return;
      }
      const buffer = await res.arrayBuffer();
      if (this.cleared) return; // another scene since
      this.fetchedBytes += buffer.byteLength;
      for (const m of decodeMeshes(buffer).meshes) this.keep(m);
    } finally {
      for (const id of ids) this.pending.delete(id);
    }
  }

  keep(mesh, etag = null) {
    const old = this.held.get(mesh.id);
    if (old) this.drop(old);
    const d = new Drawable(mesh);
    d.etag = etag;
    d.checked = performance.now();
    this.held.set(mesh.id, d);
    this.heldBytes += d.bytes;
    this.three.add(d.object);
  }

  /** Asks for a movable object's mesh again, unless it is unchanged. */
  async revalidate(d, now) {
    d.checked = now;
    const headers = d.etag ? { 'if-none-match': d.etag } : {};
    const res = await call(`/scenes/${encodeURIComponent(this.sceneId)}/objects/${d.id}/mesh`, { headers });
    if (res.status === 304 || this.cleared) return;
    const buffer = await res.arrayBuffer();
    this.fetchedBytes += buffer.byteLength;
    const [mesh] = decodeMeshes(buffer).meshes;
    if (this.held.get(d.id) === d) this.keep(mesh, res.headers.get('etag'));
  }

  drop(d) {
    this.three.remove(d.object);
    d.dispose();
    this.held.delete(d.id);
    this.heldBytes -= d.bytes;
  }

  /** Lets go of the least recently wanted objects not in `keep` while over budget. */
  trim(keep) {
    for (const d of [...this.held.values()]) {
      if (this.heldBytes <= this.budget) break;
      if (!keep.has(d.id)) this.drop(d);
    }
  }

  /** Drops everything, for good (another scene, a reload, a new session). */
  clear() {
    this.cleared = true;
    for (const d of [...this.held.values()]) this.drop(d);
    this.pending.clear();
  }
}

// ----------------------------------------------------------------- session

/**
 * A session over the WebSocket: one view in flight at a time (the newest
 * waits its turn; older ones are dropped), answers applied as deltas to the
 * set held. A session is soft state: if the socket or the session dies, a
 * new one is made and its first answer is the whole set.
 */
class Link {
  constructor(open, onFrame, onTrouble) {
    this.openSession = open; // async () => { session, user? }
    this.onFrame = onFrame;
    this.onTrouble = onTrouble;
    this.visible = new Set();
    this.frame = null;
    this.inFlight = null;
    this.queued = null;
    this.reconnects = 0;
  }

  async connect() {
    const { session, user } = await this.openSession();
    this.session = session;
    this.user = user ?? null;
    this.frame = null;
    const scheme = location.protocol === 'https:' ? 'wss' : 'ws';
    const ws = new WebSocket(`${scheme}://${location.host}/sessions/${session}/ws?encoding=x-pvs&stats=true`);
    ws.binaryType = 'arraybuffer';
    await new Promise((resolve, reject) => {
      ws.onopen = resolve;
      ws.onerror = () => reject(new Error('the WebSocket did not open'));
    });
    ws.onmessage = (e) => this.received(e.data);
    ws.onclose = () => this.closed(ws);
    this.ws = ws;
    this.inFlight = null;
    if (this.queued) {
      const next = this.queued;
      this.queued = null;
      this.transmit(next);
    }
  }

  /**
   * Asks for `view` (a view body without `base`); resolves once its answer
   * is applied (or, when a newer view replaced it before it was sent, once
   * that one's is).
   */
  send(view) {
    return new Promise((resolve) => {
      const ask = { view, waiters: [resolve] };
      if (this.inFlight || !this.ws || this.ws.readyState !== WebSocket.OPEN) {
        if (this.queued) ask.waiters.push(...this.queued.waiters);
        this.queued = ask;
      } else {
        this.transmit(ask);
      }
    });
  }

  transmit(ask) {
    this.inFlight = { ...ask, sent: performance.now() };
    this.ws.send(JSON.stringify({ ...ask.view, base: this.frame }));
  }

  received(data) {
    const asked = this.inFlight;
    this.inFlight = null;
    if (typeof data === 'string') {
      // An error about this view (the session lives on) or about the session.
      const body = JSON.parse(data);
      // A lost session is soft state, made again when the socket closes.
      const lost = ['unknown_session', 'session_expired', 'session_evicted'].includes(body.error.code);
      this.onTrouble(`${body.error.code}: ${body.error.message}`, !lost);
    } else {
      const f = decodeFrame(data);
      if (f.base === null) this.visible.clear();
      for (const id of f.removed) this.visible.delete(id);
      for (const id of f.added) this.visible.add(id);
      this.frame = f.frame;
      const latency = asked ? performance.now() - asked.sent : null;
      this.onFrame(f, latency, asked?.view);
    }
    for (const w of asked?.waiters ?? []) w();
    if (this.queued && this.ws) {
      const next = this.queued;
      this.queued = null;
      this.transmit(next);
    }
  }

  async closed(ws) {
    if (ws !== this.ws || this.stopped) return;
    this.ws = null;
    this.onTrouble('the session was lost; making a new one', false);
    // What was asked and not answered waits, merged into one ask of the
    // newest view, for the new session's socket (`connect` sends it).
    const pending = [this.inFlight, this.queued].filter(Boolean);
    this.inFlight = null;
    this.queued = pending.length
      ? { view: pending[pending.length - 1].view, waiters: pending.flatMap((p) => p.waiters) }
      : null;
    for (let wait = 250; !this.stopped; wait = Math.min(wait * 2, 5000)) {
      try {
        await this.connect();
        this.reconnects += 1;
        return;
      } catch (e) {
        this.onTrouble(`reconnecting: ${e.message}`, false);
        await new Promise((r) => setTimeout(r, wait));
      }
    }
  }

  stop() {
    this.stopped = true;
    this.ws?.close();
    for (const ask of [this.inFlight, this.queued]) for (const w of ask?.waiters ?? []) w();
    this.inFlight = null;
    this.queued = null;
  }
}

// ------------------------------------------------------------------ viewer

const canvas = $('view');
const renderer = new THREE.WebGLRenderer({ canvas, antialias: false, powerPreference: 'high-performance' });
renderer.setPixelRatio(params.has('test') ? 1 : Math.min(devicePixelRatio, 2));
renderer.setClearColor(0x10141a);
const three = new THREE.Scene();
three.add(new THREE.HemisphereLight(0xffffff, 0x404850, 1.6));
const sun = new THREE.DirectionalLight(0xffffff, 1.4);
sun.position.set(0.4, 1, 0.25);
three.add(sun);
const camera = new THREE.PerspectiveCamera(60, 1, 0.1, 1000);
const avatars = new THREE.Group();
three.add(avatars);

const state = {
  scenes: [],
  scene: null, // GET /scenes entry
  origin: [0, 0, 0],
  objects: [], // GET /scenes/{id}/objects
  geometry: null,
  link: null,
  walkthrough: params.get('walkthrough'),
  pose: { eye: [0, 0, 0], yaw: 0, pitch: 0 }, // eye in world coordinates
  near: 0.1,
  far: 1000,
  speed: 6,
  walk: null, // GET /scenes/{id}/walk
  autoWalk: null,
  latency: [],
  lastFrame: null,
  map: null,
  usersVisible: [],
  poses: new Map(),
  dirty: true,
};

function forwardOf(pose) {
  const c = Math.cos(pose.pitch);
  return [c * Math.cos(pose.yaw), Math.sin(pose.pitch), c * Math.sin(pose.yaw)];
}

function poseFrom(eye, forward) {
  const len = Math.hypot(...forward) || 1;
  const f = forward.map((v) => v / len);
  return { eye: [...eye], yaw: Math.atan2(f[2], f[0]), pitch: Math.asin(Math.max(-1, Math.min(1, f[1]))) };
}

/** The view body of the current pose at the canvas's size. */
function currentView() {
  const w = renderer.domElement.width;
  const h = renderer.domElement.height;
  return {
    eye: state.pose.eye,
    forward: forwardOf(state.pose),
    up: [0, 1, 0],
    fov_y_deg: 60,
    aspect: w / h,
    near: state.near,
    far: state.far,
    viewport: [w, h],
  };
}

/** Puts the three.js camera at the view (in the origin's frame). */
function placeCamera(view) {
  const eye = view.eye.map((v, i) => v - state.origin[i]);
  camera.position.set(eye[0], eye[1], eye[2]);
  camera.up.set(...view.up);
  camera.lookAt(eye[0] + view.forward[0], eye[1] + view.forward[1], eye[2] + view.forward[2]);
  camera.fov = view.fov_y_deg;
  camera.aspect = view.aspect;
  camera.near = view.near;
  camera.far = view.far;
  camera.updateProjectionMatrix();
  camera.updateMatrixWorld();
}

function resize() {
  const ratio = renderer.getPixelRatio();
  const w = Math.max(1, Math.floor(canvas.clientWidth));
  const h = Math.max(1, Math.floor(canvas.clientHeight));
  if (canvas.width !== Math.floor(w * ratio) || canvas.height !== Math.floor(h * ratio)) {
    renderer.setSize(w, h, false);
    state.dirty = true;
  }
}

/** Shows each held object as the draw mode says, and counts what is drawn. */
function arrange(mode = $('draw').value) {
  const visible = state.link?.visible ?? new Set();
  let drawn = 0;
  let triangles = 0;
  for (const d of state.geometry?.held.values() ?? []) {
    const inSet = visible.has(d.id);
    const show = inSet || mode !== 'visible';
    d.object.visible = show;
    d.object.material = inSet ? Materials.normal(d.id) : mode === 'xray' ? Materials.xray() : Materials.tinted();
    if (show) { drawn += 1; triangles += d.triangles; }
  }
  return { drawn, triangles };
}

function render() {
  resize();
  const view = currentView();
  placeCamera(view);
  const { drawn, triangles } = arrange();
  const t0 = performance.now();
  renderer.render(three, camera);
  state.drawMs = performance.now() - t0;
  state.drawn = drawn;
  state.trianglesDrawn = triangles;
}

// ---------------------------------------------------------------- the HUD

function hud() {
  const g = state.geometry;
  const link = state.link;
  const lat = state.latency;
  const mean = lat.length ? lat.reduce((a, b) => a + b, 0) / lat.length : null;
  const s = state.lastFrame?.stats;
  return {
    scene: state.scene?.id ?? null,
    frame: link?.frame ?? null,
    pvs: link?.visible.size ?? 0,
    held: g?.held.size ?? 0,
    drawn: state.drawn ?? 0,
    triangles: state.trianglesDrawn ?? 0,
    bytesFetched: g?.fetchedBytes ?? 0,
    heldBytes: g?.heldBytes ?? 0,
    latencyMs: lat.length ? lat[lat.length - 1] : null,
    meanLatencyMs: mean,
    cullUs: s?.cull_us ?? null,
    method: s ? (s.fallback ? `${s.fallback} (for ${s.method})` : s.method) : null,
    usersVisible: state.usersVisible,
    reconnects: link?.reconnects ?? 0,
    user: link?.user ?? null,
    session: link?.session ?? null,
    drawMs: state.drawMs ?? null,
    mapMs: state.mapMs ?? null,
    walkthrough: state.walkthrough,
    avatars: avatars.children.map((a) => a.name),
  };
}

function showHud() {
  const h = hud();
  $('hud-pvs').textContent = `${h.pvs} of ${state.objects.length}`;
  $('hud-objects').textContent = `${h.held} / ${h.drawn}`;
  $('hud-triangles').textContent = h.triangles.toLocaleString('en');
  const total = state.scene?.triangles ?? 0;
  $('hud-bytes').textContent = `${bytes(h.bytesFetched)} (${bytes(h.heldBytes)} held)`;
  $('hud-latency').textContent = h.latencyMs === null ? '–' : `${h.latencyMs.toFixed(1)} ms (mean ${h.meanLatencyMs.toFixed(1)})`;
  $('hud-cull').textContent = h.cullUs === null ? '–' : `${h.cullUs.toFixed(0)} µs`;
  $('hud-method').textContent = h.method ?? '–';
  $('hud-users').textContent = state.walkthrough ? String(h.usersVisible.length) : '–';
  $('hud-triangles').title = `${total.toLocaleString('en')} in the scene`;
}

// ---------------------------------------------------------------- the map

/** The frustum of `view` in the origin's frame. */
function frustumOf(view) {
  placeCamera(view);
  const m = new THREE.Matrix4().multiplyMatrices(camera.projectionMatrix, camera.matrixWorldInverse);
  return new THREE.Frustum().setFromProjectionMatrix(m);
}

/**
 * What the map needs of the scene, made once per scene: each object's box
 * in the origin's frame and its rectangle in map pixels, and whether it is
 * big enough to draw as an outline.
 */
function mapLayout(width, height) {
  const b = state.scene?.bounds;
  if (!b) return null;
  const span = Math.max(b.max[0] - b.min[0], b.max[2] - b.min[2]) || 1;
  const scale = (width - 12) / span;
  const o = state.origin;
  const px = (v) => 6 + (v - b.min[0]) * scale;
  const py = (v) => 6 + (v - b.min[2]) * scale;
  const objects = state.objects.filter((obj) => obj.bounds).map((obj) => {
    const [lo, hi] = [obj.bounds.min, obj.bounds.max];
    const clamp = (v, n) => Math.max(0, Math.min(n - 1, Math.floor(v)));
    return {
      id: obj.id,
      box: new THREE.Box3(new THREE.Vector3(lo[0] - o[0], lo[1] - o[1], lo[2] - o[2]),
        new THREE.Vector3(hi[0] - o[0], hi[1] - o[1], hi[2] - o[2])),
      x0: clamp(px(lo[0]), width), x1: clamp(px(hi[0]), width),
      y0: clamp(py(lo[2]), height), y1: clamp(py(hi[2]), height),
      big: (hi[0] - lo[0]) * (hi[2] - lo[2]) > span * span * 0.2,
    };
  });
  return { span, px, py, objects, image: new ImageData(width, height) };
}

// Map colours as little-endian RGBA words.
const MAP_COLOURS = { visible: 0xff78bb48, occluded: 0xff3030c5, outside: 0xff68554a };

/**
 * The top-down map: objects in the set green, culled inside the frustum
 * red, outside it grey; the eye and the frustum's wedge yellow; other
 * users blue. Rectangles are written into one pixel buffer, so a scene of
 * 10,000 objects costs a millisecond, not 10,000 canvas calls.
 */
function drawMap() {
  const t0 = performance.now();
  const map = $('minimap');
  const ctx = map.getContext('2d');
  const w = map.width;
  const h = map.height;
  if (!state.map || state.map.scene !== state.scene) state.map = { scene: state.scene, ...mapLayout(w, h) };
  const layout = state.map;
  if (!layout.objects) return;
  const view = currentView();
  const frustum = frustumOf(view);
  const visible = state.link?.visible ?? new Set();
  const pixels = new Uint32Array(layout.image.data.buffer);
  pixels.fill(0);
  const paint = (o, colour) => {
    for (let y = o.y0; y <= o.y1; y++) {
      const row = y * w;
      for (let x = o.x0; x <= o.x1; x++) {
        if (!o.big || y === o.y0 || y === o.y1 || x === o.x0 || x === o.x1) pixels[row + x] = colour;
      }
    }
  };
  // Culled first, the visible set on top.
  for (const o of layout.objects) {
    if (!visible.has(o.id)) paint(o, frustum.intersectsBox(o.box) ? MAP_COLOURS.occluded : MAP_COLOURS.outside);
  }
  for (const o of layout.objects) if (visible.has(o.id)) paint(o, MAP_COLOURS.visible);
  ctx.putImageData(layout.image, 0, 0);
  const { px, py, span } = layout;
  const e = state.pose.eye;
  const half = Math.atan(Math.tan((view.fov_y_deg * Math.PI) / 360) * view.aspect);
  const reach = Math.min(view.far, span * 1.5);
  ctx.strokeStyle = '#f6e05e';
  ctx.beginPath();
  for (const side of [-1, 1]) {
    const a = state.pose.yaw + side * half;
    ctx.moveTo(px(e[0]), py(e[2]));
    ctx.lineTo(px(e[0] + Math.cos(a) * reach), py(e[2] + Math.sin(a) * reach));
  }
  ctx.stroke();
  ctx.fillStyle = '#f6e05e';
  ctx.fillRect(px(e[0]) - 2, py(e[2]) - 2, 4, 4);
  ctx.fillStyle = '#90cdf4';
  for (const [, pose] of state.poses) ctx.fillRect(px(pose.eye[0]) - 2, py(pose.eye[2]) - 2, 4, 4);
  state.mapMs = performance.now() - t0;
}

// -------------------------------------------------------------- avatars

const AVATAR = { half: 0.25, below: 1.7, above: 0.1 }; // DESIGN: 0.5 × 1.8 × 0.5 m under the eye

const avatarShape = new THREE.BoxGeometry(AVATAR.half * 2, AVATAR.below + AVATAR.above, AVATAR.half * 2);
const avatarLook = new THREE.MeshLambertMaterial({ color: 0x3182ce, emissive: 0x102040 });

function placeAvatars() {
  // One shape and one material for all: boxes come and go every frame.
  avatars.clear();
  for (const user of state.usersVisible) {
    const pose = state.poses.get(user);
    if (!pose) continue;
    const m = new THREE.Mesh(avatarShape, avatarLook);
    const e = pose.eye.map((v, i) => v - state.origin[i]);
    m.position.set(e[0], e[1] - (AVATAR.below - AVATAR.above) / 2, e[2]);
    m.name = user;
    avatars.add(m);
  }
}

async function pollWalkthrough() {
  if (!state.walkthrough) return;
  try {
    const info = await getJson(`/walkthroughs/${state.walkthrough}`);
    state.poses = new Map(info.users.filter((u) => u.pose && u.user !== state.link?.user).map((u) => [u.user, u.pose]));
    placeAvatars();
  } catch (e) {
    report(e.message, false);
  }
}

// ------------------------------------------------------------- the frames

function onFrame(frame, latency) {
  // A new session after the first (a reconnect, or a reload rebound this
  // one) starts over: what is held may be of another version of the scene.
  const startedOver = frame.base === null && state.lastFrame !== null;
  state.lastFrame = frame;
  if (latency !== null) {
    state.latency.push(latency);
    if (state.latency.length > 120) state.latency.shift();
  }
  state.usersVisible = frame.users ?? [];
  const fetchAndDraw = () => {
    const visible = state.link.visible;
    const wanted = $('draw').value === 'tinted' ? state.objects.map((o) => o.id) : [...visible];
    return state.geometry.want(wanted).then(() => {
      state.geometry.trim(visible);
      state.dirty = true;
    });
  };
  (startedOver ? readScene().then(fetchAndDraw) : fetchAndDraw()).catch((e) => report(e.message));
  if (state.walkthrough) placeAvatars();
  showHud();
  drawMap();
}

/**
 * The scene's origin (an empty batch is the origin alone) and objects, and
 * a fresh geometry store: at the start, and again when a session starts
 * over (a reload may have changed the scene).
 */
async function readScene() {
  const sid = encodeURIComponent(state.scene.id);
  state.geometry?.clear();
  state.geometry = new Geometry(state.scene.id, three, Number(params.get('budget') ?? 256 * 1024 * 1024));
  const head = await call(`/scenes/${sid}/meshes`, {
    method: 'POST', headers: { 'content-type': 'application/json' }, body: '{"ids":[]}',
  });
  state.origin = decodeMeshes(await head.arrayBuffer()).origin;
  state.objects = await getJson(`/scenes/${sid}/objects`);
  state.map = null;
}

/** Sends the current view; resolves once its answer is applied and its geometry held. */
async function ask() {
  await state.link.send(currentView());
  await state.geometry.want([...state.link.visible]);
  state.geometry.trim(state.link.visible);
}

// --------------------------------------------------------------- controls

const keys = new Set();
addEventListener('keydown', (e) => {
  if (e.target instanceof HTMLInputElement || e.target instanceof HTMLSelectElement) return;
  keys.add(e.key.toLowerCase());
  if (e.key === '+' || e.key === '=') state.speed *= 1.5;
  if (e.key === '-') state.speed /= 1.5;
});
addEventListener('keyup', (e) => keys.delete(e.key.toLowerCase()));
addEventListener('blur', () => keys.clear());

let drag = null;
canvas.addEventListener('pointerdown', (e) => {
  canvas.setPointerCapture(e.pointerId);
  const walking = e.pointerType === 'touch' && e.clientX < canvas.clientWidth / 2;
  drag = { id: e.pointerId, x: e.clientX, y: e.clientY, x0: e.clientX, y0: e.clientY, walking };
  canvas.focus();
});
canvas.addEventListener('pointermove', (e) => {
  if (!drag || drag.id !== e.pointerId) return;
  if (!drag.walking) {
    state.pose.yaw += (e.clientX - drag.x) * 0.004;
    state.pose.pitch = Math.max(-1.5, Math.min(1.5, state.pose.pitch - (e.clientY - drag.y) * 0.004));
    stopAutoWalk();
  }
  drag.x = e.clientX;
  drag.y = e.clientY;
  state.dirty = true;
});
const endDrag = () => { drag = null; };
canvas.addEventListener('pointerup', endDrag);
canvas.addEventListener('pointercancel', endDrag);

function move(dt) {
  let ahead = 0;
  let side = 0;
  let up = 0;
  if (keys.has('w') || keys.has('arrowup')) ahead += 1;
  if (keys.has('s') || keys.has('arrowdown')) ahead -= 1;
  if (keys.has('d') || keys.has('arrowright')) side += 1;
  if (keys.has('a') || keys.has('arrowleft')) side -= 1;
  if (keys.has('e')) up += 1;
  if (keys.has('q')) up -= 1;
  if (drag?.walking) {
    // The touch stick: up the screen walks ahead, sideways strafes.
    ahead -= (drag.y - drag.y0) / 60;
    side += (drag.x - drag.x0) / 60;
  }
  if (!ahead && !side && !up) return false;
  stopAutoWalk();
  const speed = state.speed * (keys.has('shift') ? 4 : 1) * dt;
  const y = state.pose.yaw;
  const e = state.pose.eye;
  e[0] += (Math.cos(y) * ahead - Math.sin(y) * side) * speed;
  e[2] += (Math.sin(y) * ahead + Math.cos(y) * side) * speed;
  e[1] += up * speed;
  return true;
}

function stopAutoWalk() {
  if (state.autoWalk) {
    clearInterval(state.autoWalk);
    state.autoWalk = null;
    $('walk').textContent = 'auto-walk';
  }
}

$('walk').addEventListener('click', () => {
  if (state.autoWalk) return stopAutoWalk();
  const views = state.walk?.views ?? [];
  if (!views.length) return report('this scene has no walk', false);
  let i = 0;
  $('walk').textContent = 'stop';
  state.autoWalk = setInterval(() => {
    const v = views[i++ % views.length];
    state.pose = poseFrom(v.eye, v.forward);
    state.dirty = true;
  }, 1000 / 30);
});

// ------------------------------------------------------------ the scenes

function fillMethods() {
  const select = $('method');
  const wanted = params.get('method') ?? select.value;
  select.replaceChildren();
  const methods = ['auto', ...state.scene.methods];
  for (const m of methods) select.add(new Option(m, m));
  for (const u of Object.keys(state.scene.unsupported ?? {})) {
    const o = new Option(`${u} (unsupported)`, u);
    o.disabled = true;
    o.title = state.scene.unsupported[u];
    select.add(o);
  }
  select.value = methods.includes(wanted) ? wanted : 'auto';
  showOptionHelp();
}

/** The options the picked method takes, as `GET /scenes` lists them. */
function showOptionHelp() {
  const keys = state.scene?.options?.[$('method').value] ?? [];
  $('option-help').textContent = keys.length ? `takes ${keys.join(', ')}` : 'takes no options';
  $('options').placeholder = keys.length ? keys.map((k) => `${k}=…`).join(':') : '';
}

/** Loads scene `id`: its origin, objects and walk, then a session. */
async function openScene(id, { method, options, walkthrough } = {}) {
  state.link?.stop();
  state.geometry?.clear();
  stopAutoWalk();
  const scene = state.scenes.find((s) => s.id === id);
  if (!scene) throw new Error(`the server has no scene '${id}'`);
  state.scene = scene;
  $('scene').value = id;
  fillMethods();
  if (method) $('method').value = method;
  if (options !== undefined) $('options').value = options;
  const sid = encodeURIComponent(id);
  await readScene();
  state.walk = null;
  for (const kind of ['street', 'orbit']) {
    try {
      state.walk = await getJson(`/scenes/${sid}/walk?kind=${kind}&frames=1800&step=0.2`);
      break;
    } catch (e) {
      if (e.status !== 422) throw e;
    }
  }
  const b = scene.bounds ?? { min: [0, 0, 0], max: [1, 1, 1] };
  const diagonal = Math.hypot(...b.max.map((v, i) => v - b.min[i])) || 1;
  state.near = Math.min(0.1, Math.max(1e-4, diagonal * 1e-5));
  state.far = diagonal * 4;
  state.speed = Math.min(20, Math.max(1, diagonal / 200));
  const start = state.walk?.views[0];
  if (params.has('eye') && params.has('forward')) {
    state.pose = poseFrom(params.get('eye').split(',').map(Number), params.get('forward').split(',').map(Number));
  } else if (start) {
    state.pose = poseFrom(start.eye, start.forward);
  } else {
    state.pose = poseFrom([b.max[0], b.max[1], b.max[2]], [-1, -0.5, -1]);
  }
  const optionText = $('options').value;
  const body = { scene: id, method: $('method').value, options: parseOptions(optionText) };
  state.walkthrough = walkthrough ?? null;
  const open = async () => {
    // With the scene and method, so that a walkthrough lost with its
    // replica is made again under its id when its users rejoin.
    if (state.walkthrough) return postJson(`/walkthroughs/${state.walkthrough}/users`, body);
    return postJson('/sessions', body);
  };
  state.lastFrame = null;
  state.link = new Link(open, onFrame, (m, fatal) => report(m, fatal !== false));
  await state.link.connect();
  state.latency = [];
  $('share').replaceChildren();
  if (state.walkthrough) showShare();
  history.replaceState(null, '', `/viewer?${new URLSearchParams({ scene: id, method: $('method').value,
    ...(optionText ? { options: optionText } : {}), ...(state.walkthrough ? { walkthrough: state.walkthrough } : {}),
    ...(params.has('test') ? { test: '1' } : {}) })}`);
  report('', false);
  await ask();
  state.dirty = true;
}

function showShare() {
  const url = `${location.origin}/viewer?scene=${encodeURIComponent(state.scene.id)}&walkthrough=${state.walkthrough}`;
  const a = document.createElement('a');
  a.href = url;
  a.target = '_blank';
  a.textContent = 'open this walkthrough in another tab';
  $('share').replaceChildren(a);
}

$('controls').addEventListener('submit', (e) => {
  e.preventDefault();
  openScene($('scene').value, { method: $('method').value, options: $('options').value })
    .catch((err) => report(err.message));
});
$('scene').addEventListener('change', () => {
  openScene($('scene').value, { method: $('method').value, options: '' }).catch((err) => report(err.message));
});
$('method').addEventListener('change', () => { $('options').value = ''; showOptionHelp(); });
$('draw').addEventListener('change', () => {
  if ($('draw').value !== 'visible') state.geometry?.want(state.objects.map((o) => o.id)).catch((e) => report(e.message));
  state.dirty = true;
});
$('together').addEventListener('click', async () => {
  try {
    const body = { scene: state.scene.id, method: $('method').value, options: parseOptions($('options').value) };
    const w = await postJson('/walkthroughs', body);
    await openScene(state.scene.id, { walkthrough: w.walkthrough });
  } catch (e) {
    report(e.message);
  }
});

// ------------------------------------------------------------- the loop

let last = performance.now();
let lastSent = null;
function loop(now) {
  const dt = Math.min(0.1, (now - last) / 1000);
  last = now;
  if (move(dt)) state.dirty = true;
  if (state.link && state.dirty) {
    const view = JSON.stringify(currentView());
    if (view !== lastSent && !state.link.inFlight) {
      lastSent = view;
      state.link.send(currentView());
    }
    render();
    state.dirty = false;
    showHud();
  }
  requestAnimationFrame(loop);
}

// --------------------------------------------------------- for scripted tests

/** Reads back a picture with every pixel's object id (0: none). */
function idPicture(only) {
  const w = renderer.domElement.width;
  const h = renderer.domElement.height;
  const target = new THREE.WebGLRenderTarget(w, h, { depthBuffer: true });
  const saved = avatars.visible;
  avatars.visible = false;
  for (const d of state.geometry.held.values()) {
    d.object.visible = only ? only.has(d.id) : true;
    d.object.material = Materials.id(d.id);
  }
  renderer.setClearColor(0x000000, 1);
  renderer.setRenderTarget(target);
  renderer.render(three, camera);
  const rgba = new Uint8Array(w * h * 4);
  renderer.readRenderTargetPixels(target, 0, 0, w, h, rgba);
  renderer.setRenderTarget(null);
  renderer.setClearColor(0x10141a, 1);
  target.dispose();
  avatars.visible = saved;
  const ids = new Uint32Array(w * h);
  for (let i = 0; i < w * h; i++) ids[i] = rgba[i * 4] | (rgba[i * 4 + 1] << 8) | (rgba[i * 4 + 2] << 16);
  return ids;
}

window.pvsd = {
  errors,
  hud,
  /** Opens `scene` with `method` and `options` (text, `k=32`), or joins `walkthrough`. */
  open: (scene, method, options = '', walkthrough) => openScene(scene, { method, options, walkthrough }),
  /** The scene's walk (GET /scenes/{id}/walk). */
  walk: () => state.walk,
  /** Moves to `view` ({eye, forward}, world), asks, and resolves once its answer and geometry are in. */
  async goTo(view) {
    stopAutoWalk();
    state.pose = poseFrom(view.eye, view.forward);
    lastSent = JSON.stringify(currentView());
    await ask();
    render();
    showHud();
    return hud();
  },
  /**
   * The same-picture check at the current view: every object drawn by its
   * id, once with every object of the scene and once with the visible set
   * alone (less the `drop` objects covering the most pixels, to show the
   * check fails when an answer drops one). Returns the pixels that differ
   * and the ids they show in the full picture.
   */
  async samePicture({ drop = 0, picture = false } = {}) {
    await state.geometry.want(state.objects.map((o) => o.id));
    placeCamera(currentView());
    const all = idPicture(null);
    const set = new Set(state.link.visible);
    if (drop > 0) {
      const counts = new Map();
      for (const v of all) {
        const id = (v & ~SEE_THROUGH) - 1;
        if (v && set.has(id)) counts.set(id, (counts.get(id) ?? 0) + 1);
      }
      [...counts].sort((a, b) => b[1] - a[1]).slice(0, drop).forEach(([id]) => set.delete(id));
    }
    const only = idPicture(set);
    let differing = 0;
    const missing = new Set();
    const seen = new Set();
    for (let i = 0; i < all.length; i++) {
      const id = (all[i] & ~SEE_THROUGH) - 1;
      if (all[i]) seen.add(id);
      if (all[i] !== only[i]) {
        differing += 1;
        if (all[i]) missing.add(id);
      }
    }
    state.geometry.trim(state.link.visible);
    render();
    // With `picture`, the full picture's ids too (id + 1 per pixel, bit 23
    // for see-through, bottom row first, as base64 of little-endian u32s),
    // to set beside pvsd's own.
    let ids;
    if (picture) {
      const bytes = new Uint8Array(all.buffer);
      let text = '';
      for (let i = 0; i < bytes.length; i += 8192) text += String.fromCharCode(...bytes.subarray(i, i + 8192));
      ids = btoa(text);
    }
    return { width: renderer.domElement.width, height: renderer.domElement.height, pixels: all.length,
      differing, missing: [...missing].sort((a, b) => a - b), seen: seen.size, pvs: state.link.visible.size, ids,
      view: currentView() };
  },
  /** Starts a walkthrough of this scene and method, as the button does; resolves with its id. */
  async together() {
    $('together').click();
    while (!state.link?.user || !state.link.frame) await new Promise((r) => setTimeout(r, 20));
    return state.walkthrough;
  },
  /** Draws with mode `visible`, `tinted` or `xray`. */
  async draw(mode) {
    $('draw').value = mode;
    if (mode !== 'visible') await state.geometry.want(state.objects.map((o) => o.id));
    render();
    drawMap();
  },
};

// ------------------------------------------------------------------ start

async function start() {
  state.scenes = await getJson('/scenes');
  if (!state.scenes.length) throw new Error('the server has no scenes');
  for (const s of state.scenes) $('scene').add(new Option(`${s.id} (${s.objects} objects)`, s.id));
  const wanted = params.get('scene');
  const id = state.scenes.some((s) => s.id === wanted) ? wanted : state.scenes[0].id;
  await openScene(id, {
    method: params.get('method') ?? undefined,
    options: params.get('options') ?? '',
    walkthrough: params.get('walkthrough') ?? undefined,
  });
  setInterval(pollWalkthrough, 250);
  requestAnimationFrame(loop);
}

window.pvsd.ready = start().then(() => true, (e) => { report(e.message); return false; });
