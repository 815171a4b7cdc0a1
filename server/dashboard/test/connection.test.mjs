// The dashboard's connection logic (src/connection.js) without a browser: a
// fake WebSocket and a fake clock drive it through the handshake, the
// golden keyframe and delta of protocol/tests/vectors/, a delta onto a wrong
// base (-> Resync), recorded zstd streams, the golden Poses and Lights,
// server errors and closes (-> reconnect after the backoff delay, or give
// up); and the page's rules for which poses to draw (`posesToApply`) and
// for its SetLight seqs (`LightSeqs`).

import assert from 'node:assert/strict';
import fs from 'node:fs';
import path from 'node:path';
import test from 'node:test';
import { fileURLToPath } from 'node:url';

import { Backoff, CLIENT_NAME, Connection, DASHBOARD_BACKOFF, LightSeqs, Reconnector, posesToApply, sceneUrl } from '../src/connection.js';
import { HELLO_LIGHTS, HELLO_POSES, PROTOCOL_VERSION, decodeClient, decodeServer, encodeServer } from '../src/protocol.js';

const here = path.dirname(fileURLToPath(import.meta.url));
const vectors = path.resolve(here, '../../../protocol/tests/vectors');
const bin = (name) => new Uint8Array(fs.readFileSync(path.join(vectors, `${name}.bin`)));
const sequences = JSON.parse(fs.readFileSync(path.join(vectors, 'sequences.json'), 'utf8'));
const fromHex = (hex) => Uint8Array.from(Buffer.from(hex, 'hex'));
const toHex = (bytes) => Buffer.from(bytes).toString('hex');

/** A WebSocket class whose instances the test drives by hand. */
function fakeWebSocket() {
  class FakeSocket {
    static OPEN = 1;
    static sockets = [];

    constructor(url) {
      this.url = url;
      this.readyState = 0;
      this.binaryType = 'blob';
      /** Client messages sent, decoded. */
      this.sent = [];
      this.closedWith = null;
      FakeSocket.sockets.push(this);
    }

    send(bytes) {
      assert.equal(this.readyState, 1, 'send on a socket that is not open');
      this.sent.push(decodeClient(bytes));
    }

    close(code) {
      this.closedWith = code;
      this.readyState = 2;
    }

    // --- what the server side does ---

    open() {
      this.readyState = 1;
      this.onopen?.({});
    }

    /** Delivers one binary frame (bytes, as the ArrayBuffer a browser gives). */
    deliver(bytes) {
      this.onmessage?.({ data: bytes.buffer.slice(bytes.byteOffset, bytes.byteOffset + bytes.byteLength) });
    }

    serverSends(message) {
      this.deliver(encodeServer(message));
    }

    drop(code, reason = '') {
      this.readyState = 3;
      this.onclose?.({ code, reason });
    }
  }
  return FakeSocket;
}

/** A clock whose time moves only when the test says so. */
function fakeClock() {
  let now = 0;
  let next = 1;
  const timers = new Map(); // id -> [due, fn, delay]
  return {
    timers,
    now: () => now,
    setTimeout(fn, ms) {
      const id = next++;
      timers.set(id, [now + ms, fn, ms]);
      return id;
    },
    clearTimeout(id) {
      timers.delete(id);
    },
    /** Delays of the timers pending. */
    pending() {
      return [...timers.values()].map(([, , ms]) => ms);
    },
    advance(ms) {
      now += ms;
      for (const [id, [due, fn]] of [...timers].sort((a, b) => a[1][0] - b[1][0])) {
        if (due <= now) {
          timers.delete(id);
          fn();
        }
      }
    },
  };
}

/** A Reconnector on fakes, with every callback recorded. */
function harness({ backoff = new Backoff(DASHBOARD_BACKOFF), token = 'secret' } = {}) {
  const WebSocket = fakeWebSocket();
  const clock = fakeClock();
  const calls = [];
  const logs = [];
  const on = {
    log: (text, level) => logs.push([level, text]),
    state: (c) => calls.push(['state', c.state]),
    welcome: (c, w) => calls.push(['welcome', w.scene.id]),
    applied: (c, frame, keyframe) => calls.push(['applied', keyframe ? 'keyframe' : 'delta', frame.version]),
    stats: (c, s) => calls.push(['stats', s.version]),
    poses: (c, p) => calls.push(['poses', p.version]),
    lights: (c, l) => calls.push(['lights', l.version]),
    gaveUp: (c, e) => calls.push(['gaveUp', e.code]),
  };
  const link = new Reconnector({ url: sceneUrl({ protocol: 'http:', host: 'example:8080' }, 'cornell box'), token, WebSocket, clock, backoff, on });
  link.start();
  const socket = () => WebSocket.sockets[WebSocket.sockets.length - 1];
  return { WebSocket, clock, calls, logs, link, socket };
}

