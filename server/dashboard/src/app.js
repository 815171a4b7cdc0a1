// The dashboard: one WebSocket per watched scene, speaking the binary
// protocol (protocol.js), holding the lightmap (lightmap.js), and showing it
// as an atlas tone-mapped with the one tone curve (tone.js) and a 3D view
// (view3d.js) next to live statistics (chart.js).
//
// Data flow: frames arrive -> decoded -> keyframes/deltas applied to the
// Lightmap (deltas only onto their exact base, else Resync) and Stats pushed
// to the charts; each animation frame then redraws whatever changed. A
// driver's drags become Transform frames, at most one per object every
// TRANSFORM_PERIOD_MS (the server allows 120/s), each with a fresh seq.
//
// `window.lightwire` exposes a read-only snapshot for tests and the console.

import { Chart } from './chart.js';
import { ApplyError, Lightmap } from './lightmap.js';
import { DecodeError, PROTOCOL_VERSION, decodeServer, encodeClient, errorName, poseProblem } from './protocol.js';
import { ToneTable, whitePoint } from './tone.js';
import { View3D, quatMul, quatYaw } from './view3d.js';

const CLIENT_NAME = 'lightwire-dashboard/0.1';
/** Smallest gap between two Transforms for one object. */
const TRANSFORM_PERIOD_MS = 33;
/** Window of the versions/s and bytes/s rates. */
const RATE_WINDOW_MS = 5000;
/** Floor of the log-scale convergence chart (0 = converged is drawn here). */
const UNSHOT_FLOOR = 1e-6;

const $ = (id) => document.getElementById(id);

const ui = {
  scene: $('scene'),
  token: $('token'),
  connect: $('connect'),
  status: $('status'),
  role: $('role'),
  view: $('view'),
  atlas: $('atlas'),
  exposure: $('exposure'),
  exposureValue: $('exposure-value'),
  autoExposure: $('auto-exposure'),
  drive: $('drive'),
  driveHint: $('drive-hint'),
  object: $('object'),
  x: $('pose-x'),
  z: $('pose-z'),
  yaw: $('pose-yaw'),
  reset: $('pose-reset'),
  log: $('log'),
  renderer: $('renderer'),
};

const stat = (name) => document.querySelector(`[data-stat="${name}"]`);

function logEvent(text, level = 'info') {
  const li = document.createElement('li');
  li.className = level;
  li.textContent = `${new Date().toLocaleTimeString()} ${text}`;
  ui.log.prepend(li);
  while (ui.log.children.length > 60) ui.log.lastChild.remove();
}

// --- Charts -----------------------------------------------------------------

const convergence = new Chart($('chart-unshot'), {
  series: [{ name: 'unshot / emitted', color: '#f0b429' }],
  log: true,
  min: UNSHOT_FLOOR,
});
const timings = new Chart($('chart-timings'), {
  series: [
    { name: 'tick', color: '#62b0e8' },
    { name: 'solve', color: '#8bd17c' },
    { name: 'redistribution', color: '#e8776f' },
  ],
  unit: ' ms',
});

// --- 3D view ----------------------------------------------------------------

let view = null;
try {
  view = new View3D(ui.view, { onDrag: (object, pose) => driver.move(object, pose, 'drag') });
  ui.renderer.textContent = view.renderer;
} catch (e) {
  ui.view.replaceWith(Object.assign(document.createElement('p'), { className: 'error', textContent: `3D view unavailable: ${e.message}` }));
  logEvent(`3D view unavailable: ${e.message}`, 'error');
}

// --- Atlas view and exposure ----------------------------------------------

const atlasCtx = ui.atlas.getContext('2d');
let atlasImage = null;
/** The white point of the lightmap held (tone.js: the 95th percentile of
 * covered texels' luminance, the rule of `lightwire bake`). */
let autoWhite = 1;

/** The exposure: 1 / white point, times the slider's 2^EV. */
function exposure() {
  return 2 ** Number(ui.exposure.value) / autoWhite;
}

function drawAtlas() {
  const map = conn?.map;
  if (!map) return;
  if (ui.atlas.width !== map.width || ui.atlas.height !== map.height || !atlasImage) {
    ui.atlas.width = map.width;
    ui.atlas.height = map.height;
    atlasImage = atlasCtx.createImageData(map.width, map.height);
  }
  const tone = new ToneTable(exposure());
  const px = atlasImage.data;
  const rgb = map.rgb;
  for (let i = 0, j = 0; i < rgb.length; i += 3, j += 4) {
    px[j] = tone.byte(rgb[i]);
    px[j + 1] = tone.byte(rgb[i + 1]);
    px[j + 2] = tone.byte(rgb[i + 2]);
    px[j + 3] = 255;
  }
  atlasCtx.putImageData(atlasImage, 0, 0);
}

