// Lightwire's stream drawn by a stock engine: three.js (vendored, pinned in
// package.json) loads the scene's glTF from the server and draws it lit by
// the lightmap the WebSocket streams, following every delta.
//
//   /examples/threejs/?scene=ID[&token=T]   (default: the first scene)
//
// The mapping:
//
// - Geometry: `GET /api/scenes/ID/scene.glb` (`bake::scene_glb`), one node
//   per scene object in the scene's object order, its lightmap UVs in
//   TEXCOORD_1, which GLTFLoader names `uv1`: three.js's texture channel 1.
//   The file also carries a tone-mapped PNG snapshot of the light as each
//   material's base colour (for viewers that know nothing of Lightwire);
//   this page drops it and draws the live stream instead. A solver's file
//   ends with the scene's lights (KHR_lights_punctual nodes after the
//   objects'); this page drops them too: the stream holds their light.
// - Light: the protocol's lightmap (`/dashboard/lightmap.js`, the
//   dashboard's decoder: keyframes, deltas onto their exact base, Resync)
//   is one DataTexture over the lightmap's own texel bytes, uploaded as
//   received (RGB9E5 words as `UnsignedInt5999Type`, WebGL2's RGB9_E5, or
//   RGBA16F as `HalfFloatType`), linear filtering, `channel = 1`, and set as
//   every material's `lightMap`. Each applied keyframe or delta rewrites
//   those bytes in place and sets `needsUpdate` (one upload per drawn frame).
// - Material: MeshBasicMaterial (what GLTFLoader makes of scene.glb's
//   unlit materials), white, `lightMapIntensity = π`, no lights in the
//   scene. The stream is radiosity B (W/m² per channel): the light leaving
//   the surface, albedo and emission already in it. MeshBasicMaterial
//   outputs lightMap × intensity / π × colour and nothing else, so it draws
//   B exactly. MeshLambertMaterial takes a lightMap for irradiance: it
//   multiplies it by the albedo / π and adds its emissive and the scene's
//   lights, so with the glTF's albedo and emission it would count both
//   twice (and with them zeroed it is a Basic material doing more work).
//   Emitters need nothing special: their B holds their emission, so they
//   are the brightest surfaces and saturate to white.
// - HDR to the screen: the project's one tone curve (`protocol/src/tone.rs`,
//   `/dashboard/tone.js`, also the dashboard's and `lightwire bake`'s PNGs),
//   y = 1 − exp(−B · k), as three.js's CustomToneMapping (its documented
//   hook: replace the CustomToneMapping stub of the tone-mapping shader
//   chunk) with k = `toneMappingExposure` = 1 / white point (the 95th
//   percentile of the lit texels' luminance, from the first keyframe and
//   then at most once a second); three.js then applies the sRGB transfer
//   (`outputColorSpace`), the curve's last step.
// - Dynamic objects: their nodes follow the server's `Poses` (asked for in
//   Hello), each applied with the lightmap version it was lit for.
// - Camera: OrbitControls about the scene's bounds, seen from +z; inside a
//   closed level, about its dynamic object (see `frameCamera`).
//
// Before the first keyframe the materials show a placeholder: a uniform
// grey lightmap (flat, no light). `?autoconnect=0` (for the browser test,
// `e2e/threejs.e2e.mjs`) draws the placeholder and waits for
// `window.lightwireExample.connect()`; `window.lightwireExample` also
// exposes plain data about what is drawn and `move()`, which sends a
// Transform (a driver's), for that test.

import * as THREE from 'three';
import { GLTFLoader } from 'three/examples/jsm/loaders/GLTFLoader.js';
import { OrbitControls } from 'three/examples/jsm/controls/OrbitControls.js';

import { Reconnector, sceneUrl } from '/dashboard/connection.js';
import { PROTOCOL_VERSION, sceneGlbPath } from '/dashboard/protocol.js';
import { exposureFor, whitePoint } from '/dashboard/tone.js';

/** The clear colour (style.css's background); the test counts pixels that
 * differ from it. */
