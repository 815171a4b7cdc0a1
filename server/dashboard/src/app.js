// The dashboard: one WebSocket per watched scene (connection.js, which
// speaks the binary protocol of protocol.js and holds the lightmap of
// lightmap.js), shown as an atlas tone-mapped with the one tone curve
// (tone.js) and a 3D view (view3d.js) next to live statistics (chart.js).
//
// Data flow: frames arrive -> decoded -> keyframes/deltas applied to the
// Lightmap (deltas only onto their exact base, else Resync) and Stats pushed
// to the charts, all in connection.js, which reports each step to the
// callbacks here; each animation frame then redraws whatever changed. A
// driver's drags become Transform frames, at most one per object every
// TRANSFORM_PERIOD_MS (the server allows 120/s), each with a fresh seq.
// Poses (asked for in Hello) move the dynamic objects to where each
// version's light was computed for them, once that version's lightmap is
// applied, except the user's own moves that the server has not reflected
// yet (`posesToApply`).
//
// The scene's lights (SceneInfo.lights, protocol version 4) are listed with
// an on/off toggle, an intensity and a colour control, and a sun (a
// directional light) with a time-of-day slider (its path through the day
// is gizmos.js's `sunPath`), showing the states of the latest Lights (asked
// for in Hello). A driver may also drag a point or spot light's gizmo in
// the 3D view to move the light. A driver's changes become SetLight frames
// carrying the light's whole state, at most one per light every
// TRANSFORM_PERIOD_MS (the server's rate limit counts transforms and
// SetLights together), each with the next seq of `LightSeqs`: one past the
// last Lights' seq for the light, or past this page's own newer one. The
// controls wait for the first Lights (which tells the seqs), and stay
// disabled for a viewer or on a server without CAP_LIGHTS (an older
// server, or a relay whose upstream lacks it; a relay of a solver that
// follows lights announces CAP_LIGHTS and forwards SetLight upstream).
//
// The 3D view draws the scene's lights as gizmos (gizmos.js), fetched once
// per watched scene from `GET /api/scenes/{id}/lights` when the scene list
// counts any (a solver's; a relay holds none to give), where the states
// shown in the Lights panel put them. The same reply gives each light's
// scene file state (`file`), which the intensity slider's scale and a
// sun's day path are anchored on (gizmos.js's `lightAnchor`), so that every
// page agrees whenever it connected; where there is none (a relay), they
// are anchored on the Welcome's states, which are the scene file's only
// until a driver changes a light.
//
// `window.lightwire` exposes a read-only snapshot for tests and the console.

import { Chart } from './chart.js';
import { Backoff, DASHBOARD_BACKOFF, LightSeqs, Reconnector, posesToApply, sceneUrl } from './connection.js';
import { lightAnchor, lightsPath, sunHour, timeOfDay } from './gizmos.js';
import { CAP_LIGHTS, PROTOCOL_VERSION, lightProblem, poseProblem } from './protocol.js';
import { ToneTable, srgbEncode, whitePoint } from './tone.js';
import { View3D, quatMul, quatYaw } from './view3d.js';

/** Smallest gap between two Transforms for one object (and between two
 * SetLights for one light). */
const TRANSFORM_PERIOD_MS = 33;
/** The intensity slider's range, in stops from the light's intensity in
 * the scene file (`lightAnchor`). */
const INTENSITY_STOPS = [-10, 6];
/** The largest intensity a SetLight may carry (PROTOCOL.md §4). */
const MAX_INTENSITY = 1e6;
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
  showLights: $('show-lights'),
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
  lights: $('light-controls'),
  lightsHint: $('lights-hint'),
  lightList: $('light-list'),
  log: $('log'),
  renderer: $('renderer'),
  protocolVersion: $('protocol-version'),
};

// The footer names the version this page speaks, from the code that speaks
// it (protocol.js, checked against the Rust crate's golden vectors).
ui.protocolVersion.textContent = String(PROTOCOL_VERSION);

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
  view = new View3D(ui.view, {
    onDrag: (object, pose) => driver.move(object, pose, 'drag'),
    onLightDrag: (light, position) => lights.change(light, { position }),
  });
  ui.renderer.textContent = view.renderer;
} catch (e) {
  ui.view.replaceWith(Object.assign(document.createElement('p'), { className: 'error', textContent: `3D view unavailable: ${e.message}` }));
  logEvent(`3D view unavailable: ${e.message}`, 'error');
}