function exposureChanged() {
  ui.exposureValue.textContent = `${Number(ui.exposure.value) >= 0 ? '+' : ''}${Number(ui.exposure.value).toFixed(1)} EV`;
  dirty.atlas = true;
  view?.setExposure(exposure());
}
ui.exposure.addEventListener('input', exposureChanged);
ui.autoExposure.addEventListener('change', () => {
  if (ui.autoExposure.checked && conn?.map) autoWhite = whitePoint(conn.map.rgb);
  exposureChanged();
});

// --- Connection -------------------------------------------------------------

const dirty = { atlas: false, texture: false };
/** The current connection, or null. */
let conn = null;
let reconnectTimer = null;

class Connection {
  constructor(sceneId, token) {
    this.sceneId = sceneId;
    this.token = token || null;
    this.state = 'connecting';
    this.role = null;
    this.scene = null;
    this.map = null;
    this.awaitingKeyframe = true;
    this.closedByUs = false;
    this.fatal = false;
    this.counters = { frames: 0, keyframes: 0, deltas: 0, resyncs: 0, stats: 0, decodeErrors: 0, errors: 0 };
    this.errors = [];
    this.received = []; // [time ms, bytes]
    this.versions = []; // [time ms, server version] from Stats
    this.reflected = {};
    this.lastStats = null;
    const scheme = location.protocol === 'https:' ? 'wss' : 'ws';
    this.ws = new WebSocket(`${scheme}://${location.host}/ws/scenes/${encodeURIComponent(sceneId)}`);
    this.ws.binaryType = 'arraybuffer';
    this.ws.onopen = () => this.send({ type: 'Hello', protocol_version: PROTOCOL_VERSION, client: CLIENT_NAME, token: this.token, capabilities: 0 });
    this.ws.onmessage = (e) => this.receive(e.data);
    this.ws.onclose = (e) => this.closed(e);
  }

  send(message) {
    if (this.ws.readyState === WebSocket.OPEN) this.ws.send(encodeClient(message));
  }

  close() {
    this.closedByUs = true;
    this.ws.close(1000);
  }

  receive(data) {
    if (!(data instanceof ArrayBuffer)) {
      logEvent('the server sent a text frame; ignored', 'warn');
      return;
    }
    const now = performance.now();
    this.received.push([now, data.byteLength]);
    this.counters.frames++;
    let message;
    try {
      message = decodeServer(data);
    } catch (e) {
      if (!(e instanceof DecodeError)) throw e;
      this.counters.decodeErrors++;
      logEvent(`undecodable frame: ${e.message}`, 'warn');
      return;
    }
    switch (message.type) {
      case 'Welcome':
        this.welcome(message);
        break;
      case 'Keyframe':
        this.apply(message, true);
        break;
      case 'Delta':
        this.apply(message, false);
        break;
      case 'Stats':
        this.stats(message);
        break;
      case 'Error': {
        const name = errorName(message.code);
        this.counters.errors++;
        this.errors.push(`${name}: ${message.message}`);
        logEvent(`server error ${name} (${message.code}): ${message.message}`, 'warn');
        if (message.code === 3 || message.code === 4) this.fatal = true;
        break;
      }
      case 'Pong':
        break;
      default:
        break;
    }
  }

  welcome(w) {
    if (this.scene) {
      logEvent('a second Welcome; ignored', 'warn');
      return;
    }
    this.role = w.role;
    this.scene = w.scene;
    try {
      this.map = Lightmap.forScene(w.scene);
    } catch (e) {
      logEvent(`cannot hold this scene's lightmap: ${e.message}`, 'error');
      this.fatal = true;
      this.close();
      return;
    }
    this.state = 'connected';
    atlasImage = null;
    convergence.clear();
    timings.clear();
    view?.setScene(w.scene);
    driver.setScene(w.scene, w.role);
    logEvent(`connected to ${w.scene.id} as ${w.role} (${w.server}); atlas ${w.scene.atlas_width}x${w.scene.atlas_height}, ${w.scene.surfaces.length} surfaces`);
    updateStatus();
  }

