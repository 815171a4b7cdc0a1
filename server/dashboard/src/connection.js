// The dashboard's connection to one scene, without the DOM: the page
// (app.js) draws, this module speaks the protocol. Everything it needs from
// the browser is injected (the WebSocket constructor, a clock, timers), so
// `node --test` drives it with a fake socket (test/connection.test.mjs).
//
// - `Connection` is one WebSocket: it sends Hello when the socket opens,
//   takes the Welcome (role, scene, an all-zero Lightmap of its layout),
//   applies keyframes and deltas (a delta only onto its exact base; on any
//   refused frame it asks for a keyframe with Resync and ignores deltas
//   until one arrives), keeps Stats, the last Poses and the last Lights
//   (its Hello asks for them with HELLO_POSES and HELLO_LIGHTS), server
//   errors and counters.
// - `Reconnector` keeps one Connection to a scene: when the socket closes
//   without the page asking, it dials again after a `Backoff` delay; it
//   gives up when the server refused this client for good (error
//   Unauthorized or Forbidden, or close code 1008).
//
// What the page shows is its business: each step reports through the `on`
// callbacks (all optional): `log(text, level)`, `state(conn)`,
// `welcome(conn, welcome)`, `poses(conn, poses)`, `lights(conn, lights)`,
// `applied(conn, frame, keyframe)`, `stats(conn, stats)`,
// `gaveUp(conn, closeEvent)`, `serverError(conn, error)`. `posesToApply`
// is the page's rule for which of a Poses message's entries to draw;
// `LightSeqs` its seqs for SetLight and which Lights entries to show.

import { ApplyError, Lightmap } from './lightmap.js';
import {
  DecodeError,
  HELLO_LIGHTS,
  HELLO_POSES,
  PROTOCOL_VERSION,
  decodeServer,
  encodeClient,
  errorName,
  nextSeq,
  seqIsNewer,
} from './protocol.js';

export const CLIENT_NAME = 'lightwire-dashboard/0.1';
/** What Hello asks for: Poses and Lights. */
export const HELLO_CAPABILITIES = HELLO_POSES | HELLO_LIGHTS;
/** Window of the versions/s and bytes/s rates. */
export const RATE_WINDOW_MS = 5000;
/** `WebSocket.OPEN`. */
const OPEN = 1;
/** Server error codes after which reconnecting cannot help (Unauthorized,
 * Forbidden). */
const FATAL_ERRORS = new Set([3, 4]);
/** Close code: policy violation (a refused token, a bad Origin). */
const CLOSE_POLICY = 1008;

/** The dashboard's reconnect delay: a fixed 2 s. (The native peers follow
 * `protocol/src/backoff.rs` instead: 0.1 s doubling to 5 s, jittered; pass
 * such a policy to `Backoff` to have the page do the same.) */
export const DASHBOARD_BACKOFF = Object.freeze({ initialMs: 2000, maxMs: 2000, factor: 1, jitter: 0 });

/** Reconnect delays: `initialMs`, multiplied by `factor` after each failed
 * attempt up to `maxMs`, each scaled by a random factor in
 * `[1 - jitter, 1 + jitter]`; `reset()` once a connection has delivered a
 * lightmap (the rule of `protocol/src/backoff.rs`). */
export class Backoff {
  constructor(policy = DASHBOARD_BACKOFF, random = Math.random) {
    this.policy = policy;
    this.random = random;
    this.attempts = 0;
  }

  /** The delay before the next attempt, in ms. */
  next() {
    const { initialMs, maxMs, factor, jitter } = this.policy;
    const base = Math.min(maxMs, initialMs * factor ** this.attempts);
    this.attempts++;
    return base * (1 + jitter * (2 * this.random() - 1));
  }

  reset() {
    this.attempts = 0;
  }
}

/**
 * The entries of a `Poses` message (`{ object, seq, pose }`) the page should
 * draw: all but those of an object the user holds (`held`: dragging it, or a
 * move queued and not yet sent) and those older, in serial-number order
 * (`seqIsNewer`), than the last Transform this page sent for the object
 * (`lastSentSeq`: object -> seq), so that the user's own move, not yet
 * reflected, does not jump back.
 * @param {Array<{object: number, seq: number, pose: object}>} poses
 * @param {Map<number, number>} lastSentSeq
 * @param {Set<number>} [held]
 * @returns {Array<{object: number, seq: number, pose: object}>}
 */
export function posesToApply(poses, lastSentSeq, held = new Set()) {
  return poses.filter(({ object, seq }) => {
    const sent = lastSentSeq.get(object);
    return !held.has(object) && (sent === undefined || !seqIsNewer(sent, seq));
  });
}