const BACKGROUND = 0x12141a;
/** The placeholder's radiosity before any lightmap arrived. */
const PLACEHOLDER_RADIOSITY = 0.25;
/** The least time between two white-point updates after deltas. */
const WHITE_PERIOD_MS = 1000;

const params = new URLSearchParams(location.search);
const token = params.get('token') ?? '';
const statusLine = document.getElementById('status');

/** What the test (and the console) can read; see `snapshot()`. */
const state = {
  state: 'loading',
  protocol: PROTOCOL_VERSION,
  three: THREE.REVISION,
  scene: null,
  role: null,
  /** The lightmap version on screen (0: the placeholder). */
  version: 0,
  /** Frames rendered, and of them those drawn with the streamed lightmap. */
  frames: 0,
  litFrames: 0,
  keyframes: 0,
  deltas: 0,
  exposure: 1,
  /** Per object index: the pose drawn (dynamic objects only). */
  poses: {},
  /** Per object index: the newest transform seq the light reflects. */
  reflected: {},
  dynamicObjects: [],
  /** Where the camera was put: `{ inside, position, target }`. */
  camera: null,
  lastSentSeq: 0,
  errors: [],
  lightmapFormat: null,
};

function setStatus() {
  const scene = state.scene ?? '–';
  statusLine.textContent = `protocol v${state.protocol} · scene ${scene} · lightmap version ${state.version} · ${state.state}`;
  statusLine.classList.toggle('error', state.state.startsWith('error'));
}

function fail(message) {
  state.state = `error: ${message}`;
  state.errors.push(message);
  setStatus();
  console.error(`lightwire three.js example: ${message}`);
}

// --- Renderer, camera, tone curve ----------------------------------------------

// The one tone curve as three.js's custom tone mapping (see the top).
const STUB = 'vec3 CustomToneMapping( vec3 color ) { return color; }';
const CURVE = 'vec3 CustomToneMapping( vec3 color ) { return 1.0 - exp( -max( color, vec3( 0.0 ) ) * toneMappingExposure ); }';
const toneChunk = THREE.ShaderChunk.tonemapping_pars_fragment;
if (!toneChunk.includes(STUB)) throw new Error(`three.js r${THREE.REVISION} has no CustomToneMapping stub to replace`);
THREE.ShaderChunk.tonemapping_pars_fragment = toneChunk.replace(STUB, CURVE);

const container = document.getElementById('view');
// preserveDrawingBuffer: the browser test reads the canvas back.
const renderer = new THREE.WebGLRenderer({ antialias: true, preserveDrawingBuffer: true });
renderer.setPixelRatio(window.devicePixelRatio);
renderer.setClearColor(BACKGROUND);
renderer.toneMapping = THREE.CustomToneMapping;
renderer.toneMappingExposure = 1;
renderer.outputColorSpace = THREE.SRGBColorSpace;
container.append(renderer.domElement);

const camera = new THREE.PerspectiveCamera(45, 1, 0.01, 100);
const controls = new OrbitControls(camera, renderer.domElement);
const world = new THREE.Scene(); // no lights: the lightmap is all the light

let renderQueued = false;
/** Whether the lightmap's bytes changed since the last upload. */
let textureDirty = false;

function requestRender() {
  if (renderQueued) return;
  renderQueued = true;
  requestAnimationFrame(render);
}

function render() {
  renderQueued = false;
  if (textureDirty && streamTexture) {
    streamTexture.needsUpdate = true;
    textureDirty = false;
  }
  renderer.render(world, camera);
  state.frames++;
  if (lit) state.litFrames++;
}

function resize() {
  const { clientWidth: w, clientHeight: h } = container;
  renderer.setSize(w, h, false);
  camera.aspect = w / Math.max(1, h);
  camera.updateProjectionMatrix();
  requestRender();
}
window.addEventListener('resize', resize);
controls.addEventListener('change', requestRender);