  apply(frame, keyframe) {
    if (!this.map) {
      logEvent('a lightmap frame before Welcome; ignored', 'warn');
      return;
    }
    if (!keyframe && this.awaitingKeyframe) return;
    try {
      if (keyframe) {
        this.map.applyKeyframe(frame);
        this.counters.keyframes++;
        this.awaitingKeyframe = false;
      } else {
        this.map.applyDelta(frame);
        this.counters.deltas++;
      }
    } catch (e) {
      if (!(e instanceof ApplyError)) throw e;
      // Either way we no longer hold a version the server can build on.
      logEvent(`${keyframe ? 'keyframe' : 'delta'} not applied (${e.message}); asking for a keyframe`, e.kind === 'wrong-base' ? 'info' : 'warn');
      this.counters.resyncs++;
      this.awaitingKeyframe = true;
      this.send({ type: 'Resync', have_version: this.map.version || null });
      return;
    }
    const now = performance.now();
    for (const { object, seq } of frame.reflected) {
      this.reflected[object] = seq;
      driver.reflected(object, seq, now);
    }
    if (keyframe || ui.autoExposure.checked) {
      if (ui.autoExposure.checked || autoWhite === 1) autoWhite = whitePoint(this.map.rgb);
      view?.setExposure(exposure());
    }
    dirty.atlas = true;
    dirty.texture = true;
  }

  stats(s) {
    this.counters.stats++;
    this.lastStats = s;
    const t = s.server_time_us / 1e6;
    convergence.push(t, [Math.max(s.unshot_fraction, 0)]);
    timings.push(t, [s.tick_ms, s.solve_ms, s.redistribution_ms]);
    this.versions.push([performance.now(), s.version]);
    updateNumbers();
  }

  closed(e) {
    this.state = 'closed';
    if (conn !== this) return;
    updateStatus();
    if (this.closedByUs) return;
    const why = e.reason ? `: ${e.reason}` : '';
    if (this.fatal || e.code === 1008) {
      ui.driveHint.textContent = `Not connected (${e.code}${why}).`;
      logEvent(`disconnected (${e.code}${why}); press Connect to retry`, 'warn');
      return;
    }
    logEvent(`disconnected (${e.code}${why}); reconnecting in 2 s`, 'warn');
    clearTimeout(reconnectTimer);
    reconnectTimer = setTimeout(() => connect(), 2000);
  }

  /** [versions per second, bytes per second] over the last RATE_WINDOW_MS. */
  rates() {
    const now = performance.now();
    const since = now - RATE_WINDOW_MS;
    while (this.received.length && this.received[0][0] < since) this.received.shift();
    while (this.versions.length > 2 && this.versions[0][0] < since) this.versions.shift();
    const span = this.received.length ? Math.max(1000, now - this.received[0][0]) : RATE_WINDOW_MS;
    const bytes = this.received.reduce((sum, [, n]) => sum + n, 0) / (span / 1000);
    let versions = 0;
    if (this.versions.length >= 2) {
      const [t0, v0] = this.versions[0];
      const [t1, v1] = this.versions[this.versions.length - 1];
      if (t1 > t0) versions = ((v1 - v0) * 1000) / (t1 - t0);
    }
    return [versions, bytes];
  }
}

// --- Driving dynamic objects ----------------------------------------------