ui.showLights.addEventListener('change', () => view?.setShowLights(ui.showLights.checked));

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
  const map = conn()?.map;
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
  const map = conn()?.map;
  if (ui.autoExposure.checked && map) autoWhite = whitePoint(map.rgb);
  exposureChanged();
});

// --- Connection -------------------------------------------------------------

const dirty = { atlas: false, texture: false };
/** The Reconnector of the watched scene, or null. */
let link = null;
/** The current connection (connection.js), or null. */
const conn = () => link?.current ?? null;

/** What the page does at each step of the connection. */
const events = {
  log: logEvent,
  state: () => updateStatus(),
  welcome(_conn, w) {
    atlasImage = null;
    convergence.clear();
    timings.clear();
    view?.setScene(w.scene);
    driver.setScene(w.scene, w.role);
    lights.setScene(w.scene, w.role, w.capabilities);
  },
  lights(_conn, l) {
    lights.received(l.lights);
  },
  poses(_conn, p) {
    // Drawn with the lightmap they were lit for, once it is applied.
    driver.pendingPoses = p;
  },
  applied(c, frame, keyframe) {
    const now = performance.now();
    for (const { object, seq } of frame.reflected) driver.reflected(object, seq, now);
    const poses = driver.pendingPoses;
    if (poses && poses.version <= c.map.version) {
      driver.pendingPoses = null;
      driver.posesArrived(poses.poses);
    }
    if (keyframe || ui.autoExposure.checked) {
      if (ui.autoExposure.checked || autoWhite === 1) autoWhite = whitePoint(c.map.rgb);
      view?.setExposure(exposure());
    }
    dirty.atlas = true;
    dirty.texture = true;
  },
  stats(_conn, s) {
    const t = s.server_time_us / 1e6;
    convergence.push(t, [Math.max(s.unshot_fraction, 0)]);
    timings.push(t, [s.tick_ms, s.solve_ms, s.redistribution_ms]);
    updateNumbers();
  },
  serverError(c, _e) {
    // A refused transform leaves the server at an older pose than the page
    // shows: stop waiting for it to be reflected and draw the server's.
    driver.sentSeq.clear();
    if (c.poses) driver.posesArrived(c.poses.poses);
    // Likewise a refused SetLight: show the server's light states.
    lights.seqs.forget();
    if (c.lights) lights.received(c.lights.lights);
  },
  gaveUp(_conn, e) {
    const why = e.reason ? `: ${e.reason}` : '';
    ui.driveHint.textContent = `Not connected (${e.code}${why}).`;
    ui.lights.disabled = true;
    ui.lightsHint.textContent = ui.driveHint.textContent;
  },
};

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
  sentSeq: new Map(), // object -> last seq sent on this connection
  pendingPoses: null, // the last Poses, until the lightmap of its version is applied
  latencyMs: null,

  setScene(scene, role) {
    this.scene = scene;
    this.canDrive = role === 'Driver' || role === 'Admin';
    this.initial = scene.objects.map((o) => structuredClone(o.pose));
    this.pending.clear();
    this.sentSeq.clear();
    this.pendingPoses = null;
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
      this.sentSeq.set(object, this.seq);
      conn()?.send({ type: 'Transform', object, seq: this.seq, pose, client_time_us: Date.now() * 1000 });
    }
  },

  /** Draws a Poses message's objects where the server has them, but for
   * the user's own moves not yet reflected (`posesToApply`). */
  posesArrived(poses) {
    if (!view) return;
    const held = new Set(this.pending.keys());
    if (view.drag?.object !== undefined) held.add(view.drag.object);
    const apply = posesToApply(poses, this.sentSeq, held);
    for (const { object, pose } of apply) view.setPose(object, pose);
    if (apply.some(({ object }) => object === this.selected())) this.syncSliders();
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

// --- Lights -------------------------------------------------------------------

/** The sRGB transfer's inverse (tone.js has the forward one). */
const srgbDecode = (s) => (s <= 0.04045 ? s / 12.92 : ((s + 0.055) / 1.055) ** 2.4);
const clamp01 = (v) => Math.min(Math.max(v, 0), 1);
/** A linear RGB colour as an `<input type="color">` value. */
const colorHex = (rgb) => `#${rgb.map((c) => Math.round(srgbEncode(clamp01(c)) * 255).toString(16).padStart(2, '0')).join('')}`;
/** An `<input type="color">` value as a linear RGB colour. */
const hexColor = (hex) => [1, 3, 5].map((i) => clamp01(srgbDecode(parseInt(hex.slice(i, i + 2), 16) / 255)));

/** An hour (0 to 24) as a clock time, `hh:mm`. */
function clockText(hour) {
  const minutes = Math.round(hour * 60) % (24 * 60);
  return `${String(Math.floor(minutes / 60)).padStart(2, '0')}:${String(minutes % 60).padStart(2, '0')}`;
}

function intensityText(v, kind) {
  const unit = kind === 'Directional' ? 'W/m²' : 'W/sr';
  return `${v >= 100 ? v.toFixed(0) : v.toPrecision(3)} ${unit}`;
}

const lights = {
  scene: null,
  role: null,
  canDrive: false,
  /** The server follows SetLight (CAP_LIGHTS). */
  follows: false,
  /** A Lights arrived on this connection: the seqs are known. */
  known: false,
  /** Per light: its row's controls, the intensity of the slider's 0 stop
   * and, for a sun, its path through the day (`lightAnchor`: from the
   * scene file's state in `entries`, else from this connection's Welcome,
   * which tells the lights as they are then). */
  rows: [],
  /** The lights route's reply for scene `id` (`list`: its entries, with
   * each light's scene file state, `file`), or null: not fetched (yet), or
   * a relay, which has no such route. */
  entries: null,
  /** Per light: the state shown (the latest Lights', or this page's change). */
  states: [],
  seqs: new LightSeqs(),
  pending: new Map(), // light -> state waiting to be sent
  lastSent: new Map(), // light -> time ms
  timer: null,

  setScene(scene, role, capabilities) {
    this.scene = scene;
    this.role = role;
    this.canDrive = role === 'Driver' || role === 'Admin';
    this.follows = (capabilities & CAP_LIGHTS) !== 0;
    this.known = false;
    this.seqs = new LightSeqs();
    this.pending.clear();
    clearTimeout(this.timer);
    this.timer = null;
    this.states = scene.lights.map((l) => structuredClone(l.state));
    this.rows = scene.lights.map((l, i) => this.row(l, i));
    ui.lightList.replaceChildren(...this.rows.map((r) => r.li));
    this.states.forEach((_, i) => this.draw(i));
    view?.setLightStates(this.states);
    this.enable();
  },

  /** The controls of light `i`. */
  row(light, i) {
    const li = document.createElement('li');
    const on = Object.assign(document.createElement('input'), { type: 'checkbox' });
    on.setAttribute('aria-label', `${light.name} on`);
    const name = Object.assign(document.createElement('label'), { className: 'name' });
    name.append(on, ` ${light.name}`);
    const kind = Object.assign(document.createElement('span'), { className: 'kind', textContent: light.kind.toLowerCase() });
    const intensity = Object.assign(document.createElement('input'), {
      type: 'range',
      min: String(INTENSITY_STOPS[0]),
      max: String(INTENSITY_STOPS[1]),
      step: '0.1',
    });
    intensity.setAttribute('aria-label', `${light.name} intensity`);
    const value = document.createElement('output');
    const color = Object.assign(document.createElement('input'), { type: 'color' });
    color.setAttribute('aria-label', `${light.name} colour`);
    li.append(name, kind, intensity, value, color);
    on.addEventListener('change', () => this.change(i, { on: on.checked }));
    intensity.addEventListener('input', () => {
      const v = Math.min(r.reference * 2 ** Number(intensity.value), MAX_INTENSITY);
      value.textContent = intensityText(v, light.kind);
      this.change(i, { intensity: v });
    });
    color.addEventListener('input', () => this.change(i, { color: hexColor(color.value) }));
    const r = { li, on, intensity, value, color, kind: light.kind, ...lightAnchor(light, this.entry(i)) };
    if (r.path) {
      r.hour = Object.assign(document.createElement('input'), { type: 'range', min: '0', max: '24', step: '0.25' });
      r.hour.setAttribute('aria-label', `${light.name} time of day`);
      r.clock = document.createElement('output');
      const day = Object.assign(document.createElement('label'), { className: 'day' });
      day.append(Object.assign(document.createElement('span'), { textContent: 'time of day' }), r.hour, r.clock);
      li.append(day);
      r.hour.addEventListener('input', () => {
        const hour = Number(r.hour.value);
        r.clock.textContent = clockText(hour);
        // The whole state at that hour (the sun goes off as it sets, on as it rises).
        const state = timeOfDay(r.path, hour, this.states[i]);
        this.change(i, { direction: state.direction, on: state.on });
        r.on.checked = this.states[i].on;
      });
    }
    return r;
  },

  /** The lights route's entry of light `i` of the scene shown, if the
   * route has answered for that scene. */
  entry(i) {
    return this.scene && this.entries?.id === this.scene.id ? this.entries.list[i] : undefined;
  },

  /** The lights route's entries `list` of scene `id` (null: none): the
   * sliders are anchored on the scene file's states from now on, on the
   * Welcome's where there are none. */
  setEntries(id, list) {
    this.entries = list ? { id, list } : null;
    if (!this.scene) return;
    this.scene.lights.forEach((light, i) => {
      Object.assign(this.rows[i], lightAnchor(light, this.entry(i)));
      this.draw(i);
    });
  },

  /** Light `i`'s controls from its state. */
  draw(i) {
    const r = this.rows[i];
    const s = this.states[i];
    r.on.checked = s.on;
    r.intensity.value = s.intensity > 0 ? String(Math.log2(s.intensity / r.reference)) : String(INTENSITY_STOPS[0]);
    r.value.textContent = intensityText(s.intensity, r.kind);
    r.color.value = colorHex(s.color);
    if (r.hour) {
      const hour = sunHour(r.path, s.direction);
      r.hour.value = String(hour);
      r.clock.textContent = clockText(hour);
    }
  },

  enable() {
    const scene = this.scene;
    const any = scene.lights.length > 0;
    const changeable = any && this.canDrive && this.follows && this.known;
    ui.lights.disabled = !changeable;
    if (view) view.lightsDraggable = changeable;
    ui.lightsHint.textContent = !any
      ? 'This scene has no lights.'
      : !this.follows
        ? 'This server does not take light changes (no CAP_LIGHTS: an older server, or a relay whose upstream does not offer it); connect to a server that does, or to a relay of one, to change them.'
        : !this.canDrive
          ? `Your role (${this.role}) may watch but not change lights: connect with a driver token.`
          : this.known
            ? `Switch, dim or colour a light${this.rows.some((r) => r.path) ? ', set the sun\'s time of day' : ''}${
                scene.lights.some((l) => l.kind !== 'Directional') ? ', drag a light\'s gizmo in the 3D view to move it' : ''
              }; the lightmap follows.`
            : 'Waiting for the lights\' states…';
  },

  /** A Lights message's states: shown, but for this page's own changes
   * not reflected yet, those still queued and a light being dragged. */
  received(statuses) {
    for (const { light, state } of this.seqs.received(statuses)) {
      if (!this.rows[light] || this.pending.has(light) || view?.drag?.light === light) continue;
      this.states[light] = structuredClone(state);
      this.draw(light);
    }
    view?.setLightStates(this.states);
    if (!this.known) {
      this.known = true;
      this.enable();
    }
  },

  /** The user changed light `i`: its whole state, sent at most every
   * TRANSFORM_PERIOD_MS. */
  change(i, patch) {
    if (!(this.canDrive && this.follows && this.known)) return;
    const state = { ...this.states[i], ...patch };
    const problem = lightProblem(state);
    if (problem) {
      logEvent(`not sending light "${this.scene.lights[i].name}": ${problem}`, 'warn');
      this.draw(i);
      return;
    }
    this.states[i] = state;
    view?.setLightStates(this.states);
    this.pending.set(i, state);
    this.flush();
  },

  flush() {
    if (this.timer) return;
    const now = performance.now();
    for (const [light, state] of this.pending) {
      const wait = (this.lastSent.get(light) ?? -Infinity) + TRANSFORM_PERIOD_MS - now;
      if (wait > 0) {
        this.timer = setTimeout(() => {
          this.timer = null;
          this.flush();
        }, wait);
        return;
      }
      this.pending.delete(light);
      this.lastSent.set(light, now);
      conn()?.send({ type: 'SetLight', light, seq: this.seqs.next(light), state, client_time_us: Date.now() * 1000 });
    }
  },
};

// --- Status and numbers -----------------------------------------------------

function updateStatus() {
  const c = conn();
  const state = c?.state ?? 'idle';
  ui.status.textContent = state;
  ui.status.dataset.state = state;
  ui.role.textContent = c?.role ? c.role : '';
}

const fmt = (v, digits = 1) => (Number.isFinite(v) ? v.toFixed(digits) : '–');

function bytesText(b) {
  if (b >= 1e6) return `${(b / 1e6).toFixed(2)} MB/s`;
  if (b >= 1e3) return `${(b / 1e3).toFixed(1)} kB/s`;
  return `${b.toFixed(0)} B/s`;
}

function updateNumbers() {
  const c = conn();
  const s = c?.lastStats;
  const [versions, bytes] = c ? c.rates() : [0, 0];
  stat('version').textContent = c?.map ? `${c.map.version}` : '–';
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
  if (link) {
    link.stop();
    link = null;
  }
  const id = ui.scene.value;
  if (!id) return;
  const params = new URLSearchParams(location.search);
  params.set('scene', id);
  // The token stays in the field, not in the address bar (history, screenshots).
  params.delete('token');
  history.replaceState(null, '', `?${params}`);
  link = new Reconnector({
    url: sceneUrl(location, id),
    token: ui.token.value.trim(),
    backoff: new Backoff(DASHBOARD_BACKOFF),
    on: events,
  });
  link.start();
  loadLights(id).catch((e) => logEvent(`cannot load the lights of ${id}: ${e.message}`, 'warn'));
}

/** The scene list's entries by id (`GET /api/scenes`). */
let listed = new Map();

/** Fetches scene `id`'s lights for the 3D view's gizmos and the Lights
 * panel's anchors (their scene file states), if the scene list counts any
 * (a solver's; a relay has no lights route, and the panel is anchored on
 * its Welcome's states); a reply for a scene no longer watched is
 * dropped. */
async function loadLights(id) {
  view?.setLights([]);
  lights.setEntries(id, null);
  if (!(listed.get(id)?.lights > 0)) return;
  const response = await fetch(lightsPath(id), { headers: authHeaders() });
  if (!response.ok) {
    const body = await response.json().catch(() => null);
    throw new Error(`HTTP ${response.status}${body?.error ? `: ${body.error}` : ''}`);
  }
  const { lights: entries } = await response.json();
  if (ui.scene.value !== id) return;
  lights.setEntries(id, entries);
  if (!view) return;
  view.setLights(entries);
  logEvent(`${entries.length} light${entries.length === 1 ? '' : 's'} drawn as gizmos`);
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
  listed = new Map(scenes.map((s) => [s.id, s]));
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
  const c = conn();
  if (dirty.texture && c?.map && view) {
    view.uploadLightmap(c.map);
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
setInterval(() => conn()?.send({ type: 'Ping', nonce: Date.now() }), 15000);

window.lightwire = {
  /** Plain data about the connection and what is on screen. */
  snapshot() {
    const c = conn();
    return {
      state: c?.state ?? 'idle',
      role: c?.role ?? null,
      scene: c?.scene?.id ?? null,
      version: c?.map?.version ?? 0,
      counters: c ? { ...c.counters } : null,
      errors: c ? [...c.errors] : [],
      chartPoints: convergence.points.length,
      reflected: c ? { ...c.reflected } : {},
      poses: c?.poses ? structuredClone(c.poses) : null,
      lights: c?.lights ? structuredClone(c.lights) : null,
      lightControls: lights.rows.length,
      lightControlsEnabled: !ui.lights.disabled,
      lightStates: structuredClone(lights.states),
      lightAnchorsFromFile: lights.rows.map((r) => r.fromFile),
      lightSeqsSent: Object.fromEntries(lights.seqs.sent),
      lastSentSeq: driver.lastSentSeq,
      latencyMs: driver.latencyMs,
      renderer: view?.renderer ?? null,
      framesDrawn: view?.framesDrawn ?? 0,
      hasLightmap: !!view?.hasLightmap,
      lightGizmoSegments: view?.gizmoSegments() ?? 0,
      dynamicObjects: c?.scene ? c.scene.objects.flatMap((o, i) => (o.dynamic ? [i] : [])) : [],
    };
  },
  /** Client coordinates of an object's centre in the 3D view. */
  objectScreenPoint(index) {
    return view?.screenPoint(index) ?? null;
  },
  /** Client coordinates of a point or spot light in the 3D view. */
  lightScreenPoint(index) {
    return view?.lightScreenPoint(index) ?? null;
  },
  /** The mean radiosity (W/m², the three channels summed) over the atlas
   * rectangle of the surface named `name`, or null. */
  surfaceRadiosity(name) {
    const c = conn();
    const s = c?.scene?.surfaces.find((s) => s.name === name);
    if (!s || !c.map) return null;
    const [x0, y0, w, h] = s.rect;
    let sum = 0;
    for (let y = y0; y < y0 + h; y++) {
      for (let x = x0; x < x0 + w; x++) {
        const i = 3 * (y * c.map.width + x);
        sum += c.map.rgb[i] + c.map.rgb[i + 1] + c.map.rgb[i + 2];
      }
    }
    return sum / (w * h);
  },
};

exposureChanged();
updateStatus();
requestAnimationFrame(frame);
start();