/**
 * Frames the camera on `object`'s bounds: it looks at their centre from +z,
 * a little above, as the dashboard does (a scene's open side, e.g. the
 * Cornell box's, faces +z), from far enough to see them whole. A closed
 * level's outer walls would hide it, so when the way out from the centre
 * meets a surface facing it (a wall's inner face), the camera stays inside
 * instead: it looks down at the first dynamic object (else the centre)
 * from the side with the most room (of +z, +x, -z, -x), short of the wall
 * there, with a wider view.
 */
function frameCamera(object, dynamic) {
  object.updateMatrixWorld(true);
  const box = new THREE.Box3().setFromObject(object);
  const size = box.getSize(new THREE.Vector3()).length() || 1;
  let target = box.getCenter(new THREE.Vector3());
  let direction = new THREE.Vector3(0, Math.sin(0.12), Math.cos(0.12));
  let distance = size * 1.05;
  const room = (from, towards) => new THREE.Raycaster(from, towards, 0, distance).intersectObject(object, true)[0]?.distance ?? distance;
  const inside = room(target, direction) < distance;
  if (inside) {
    if (dynamic) target = new THREE.Box3().setFromObject(dynamic).getCenter(new THREE.Vector3());
    const pitch = 0.3;
    const sides = [0, 1, 2, 3].map((k) => new THREE.Vector3(Math.sin((k * Math.PI) / 2) * Math.cos(pitch), Math.sin(pitch), Math.cos((k * Math.PI) / 2) * Math.cos(pitch)));
    const free = sides.map((d) => room(target, d));
    const best = free.indexOf(Math.max(...free));
    direction = sides[best];
    distance = free[best] * 0.9;
    camera.fov = 65;
  }
  camera.position.copy(target).addScaledVector(direction, distance);
  camera.near = distance * 0.01;
  camera.far = distance + size * 2;
  camera.updateProjectionMatrix();
  controls.target.copy(target);
  controls.update();
  state.camera = { inside, position: camera.position.toArray(), target: target.toArray() };
}

// --- Lightmaps: the placeholder and the stream ------------------------------------

const placeholder = (() => {
  const h = THREE.DataUtils.toHalfFloat(PLACEHOLDER_RADIOSITY);
  const t = new THREE.DataTexture(new Uint16Array([h, h, h, THREE.DataUtils.toHalfFloat(1)]), 1, 1, THREE.RGBAFormat, THREE.HalfFloatType);
  t.channel = 1;
  t.colorSpace = THREE.LinearSRGBColorSpace;
  t.needsUpdate = true;
  return t;
})();

/** The materials that show the lightmap. */
const materials = new Set();
/** The DataTexture over the streamed lightmap's bytes, and that lightmap. */
let streamTexture = null;
let streamMap = null;
/** Whether the materials show the stream (a keyframe has arrived). */
let lit = false;
let whiteAt = -Infinity;

/** A DataTexture over `map.bytes` (connection.js's Lightmap), which the
 * decoder rewrites in place. */
function textureOf(map) {
  let t;
  if (map.format === 'Rgb9e5') {
    t = new THREE.DataTexture(new Uint32Array(map.bytes.buffer, map.bytes.byteOffset, map.bytes.length / 4), map.width, map.height, THREE.RGBFormat, THREE.UnsignedInt5999Type);
  } else {
    t = new THREE.DataTexture(new Uint16Array(map.bytes.buffer, map.bytes.byteOffset, map.bytes.length / 2), map.width, map.height, THREE.RGBAFormat, THREE.HalfFloatType);
  }
  t.channel = 1; // TEXCOORD_1
  t.colorSpace = THREE.LinearSRGBColorSpace; // linear radiosity, Rec. 709 primaries
  t.magFilter = THREE.LinearFilter;
  t.minFilter = THREE.LinearFilter;
  t.generateMipmaps = false;
  t.flipY = false; // v = 0 is the atlas's first row, as in glTF
  t.unpackAlignment = 4;
  t.needsUpdate = true;
  return t;
}

function showLightmap(texture) {
  for (const m of materials) m.lightMap = texture;
}