/** The golden Welcome, keyframe (version 1) and delta (1 -> 2). */
const golden = () => ({
  welcome: bin('server_welcome'),
  keyframe: bin('server_keyframe'),
  delta: bin('server_delta'),
});

test('the handshake: the scene URL, then Hello with the protocol version, the client, the token, HELLO_POSES and HELLO_LIGHTS', () => {
  const { socket, link, calls } = harness();
  assert.equal(socket().url, 'ws://example:8080/ws/scenes/cornell%20box');
  assert.equal(socket().binaryType, 'arraybuffer');
  assert.equal(link.current.state, 'connecting');
  assert.deepEqual(calls, [['state', 'connecting']]);
  socket().open();
  assert.deepEqual(socket().sent, [{ type: 'Hello', protocol_version: PROTOCOL_VERSION, client: CLIENT_NAME, token: 'secret', capabilities: HELLO_POSES | HELLO_LIGHTS }]);
  assert.equal(sceneUrl({ protocol: 'https:', host: 'h' }, 'a/b'), 'wss://h/ws/scenes/a%2Fb');
});

test('no token: Hello carries none', () => {
  const { socket } = harness({ token: '' });
  socket().open();
  assert.equal(socket().sent[0].token, null);
});

test('Welcome, the golden keyframe, and a delta onto its exact base are applied', () => {
  const { socket, link, calls } = harness();
  const { welcome, keyframe, delta } = golden();
  socket().open();
  socket().deliver(welcome);
  const conn = link.current;
  assert.equal(conn.state, 'connected');
  assert.equal(conn.role, decodeServer(welcome).role);
  assert.equal(conn.map.version, 0);
  // A delta before the first keyframe has no base: ignored, no Resync.
  socket().deliver(delta);
  assert.equal(conn.map.version, 0);
  assert.equal(conn.counters.deltas, 0);
  assert.equal(conn.counters.resyncs, 0);
  socket().deliver(keyframe);
  assert.equal(conn.map.version, 1);
  assert.deepEqual(conn.map.texel(0, 0), [1, 0.5, 0.25]);
  socket().deliver(delta);
  assert.equal(conn.map.version, 2);
  assert.deepEqual(conn.map.texel(2, 0), [1, 1, 1]);
  assert.deepEqual(conn.map.texel(2, 1), [0, 0, 0]);
  assert.deepEqual(conn.counters, { frames: 4, keyframes: 1, deltas: 1, resyncs: 0, stats: 0, poses: 0, lights: 0, decodeErrors: 0, errors: 0 });
  // Only Hello went out: no Resync.
  assert.deepEqual(socket().sent.map((m) => m.type), ['Hello']);
  const welcomeId = decodeServer(welcome).scene.id;
  assert.deepEqual(calls, [
    ['state', 'connecting'],
    ['welcome', welcomeId],
    ['state', 'connected'],
    ['applied', 'keyframe', 1],
    ['applied', 'delta', 2],
  ]);
  // Objects whose transforms a version reflects are remembered.
  for (const { object, seq } of decodeServer(delta).reflected) assert.equal(conn.reflected[object], seq);
});

test('Poses are kept and reported, before the lightmap of their version; before Welcome they are ignored', () => {
  const { socket, link, calls, logs } = harness();
  const { welcome, keyframe, delta } = golden();
  const poses = decodeServer(bin('server_poses'));
  socket().open();
  socket().deliver(bin('server_poses'));
  const conn = link.current;
  assert.equal(conn.poses, null);
  assert.equal(conn.counters.poses, 0);
  assert.equal(logs.at(-1)[1], 'Poses before Welcome; ignored');
  socket().deliver(welcome);
  socket().deliver(keyframe);
  socket().deliver(bin('server_poses'));
  socket().deliver(delta);
  assert.deepEqual(conn.poses, { version: 2, poses: poses.poses });
  assert.equal(conn.counters.poses, 1);
  assert.deepEqual(calls.slice(-2), [
    ['poses', 2],
    ['applied', 'delta', 2],
  ]);
  assert.equal(conn.map.version, 2);
  assert.deepEqual(socket().sent.map((m) => m.type), ['Hello']);
});