const driver = {
  scene: null,
  canDrive: false,
  initial: [],
  pending: new Map(), // object -> pose waiting to be sent
  lastSent: new Map(), // object -> time ms
  timer: null,
  seq: 0,
  sentAt: new Map(), // seq -> time ms
  lastSentSeq: 0,
  latencyMs: null,

  setScene(scene, role) {
    this.scene = scene;
    this.canDrive = role === 'Driver' || role === 'Admin';
    this.initial = scene.objects.map((o) => structuredClone(o.pose));
    this.pending.clear();
    ui.object.replaceChildren();
    scene.objects.forEach((o, i) => {
      if (o.dynamic) ui.object.append(new Option(o.name, String(i)));
    });
    const dynamic = ui.object.options.length > 0;
    ui.drive.disabled = !(this.canDrive && dynamic);
    if (view) view.draggable = this.canDrive;
    ui.driveHint.textContent = !dynamic
      ? 'This scene has no dynamic object.'
      : this.canDrive
        ? 'Drag the outlined object in the 3D view to slide it, shift-drag to turn it; or use the sliders.'
        : `Your role (${role}) may watch but not move objects: connect with a driver token.`;
    this.syncSliders();
  },

  selected() {
    return Number(ui.object.value);
  },

  /** Slider ranges and values from the selected object's pose. */
  syncSliders() {
    const i = this.selected();
    const pose = view?.pose(i) ?? this.scene?.objects[i]?.pose;
    if (!pose) return;
    if (view?.bounds) {
      const range = view.translationRange(i);
      [ui.x.min, ui.x.max] = range.x;
      [ui.z.min, ui.z.max] = range.z;
      ui.x.step = ui.z.step = Math.max(range.x[1] - range.x[0], range.z[1] - range.z[0], 1e-3) / 200;
    }
    ui.x.value = pose.translation[0];
    ui.z.value = pose.translation[2];
    const q0 = this.initial[i].rotation;
    const rel = quatMul(pose.rotation, [-q0[0], -q0[1], -q0[2], q0[3]]);
    ui.yaw.value = ((2 * Math.atan2(rel[1], rel[3]) * 180) / Math.PI).toFixed(0);
  },

  fromSliders() {
    const i = this.selected();
    const current = view?.pose(i) ?? this.initial[i];
    const yaw = (Number(ui.yaw.value) * Math.PI) / 180;
    const pose = {
      translation: [Number(ui.x.value), current.translation[1], Number(ui.z.value)],
      rotation: quatMul(quatYaw(yaw), this.initial[i].rotation),
      scale: current.scale,
    };
    view?.setPose(i, pose);
    this.move(i, pose, 'slider');
  },

  /** Queues a pose for an object; sent at most every TRANSFORM_PERIOD_MS. */
  move(object, pose, source) {
    if (!this.canDrive) return;
    const problem = poseProblem(pose);
    if (problem) {
      logEvent(`not sending pose: ${problem}`, 'warn');
      return;
    }
    this.pending.set(object, pose);
    if (source === 'drag' && object === this.selected()) this.syncSliders();
    this.flush();
  },

  flush() {
    if (this.timer) return;
    const now = performance.now();
    for (const [object, pose] of this.pending) {
      const wait = (this.lastSent.get(object) ?? -Infinity) + TRANSFORM_PERIOD_MS - now;
      if (wait > 0) {
        this.timer = setTimeout(() => {
          this.timer = null;
          this.flush();
        }, wait);
        return;
      }
      this.pending.delete(object);
      this.lastSent.set(object, now);
      // Seqs must grow per object across connections and clients; the
      // wall clock in microseconds does (and the latest move wins).
      this.seq = Math.max(this.seq + 1, Date.now() * 1000);
      this.sentAt.set(this.seq, now);
      if (this.sentAt.size > 256) this.sentAt.delete(this.sentAt.keys().next().value);
      this.lastSentSeq = this.seq;
      conn?.send({ type: 'Transform', object, seq: this.seq, pose, client_time_us: Date.now() * 1000 });
    }
  },

  /** A published version reflects `seq`: measure transform-to-light latency. */
  reflected(object, seq, now) {
    const sent = this.sentAt.get(seq);
    if (sent !== undefined) {
      this.latencyMs = now - sent;
      updateNumbers();
    }
  },
};

ui.object.addEventListener('change', () => driver.syncSliders());
for (const input of [ui.x, ui.z, ui.yaw]) input.addEventListener('input', () => driver.fromSliders());
ui.reset.addEventListener('click', () => {
  const i = driver.selected();
  if (!driver.initial[i]) return;
  view?.setPose(i, driver.initial[i]);
  driver.move(i, driver.initial[i], 'reset');
  driver.syncSliders();
});

// --- Status and numbers -----------------------------------------------------

function updateStatus() {
  const state = conn?.state ?? 'idle';
  ui.status.textContent = state;
  ui.status.dataset.state = state;
  ui.role.textContent = conn?.role ? conn.role : '';
}

const fmt = (v, digits = 1) => (Number.isFinite(v) ? v.toFixed(digits) : '–');

function bytesText(b) {
  if (b >= 1e6) return `${(b / 1e6).toFixed(2)} MB/s`;
  if (b >= 1e3) return `${(b / 1e3).toFixed(1)} kB/s`;
  return `${b.toFixed(0)} B/s`;
}