/** A lightmap version was applied to `map`. */
function lightmapChanged(map, keyframe) {
  if (map !== streamMap) {
    // A new connection holds a new Lightmap: a texture over its bytes.
    streamTexture?.dispose();
    streamMap = map;
    streamTexture = textureOf(map);
    state.lightmapFormat = map.format;
    showLightmap(streamTexture);
    lit = true;
  } else {
    textureDirty = true;
  }
  const now = performance.now();
  if (keyframe || now - whiteAt >= WHITE_PERIOD_MS) {
    whiteAt = now;
    state.exposure = exposureFor(whitePoint(map.rgb));
    renderer.toneMappingExposure = state.exposure;
  }
  state.version = map.version;
  setStatus();
  requestRender();
}

// --- The scene: glTF ----------------------------------------------------------

/** Per object index (SceneInfo order): its node, or undefined. */
let nodes = [];

function authHeaders() {
  return token ? { Authorization: `Bearer ${token}` } : {};
}

async function firstScene() {
  const r = await fetch('/api/scenes', { headers: authHeaders() });
  if (!r.ok) throw new Error(`GET /api/scenes: HTTP ${r.status}`);
  const scenes = await r.json();
  const wanted = params.get('scene');
  if (wanted) {
    if (!scenes.some((s) => s.id === wanted)) throw new Error(`the server serves no scene "${wanted}"`);
    return wanted;
  }
  if (!scenes.length) throw new Error('the server serves no scene');
  return scenes[0].id;
}

/** The scene's glTF, waiting while the server has no lightmap yet (503). */
async function fetchGlb(id) {
  for (;;) {
    const r = await fetch(sceneGlbPath(id), { headers: authHeaders() });
    if (r.ok) return r.arrayBuffer();
    if (r.status !== 503) throw new Error(`GET ${sceneGlbPath(id)}: HTTP ${r.status}`);
    state.state = 'waiting for the first lightmap';
    setStatus();
    await new Promise((done) => setTimeout(done, 2000));
  }
}

async function loadScene(id) {
  const gltf = await new GLTFLoader().parseAsync(await fetchGlb(id), '');
  // Node i is object i (`bake::scene_glb` writes one node per object, in
  // order, then one per light).
  nodes = [];
  const lights = [];
  gltf.scene.traverse((o) => {
    if (o.isLight) {
      lights.push(o);
      return;
    }
    const node = gltf.parser.associations.get(o)?.nodes;
    if (node !== undefined) nodes[node] = o;
    if (!o.isMesh) return;
    if (!o.geometry.getAttribute('uv1')) console.warn(`mesh "${o.name}" has no TEXCOORD_1: no light on it`);
    for (const m of Array.isArray(o.material) ? o.material : [o.material]) {
      if (materials.has(m)) continue;
      if (!m.isMeshBasicMaterial) {
        throw new Error(`material "${m.name}" is a ${m.type}, not the unlit MeshBasicMaterial scene.glb declares`);
      }
      // Drop the baked snapshot: only the stream lights the scene.
      m.map?.dispose();
      m.map = null;
      m.color.set(0xffffff);
      m.lightMap = placeholder;
      m.lightMapIntensity = Math.PI; // three.js divides a lightMap by π
      m.needsUpdate = true;
      materials.add(m);
    }
  });
  for (const light of lights) light.removeFromParent();
  // The dynamic objects where the file has them (its version's poses).
  nodes.forEach((o, i) => {
    if (o.userData.lightwire?.dynamic) {
      state.poses[i] = { translation: o.position.toArray(), rotation: o.quaternion.toArray(), scale: o.scale.x };
    }
  });
  world.add(gltf.scene);
  frameCamera(gltf.scene, nodes.find((o) => o?.userData.lightwire?.dynamic));
  return gltf;
}

// --- The stream ---------------------------------------------------------------

let link = null;
/** The Poses waiting for the lightmap version they were lit for. */
let pendingPoses = null;
let seq = 0;

const conn = () => link?.current ?? null;