/**
 * The page's SetLight seqs and which light states to show. Seqs are per
 * light and shared by all drivers (PROTOCOL.md §1.7): the next seq for a
 * light is one past the newer, in serial-number order (`seqIsNewer`), of
 * the seq in the last `Lights` and the last seq this page sent for it.
 * `received` takes a Lights message's entries and returns those the page
 * should show: all but the lights whose last change from this page is not
 * reflected yet (so that the control does not jump back); `forget` stops
 * waiting for them (a refusal: the server's state is what holds).
 */
export class LightSeqs {
  constructor() {
    /** light -> seq of the last Lights. */
    this.latest = new Map();
    /** light -> last seq this page sent. */
    this.sent = new Map();
    /** light -> seq sent and not yet reflected by a Lights. */
    this.awaiting = new Map();
  }

  /** The seq of this page's next SetLight of `light`. */
  next(light) {
    const latest = this.latest.get(light) ?? 0;
    const sent = this.sent.get(light);
    const seq = nextSeq(sent !== undefined && seqIsNewer(sent, latest) ? sent : latest);
    this.sent.set(light, seq);
    this.awaiting.set(light, seq);
    return seq;
  }

  /**
   * @param {Array<{light: number, seq: number, state: object}>} lights
   * @returns {Array<{light: number, seq: number, state: object}>}
   */
  received(lights) {
    for (const { light, seq } of lights) {
      this.latest.set(light, seq);
      const waiting = this.awaiting.get(light);
      if (waiting !== undefined && !seqIsNewer(waiting, seq)) this.awaiting.delete(light);
    }
    return lights.filter(({ light }) => !this.awaiting.has(light));
  }

  forget() {
    this.awaiting.clear();
  }
}

/** The browser's clock and timers (node has the same globals). */
export const systemClock = Object.freeze({
  now: () => performance.now(),
  setTimeout: (f, ms) => setTimeout(f, ms),
  clearTimeout: (t) => clearTimeout(t),
});

/** The WebSocket URL of a scene, for a page served from `location`. */
export function sceneUrl(location, sceneId) {
  const scheme = location.protocol === 'https:' ? 'wss' : 'ws';
  return `${scheme}://${location.host}/ws/scenes/${encodeURIComponent(sceneId)}`;
}

/** One WebSocket to one scene; see the module comment. */
export class Connection {
  /**
   * @param {string} url the scene's WebSocket URL (`sceneUrl`)
   * @param {string|null} token presented in Hello, or none
   * @param {object} options `WebSocket` (constructor), `now()` (ms), `on`
   *   (callbacks; `closed(conn, event)` is the Reconnector's)
   */
  constructor(url, token, { WebSocket, now, on = {} }) {
    this.token = token || null;
    this.now = now;
    this.on = on;
    this.state = 'connecting';
    this.role = null;
    /** `Welcome.capabilities` (CAP_LIGHTS: SetLight is followed). */
    this.capabilities = 0;
    this.scene = null;
    this.map = null;
    this.awaitingKeyframe = true;
    this.closedByUs = false;
    this.fatal = false;
    this.counters = { frames: 0, keyframes: 0, deltas: 0, resyncs: 0, stats: 0, poses: 0, lights: 0, decodeErrors: 0, errors: 0 };
    this.errors = [];
    this.received = []; // [time ms, bytes]
    this.versions = []; // [time ms, server version] from Stats
    this.reflected = {};
    /** The last Poses, `{ version, poses }`, or null. */
    this.poses = null;
    /** The last Lights, `{ version, lights }`, or null. */
    this.lights = null;
    this.lastStats = null;
    this.ws = new WebSocket(url);
    this.ws.binaryType = 'arraybuffer';
    this.ws.onopen = () => this.send({ type: 'Hello', protocol_version: PROTOCOL_VERSION, client: CLIENT_NAME, token: this.token, capabilities: HELLO_CAPABILITIES });
    this.ws.onmessage = (e) => this.receive(e.data);
    this.ws.onclose = (e) => this.closed(e);
  }

  log(text, level = 'info') {
    this.on.log?.(text, level);
  }

  send(message) {
    if (this.ws.readyState === OPEN) this.ws.send(encodeClient(message));
  }

  close() {
    this.closedByUs = true;
    this.ws.close(1000);
  }

  receive(data) {
    if (!(data instanceof ArrayBuffer)) {
      this.log('the server sent a text frame; ignored', 'warn');
      return;
    }
    this.received.push([this.now(), data.byteLength]);
    this.counters.frames++;
    let message;
    try {
      message = decodeServer(data);
    } catch (e) {
      if (!(e instanceof DecodeError)) throw e;
      this.counters.decodeErrors++;
      this.log(`undecodable frame: ${e.message}`, 'warn');
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
      case 'Poses':
        this.takePoses(message);
        break;
      case 'Lights':
        this.takeLights(message);
        break;
      case 'Error': {
        const name = errorName(message.code);
        this.counters.errors++;
        this.errors.push(`${name}: ${message.message}`);
        this.log(`server error ${name} (${message.code}): ${message.message}`, 'warn');
        if (FATAL_ERRORS.has(message.code)) this.fatal = true;
        this.on.serverError?.(this, message);
        break;
      }
      default:
        break;
    }
  }