test('Lights are kept and reported, before the lightmap of their version; before Welcome they are ignored', () => {
  const { socket, link, calls, logs } = harness();
  const { keyframe, delta } = golden();
  const lights = decodeServer(bin('server_lights'));
  socket().open();
  socket().deliver(bin('server_lights'));
  const conn = link.current;
  assert.equal(conn.lights, null);
  assert.equal(conn.counters.lights, 0);
  assert.equal(logs.at(-1)[1], 'Lights before Welcome; ignored');
  const welcome = decodeServer(bin('server_welcome_lights'));
  socket().deliver(bin('server_welcome_lights'));
  assert.equal(conn.capabilities, welcome.capabilities);
  socket().deliver(keyframe);
  socket().deliver(bin('server_lights'));
  socket().deliver(delta);
  assert.deepEqual(conn.lights, { version: 2, lights: lights.lights });
  assert.equal(conn.counters.lights, 1);
  assert.deepEqual(calls.slice(-2), [
    ['lights', 2],
    ['applied', 'delta', 2],
  ]);
  assert.equal(conn.map.version, 2);
  assert.deepEqual(socket().sent.map((m) => m.type), ['Hello']);
});

test('LightSeqs: one past the newer of the last Lights and what this page sent; its own unreflected changes are not shown', () => {
  const state = decodeServer(bin('server_lights')).lights[0].state;
  const status = (light, seq) => ({ light, seq, state });
  const seqs = new LightSeqs();
  // Before any Lights: from 0.
  assert.equal(seqs.next(0), 1);
  assert.equal(seqs.next(0), 2);
  // Another driver's seq 5 for light 0 overtakes this page's; light 1 untouched.
  assert.deepEqual(seqs.received([status(0, 5), status(1, 0)]), [status(0, 5), status(1, 0)]);
  assert.equal(seqs.next(0), 6);
  assert.equal(seqs.next(0), 7);
  // A Lights reflecting seq 6 only: light 0 still awaits 7 and is not shown.
  assert.deepEqual(seqs.received([status(0, 6), status(1, 0)]), [status(1, 0)]);
  assert.equal(seqs.next(0), 8, 'what this page sent is newer than the Lights');
  assert.deepEqual(seqs.received([status(0, 8), status(1, 0)]).map((l) => l.light), [0, 1]);
  // A refusal: stop waiting, show the server's state.
  assert.equal(seqs.next(1), 1);
  assert.deepEqual(seqs.received([status(0, 8), status(1, 0)]).map((l) => l.light), [0]);
  seqs.forget();
  assert.deepEqual(seqs.received([status(0, 8), status(1, 0)]).map((l) => l.light), [0, 1]);
  assert.equal(seqs.next(1), 2, 'seqs never go back');
  // The golden Lights: the lamp at seq 5 as the golden SetLight set it.
  const golden = new LightSeqs();
  golden.received(decodeServer(bin('server_lights')).lights);
  assert.equal(golden.next(0), decodeClient(bin('client_set_light')).seq + 1);
  assert.equal(golden.next(1), 1);
  // Serial-number order: after another driver's 2^64 - 1 comes 0, and a
  // Lights at 0 reflects it.
  const max = (1n << 64n) - 1n;
  const wrap = new LightSeqs();
  wrap.received([status(0, max)]);
  assert.equal(wrap.next(0), 0);
  assert.deepEqual(wrap.received([status(0, max)]), [], 'seq 0 is newer than 2^64 - 1: still awaited');
  assert.deepEqual(wrap.received([status(0, 0)]), [status(0, 0)]);
  assert.equal(wrap.next(0), 1);
});

test('posesToApply: all but held objects and those behind the last seq this page sent', () => {
  const pose = (x) => ({ translation: [x, 0, 0], rotation: [0, 0, 0, 1], scale: 1 });
  const poses = [
    { object: 0, seq: 0, pose: pose(0) }, // never moved by this page
    { object: 1, seq: 5, pose: pose(1) }, // behind this page's seq 9: skipped
    { object: 2, seq: 9, pose: pose(2) }, // reflects this page's seq 9
    { object: 3, seq: 12, pose: pose(3) }, // another driver's later move
    { object: 4, seq: 20, pose: pose(4) }, // held (dragging or queued): skipped
  ];
  const lastSentSeq = new Map([
    [1, 9],
    [2, 9],
    [3, 10],
    [4, 1],
  ]);
  assert.deepEqual(
    posesToApply(poses, lastSentSeq, new Set([4])).map((p) => p.object),
    [0, 2, 3],
  );
  assert.deepEqual(posesToApply(poses, new Map()), poses, 'nothing sent, nothing held: all of them');
  assert.deepEqual(posesToApply([], lastSentSeq), []);
  // The golden Poses (object 0 at seq 300) against a pending seq 301 and a reflected 300.
  const golden = decodeServer(bin('server_poses')).poses;
  assert.deepEqual(posesToApply(golden, new Map([[0, 301]])), []);
  assert.deepEqual(posesToApply(golden, new Map([[0, 300]])), golden);
  // Serial-number order: a pose at seq 0 reflects a move after 2^64 - 1,
  // and one at 2^64 - 1 is behind this page's seq 0.
  const max = (1n << 64n) - 1n;
  assert.equal(posesToApply([{ ...golden[0], seq: 0 }], new Map([[0, max]])).length, 1);
  assert.equal(posesToApply([{ ...golden[0], seq: max }], new Map([[0, 0]])).length, 0);
  assert.equal(posesToApply([{ ...golden[0], seq: max }], new Map()).length, 1, 'nothing sent: any seq');
});