function applyPoses(p) {
  for (const { object, pose } of p.poses) {
    const node = nodes[object];
    if (!node) continue;
    node.position.fromArray(pose.translation);
    node.quaternion.fromArray(pose.rotation);
    node.scale.setScalar(pose.scale);
    state.poses[object] = structuredClone(pose);
  }
  requestRender();
}

const events = {
  log(text, level) {
    // The decoder's refusals and reconnects: warnings, not page errors.
    (level === 'error' ? console.error : level === 'warn' ? console.warn : console.info)(text);
  },
  state(c) {
    if (c !== conn()) return;
    state.state = c.state;
    setStatus();
  },
  welcome(c, w) {
    state.scene = w.scene.id;
    state.role = w.role;
    state.dynamicObjects = w.scene.objects.flatMap((o, i) => (o.dynamic ? [i] : []));
    if (nodes.length !== w.scene.objects.length) {
      console.warn(`scene.glb has ${nodes.length} nodes, the scene ${w.scene.objects.length} objects`);
    }
    pendingPoses = null;
    setStatus();
  },
  poses(c, p) {
    // Drawn with the lightmap they were lit for, once it is applied.
    if (c.map && c.map.version >= p.version && !c.awaitingKeyframe) applyPoses(p);
    else pendingPoses = p;
  },
  applied(c, message, keyframe) {
    if (keyframe) state.keyframes++;
    else state.deltas++;
    for (const { object, seq: s } of message.reflected) state.reflected[object] = s;
    lightmapChanged(c.map, keyframe);
    if (pendingPoses && pendingPoses.version <= c.map.version) {
      applyPoses(pendingPoses);
      pendingPoses = null;
    }
  },
  serverError(_c, e) {
    state.errors.push(`server error ${e.code}: ${e.message}`);
  },
  gaveUp(_c, e) {
    fail(`disconnected for good (${e.code}${e.reason ? `: ${e.reason}` : ''})`);
  },
};

function connect() {
  if (link || !state.scene) return;
  link = new Reconnector({ url: sceneUrl(location, state.scene), token, on: events });
  link.start();
}

/** Projected bounds of object `index` on the canvas, in canvas pixels. */
function objectScreenRect(index) {
  const node = nodes[index];
  if (!node) return null;
  const box = new THREE.Box3().setFromObject(node);
  const { width, height } = renderer.domElement;
  let [x0, y0, x1, y1] = [Infinity, Infinity, -Infinity, -Infinity];
  for (let k = 0; k < 8; k++) {
    const p = new THREE.Vector3(k & 1 ? box.max.x : box.min.x, k & 2 ? box.max.y : box.min.y, k & 4 ? box.max.z : box.min.z);
    p.project(camera);
    const x = ((p.x + 1) / 2) * width;
    const y = ((1 - p.y) / 2) * height;
    [x0, y0, x1, y1] = [Math.min(x0, x), Math.min(y0, y), Math.max(x1, x), Math.max(y1, y)];
  }
  return { x0, y0, x1, y1 };
}

window.lightwireExample = {
  state,
  /** Plain data about the connection and what is drawn. */
  snapshot: () => structuredClone(state),
  /** Opens the WebSocket (done at once unless `?autoconnect=0`). */
  connect,
  /** Sends a Transform of object `object` to `pose` as a driver would; the
   * page still draws the object where the server's Poses say. Returns the
   * seq. */
  move(object, pose) {
    seq = Math.max(seq + 1, Date.now() * 1000);
    state.lastSentSeq = seq;
    conn()?.send({ type: 'Transform', object, seq, pose, client_time_us: Date.now() * 1000 });
    return seq;
  },
  objectScreenRect,
};

// --- Start ----------------------------------------------------------------------

setStatus();
resize();
try {
  state.scene = await firstScene();
  setStatus();
  await loadScene(state.scene);
  state.state = 'ready';
  setStatus();
  resize();
  if (params.get('autoconnect') !== '0') connect();
} catch (e) {
  fail(e.message);
}