  welcome(w) {
    if (this.scene) {
      this.log('a second Welcome; ignored', 'warn');
      return;
    }
    this.role = w.role;
    this.capabilities = w.capabilities;
    this.scene = w.scene;
    try {
      this.map = Lightmap.forScene(w.scene);
    } catch (e) {
      this.log(`cannot hold this scene's lightmap: ${e.message}`, 'error');
      this.fatal = true;
      this.close();
      return;
    }
    this.state = 'connected';
    this.on.welcome?.(this, w);
    this.log(`connected to ${w.scene.id} as ${w.role} (${w.server}); atlas ${w.scene.atlas_width}x${w.scene.atlas_height}, ${w.scene.surfaces.length} surfaces`);
    this.on.state?.(this);
  }

  apply(frame, keyframe) {
    if (!this.map) {
      this.log('a lightmap frame before Welcome; ignored', 'warn');
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
      this.log(`${keyframe ? 'keyframe' : 'delta'} not applied (${e.message}); asking for a keyframe`, e.kind === 'wrong-base' ? 'info' : 'warn');
      this.counters.resyncs++;
      this.awaitingKeyframe = true;
      this.send({ type: 'Resync', have_version: this.map.version || null });
      return;
    }
    for (const { object, seq } of frame.reflected) this.reflected[object] = seq;
    this.on.applied?.(this, frame, keyframe);
  }

  /** Where the dynamic objects are in the version that follows. */
  takePoses(p) {
    if (!this.scene) {
      this.log('Poses before Welcome; ignored', 'warn');
      return;
    }
    this.counters.poses++;
    this.poses = { version: p.version, poses: p.poses };
    this.on.poses?.(this, p);
  }

  /** The lights' states in the version that follows. */
  takeLights(l) {
    if (!this.scene) {
      this.log('Lights before Welcome; ignored', 'warn');
      return;
    }
    this.counters.lights++;
    this.lights = { version: l.version, lights: l.lights };
    this.on.lights?.(this, l);
  }

  stats(s) {
    this.counters.stats++;
    this.lastStats = s;
    this.versions.push([this.now(), s.version]);
    this.on.stats?.(this, s);
  }

  closed(e) {
    this.state = 'closed';
    this.on.closed?.(this, e);
  }

  /** [versions per second, bytes per second] over the last RATE_WINDOW_MS. */
  rates() {
    const now = this.now();
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

/** Keeps one Connection to a scene open; see the module comment. */
export class Reconnector {
  /**
   * @param {object} options `url`, `token`, `WebSocket` (constructor;
   *   the global one by default), `clock` ({ now, setTimeout, clearTimeout };
   *   `systemClock` by default), `backoff` (a `Backoff`; DASHBOARD_BACKOFF
   *   by default), `on` (the callbacks of the module comment)
   */
  constructor({ url, token, WebSocket = globalThis.WebSocket, clock = systemClock, backoff = new Backoff(), on = {} }) {
    this.url = url;
    this.token = token;
    this.WebSocket = WebSocket;
    this.clock = clock;
    this.backoff = backoff;
    this.on = on;
    /** The Connection in use (the latest one), or null before `start`. */
    this.current = null;
    this.timer = null;
    this.stopped = false;
  }

  start() {
    this.stopped = false;
    this.open();
  }

  /** Closes the connection for good (no reconnect). */
  stop() {
    this.stopped = true;
    this.clock.clearTimeout(this.timer);
    this.timer = null;
    this.current?.close();
  }

  open() {
    this.timer = null;
    const on = {
      ...this.on,
      applied: (conn, frame, keyframe) => {
        // A connection that delivered a lightmap: the next outage starts
        // from the short delay again.
        if (keyframe) this.backoff.reset();
        this.on.applied?.(conn, frame, keyframe);
      },
      closed: (conn, e) => this.closed(conn, e),
    };
    this.current = new Connection(this.url, this.token, { WebSocket: this.WebSocket, now: this.clock.now, on });
    this.on.state?.(this.current);
  }

  closed(conn, e) {
    if (conn !== this.current || this.stopped) return;
    this.on.state?.(conn);
    if (conn.closedByUs) return;
    const why = e.reason ? `: ${e.reason}` : '';
    if (conn.fatal || e.code === CLOSE_POLICY) {
      this.on.log?.(`disconnected (${e.code}${why}); press Connect to retry`, 'warn');
      this.on.gaveUp?.(conn, e);
      return;
    }
    const delay = this.backoff.next();
    this.on.log?.(`disconnected (${e.code}${why}); reconnecting in ${+(delay / 1000).toFixed(1)} s`, 'warn');
    this.clock.clearTimeout(this.timer);
    this.timer = this.clock.setTimeout(() => this.open(), delay);
  }
}