test('a delta onto a wrong base asks for a keyframe with Resync, and deltas wait for it', () => {
  const { socket, link, logs } = harness();
  const { welcome, keyframe, delta } = golden();
  socket().open();
  socket().deliver(welcome);
  socket().deliver(keyframe);
  const conn = link.current;
  const d = decodeServer(delta);
  socket().serverSends({ ...d, base_version: 5, version: 6 });
  assert.equal(conn.map.version, 1, 'the wrong-base delta changed nothing');
  assert.equal(conn.counters.resyncs, 1);
  assert.deepEqual(socket().sent.at(-1), { type: 'Resync', have_version: 1 });
  assert.match(logs.at(-1)[1], /delta not applied \(delta 5 -> 6 does not apply to version 1\); asking for a keyframe/);
  assert.equal(logs.at(-1)[0], 'info');
  // Until a keyframe arrives, even a delta onto the version held is ignored.
  socket().deliver(delta);
  assert.equal(conn.map.version, 1);
  assert.equal(conn.counters.deltas, 0);
  socket().serverSends({ ...decodeServer(keyframe), version: 6 });
  assert.equal(conn.map.version, 6);
  socket().serverSends({ ...d, base_version: 6, version: 7 });
  assert.equal(conn.map.version, 7);
  assert.equal(conn.counters.deltas, 1);
  assert.equal(conn.counters.resyncs, 1);
});

test('a bad frame is refused with Resync too; without any version held, Resync has none', () => {
  const { socket, link, logs } = harness();
  const { welcome, keyframe } = golden();
  socket().open();
  socket().deliver(welcome);
  const kf = decodeServer(keyframe);
  socket().serverSends({ ...kf, tiles: [kf.tiles[0]] });
  assert.equal(link.current.map.version, 0);
  assert.deepEqual(socket().sent.at(-1), { type: 'Resync', have_version: null });
  assert.equal(logs.at(-1)[0], 'warn');
});

test('recorded zstd streams apply frame by frame to their final texels', () => {
  const welcome = decodeServer(bin('server_welcome'));
  for (const seq of sequences.sequences) {
    const { socket, link } = harness();
    socket().open();
    socket().serverSends({
      ...welcome,
      scene: { ...welcome.scene, atlas_width: seq.atlas_width, atlas_height: seq.atlas_height, tile_size: seq.tile_size, format: seq.format },
    });
    for (const hex of seq.frames) socket().deliver(fromHex(hex));
    const conn = link.current;
    assert.equal(conn.map.version, seq.final_version, seq.name);
    assert.equal(toHex(conn.map.bytes), seq.final_texels, seq.name);
    assert.equal(conn.counters.resyncs, 0, seq.name);
    assert.equal(conn.counters.deltas, seq.frames.length - 1, seq.name);
  }
});

test('Stats, server errors, undecodable and text frames', () => {
  const { socket, link, calls, logs } = harness();
  socket().open();
  const stats = decodeServer(bin('server_stats'));
  socket().deliver(bin('server_stats'));
  const conn = link.current;
  assert.equal(conn.counters.stats, 1);
  assert.deepEqual(conn.lastStats, stats);
  assert.deepEqual(calls.at(-1), ['stats', stats.version]);
  socket().deliver(Uint8Array.from([0xff, 0xff, 0xff]));
  assert.equal(conn.counters.decodeErrors, 1);
  assert.match(logs.at(-1)[1], /^undecodable frame: /);
  socket().onmessage({ data: 'hello' });
  assert.equal(logs.at(-1)[1], 'the server sent a text frame; ignored');
  const error = decodeServer(bin('server_error'));
  socket().deliver(bin('server_error'));
  assert.equal(conn.counters.errors, 1);
  assert.equal(conn.errors.length, 1);
  assert.ok(conn.errors[0].endsWith(`: ${error.message}`));
  assert.equal(conn.counters.frames, 3, 'text frames are not counted');
  // Rates over the window: 3 frames, no versions yet.
  const [versions, bytes] = conn.rates();
  assert.equal(versions, 0);
  assert.ok(bytes > 0);
});