function updateNumbers() {
  const s = conn?.lastStats;
  const [versions, bytes] = conn ? conn.rates() : [0, 0];
  stat('version').textContent = conn?.map ? `${conn.map.version}` : '–';
  stat('unshot').textContent = s ? (s.unshot_fraction > 0 ? s.unshot_fraction.toExponential(2) : '0 (converged)') : '–';
  stat('tick').textContent = s ? `${fmt(s.tick_ms)} ms` : '–';
  stat('solve').textContent = s ? `${fmt(s.solve_ms)} ms` : '–';
  stat('redistribution').textContent = s ? `${fmt(s.redistribution_ms)} ms` : '–';
  stat('versions').textContent = fmt(versions, 2);
  stat('clients').textContent = s ? `${s.clients}` : '–';
  stat('bytes').textContent = bytesText(bytes);
  stat('latency').textContent = driver.latencyMs === null ? '–' : `${driver.latencyMs.toFixed(0)} ms`;
}

// --- Scenes and connecting ----------------------------------------------------

function connect() {
  clearTimeout(reconnectTimer);
  if (conn) {
    const old = conn;
    conn = null;
    old.close();
  }
  const id = ui.scene.value;
  if (!id) return;
  const params = new URLSearchParams(location.search);
  params.set('scene', id);
  // The token stays in the field, not in the address bar (history, screenshots).
  params.delete('token');
  history.replaceState(null, '', `?${params}`);
  conn = new Connection(id, ui.token.value.trim());
  updateStatus();
}

/** Headers that present the token field's token to the REST API, which
 * asks for the same token as the WebSocket (none in development mode). */
function authHeaders() {
  const token = ui.token.value.trim();
  return token ? { Authorization: `Bearer ${token}` } : {};
}

async function loadScenes() {
  const response = await fetch('/api/scenes', { headers: authHeaders() });
  if (!response.ok) {
    const body = await response.json().catch(() => null);
    const why = body?.error ? `: ${body.error}` : '';
    throw new Error(`GET /api/scenes: HTTP ${response.status}${why}`);
  }
  const scenes = await response.json();
  // A relay knows no element count: it holds the lightmap, not the mesh.
  const label = (s) => (s.elements == null ? s.id : `${s.id} (${s.elements} elements)`);
  ui.scene.replaceChildren(...scenes.map((s) => new Option(label(s), s.id)));
  const wanted = new URLSearchParams(location.search).get('scene');
  if (wanted && scenes.some((s) => s.id === wanted)) ui.scene.value = wanted;
  if (!scenes.length) logEvent('the server serves no scene', 'warn');
}

/** Lists the scenes (with the token in the field), then connects. */
function start() {
  loadScenes()
    .then(connect)
    .catch((e) => logEvent(`cannot list scenes: ${e.message}`, 'error'));
}

ui.scene.addEventListener('change', connect);
// Without a list yet (e.g. no token was given), Connect lists first.
ui.connect.addEventListener('click', () => (ui.scene.options.length ? connect() : start()));
ui.token.value = new URLSearchParams(location.search).get('token') ?? '';

// --- Frame loop ---------------------------------------------------------------

function frame() {
  if (dirty.texture && conn?.map && view) {
    view.uploadLightmap(conn.map);
    dirty.texture = false;
  }
  if (dirty.atlas) {
    drawAtlas();
    dirty.atlas = false;
  }
  convergence.draw();
  timings.draw();
  view?.draw();
  requestAnimationFrame(frame);
}

setInterval(updateNumbers, 1000);
setInterval(() => conn?.send({ type: 'Ping', nonce: Date.now() }), 15000);

window.lightwire = {
  /** Plain data about the connection and what is on screen. */
  snapshot() {
    return {
      state: conn?.state ?? 'idle',
      role: conn?.role ?? null,
      scene: conn?.scene?.id ?? null,
      version: conn?.map?.version ?? 0,
      counters: conn ? { ...conn.counters } : null,
      errors: conn ? [...conn.errors] : [],
      chartPoints: convergence.points.length,
      reflected: conn ? { ...conn.reflected } : {},
      lastSentSeq: driver.lastSentSeq,
      latencyMs: driver.latencyMs,
      renderer: view?.renderer ?? null,
      framesDrawn: view?.framesDrawn ?? 0,
      hasLightmap: !!view?.hasLightmap,
      dynamicObjects: conn?.scene ? conn.scene.objects.flatMap((o, i) => (o.dynamic ? [i] : [])) : [],
    };
  },
  /** Client coordinates of an object's centre in the 3D view. */
  objectScreenPoint(index) {
    return view?.screenPoint(index) ?? null;
  },
};

exposureChanged();
updateStatus();
requestAnimationFrame(frame);
start();