test('a close the page did not ask for reconnects after the backoff delay, with a fresh connection', () => {
  const { socket, link, clock, logs, WebSocket } = harness();
  const { welcome, keyframe } = golden();
  socket().open();
  socket().deliver(welcome);
  socket().deliver(keyframe);
  const first = link.current;
  socket().drop(1006);
  assert.equal(first.state, 'closed');
  assert.deepEqual(clock.pending(), [2000], 'the dashboard waits a fixed 2 s');
  assert.deepEqual(logs.at(-1), ['warn', 'disconnected (1006); reconnecting in 2 s']);
  clock.advance(1999);
  assert.equal(WebSocket.sockets.length, 1);
  clock.advance(1);
  assert.equal(WebSocket.sockets.length, 2);
  assert.notEqual(link.current, first);
  assert.equal(link.current.state, 'connecting');
  assert.equal(link.current.map, null, 'a new connection starts from Welcome');
  socket().open();
  assert.deepEqual(socket().sent.map((m) => m.type), ['Hello']);
  // A close of the old socket after the new one opened changes nothing.
  first.closed({ code: 1006, reason: '' });
  assert.deepEqual(clock.pending(), []);
});

test('consecutive failures back off by the policy; a delivered lightmap resets it', () => {
  const policy = { initialMs: 100, maxMs: 1000, factor: 2, jitter: 0 };
  const { socket, clock, logs } = harness({ backoff: new Backoff(policy) });
  const delays = [];
  for (let i = 0; i < 6; i++) {
    socket().drop(1006, 'gone');
    [delays[i]] = clock.pending();
    clock.advance(delays[i]);
  }
  assert.deepEqual(delays, [100, 200, 400, 800, 1000, 1000]);
  assert.deepEqual(logs.at(-1), ['warn', 'disconnected (1006: gone); reconnecting in 1 s']);
  const { welcome, keyframe } = golden();
  socket().open();
  socket().deliver(welcome);
  socket().deliver(keyframe);
  socket().drop(1001);
  assert.deepEqual(clock.pending(), [100]);
  // Jitter stays within its bounds.
  const jittered = new Backoff({ initialMs: 1000, maxMs: 1000, factor: 1, jitter: 0.25 }, () => 0);
  assert.equal(jittered.next(), 750);
  jittered.random = () => 1;
  assert.equal(jittered.next(), 1250);
});

test('a refusal for good does not reconnect: close code 1008, or an Unauthorized/Forbidden error', () => {
  const policy = harness();
  policy.socket().drop(1008, 'bad token');
  assert.deepEqual(policy.clock.pending(), []);
  assert.deepEqual(policy.calls.at(-1), ['gaveUp', 1008]);
  assert.deepEqual(policy.logs.at(-1), ['warn', 'disconnected (1008: bad token); press Connect to retry']);

  for (const code of [3, 4]) {
    const { socket, clock, calls, link } = harness();
    socket().open();
    socket().serverSends({ type: 'Error', code, message: 'no' });
    assert.equal(link.current.fatal, true);
    socket().drop(1000);
    assert.deepEqual(clock.pending(), [], `error ${code}`);
    assert.deepEqual(calls.at(-1), ['gaveUp', 1000]);
  }
});

test('stop closes the socket with 1000 and never reconnects', () => {
  const { socket, link, clock, calls } = harness();
  socket().open();
  const s = socket();
  link.stop();
  assert.equal(s.closedWith, 1000);
  assert.equal(link.current.closedByUs, true);
  const before = calls.length;
  s.drop(1000);
  assert.deepEqual(clock.pending(), []);
  assert.equal(calls.length, before, 'no callback after stop');
  // Stopping while a reconnect is pending cancels it.
  const other = harness();
  other.socket().drop(1006);
  assert.equal(other.clock.pending().length, 1);
  other.link.stop();
  assert.deepEqual(other.clock.pending(), []);
});

test('a Connection on its own: send only while open', () => {
  const WebSocket = fakeWebSocket();
  const conn = new Connection('ws://x/ws/scenes/s', null, { WebSocket, now: () => 0 });
  conn.send({ type: 'Ping', nonce: 1 });
  assert.deepEqual(WebSocket.sockets[0].sent, []);
  WebSocket.sockets[0].open();
  conn.send({ type: 'Ping', nonce: 2 });
  assert.deepEqual(WebSocket.sockets[0].sent.map((m) => m.type), ['Hello', 'Ping']);
});
