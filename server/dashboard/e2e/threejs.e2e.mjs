// End-to-end test of the three.js example (src/examples/threejs/): a stock
// engine draws Lightwire's stream. Debian's headless Chromium, driven by
// Playwright (`playwright-core`, which never downloads a browser), WebGL2 on
// SwiftShader (no GPU here: `--use-angle=swiftshader
// --enable-unsafe-swiftshader`, as the dashboard's test).
//
//   node e2e/threejs.e2e.mjs --url 'http://127.0.0.1:PORT/examples/threejs/?scene=ID' \
//     --artifacts DIR [--name NAME] [--move DX,DY,DZ,YAW_DEGREES]
//
// The server must already run and have published a lightmap (development
// mode, or a driver token in the URL's `?token=`); `server/tests/threejs.rs`
// and `server/tests/levels.rs` start one and run this script. Checks, in
// order:
//
//  1. the page loads under its Content-Security-Policy; with
//     `?autoconnect=0` it loads the scene's glTF and draws it with the
//     placeholder lightmap (flat grey): that frame is kept;
//  2. connected, a keyframe arrives and the lightmap settles (its version
//     holds still for 2 s); the frame drawn then is lit: a good share of
//     its pixels are neither black nor the clear colour, their brightness
//     varies (not flat), and it differs from the placeholder's;
//  3. the test moves the dynamic object as a driver (a Transform sent on the
//     page's WebSocket by `window.lightwireExample.move`, translated by DX,
//     DY, DZ metres and turned by YAW about y): a newer lightmap version
//     reflects it, the page draws the object at the new pose (from the
//     server's Poses), and the image changes, also outside the object's
//     projected bounds before and after (the light moved, not only the
//     object);
//  4. no console error, page error, failed request or HTTP error at any time.
//
// Screenshots: NAME-placeholder.png, NAME-lit.png, NAME-moved.png in the
// artifacts directory. Exits 0 if every check passed, 1 otherwise.

import fs from 'node:fs';
import os from 'node:os';
import path from 'node:path';
import { parseArgs } from 'node:util';

import { chromium } from 'playwright-core';

const { values: args } = parseArgs({
  options: {
    url: { type: 'string' },
    artifacts: { type: 'string', default: 'target/threejs-artifacts' },
    name: { type: 'string', default: 'threejs' },
    chromium: { type: 'string', default: process.env.CHROMIUM ?? '/usr/bin/chromium' },
    timeout: { type: 'string', default: '120' },
    move: { type: 'string', default: '0.8,0,0,30' },
  },
});
if (!args.url) {
  console.error("usage: node e2e/threejs.e2e.mjs --url 'http://HOST:PORT/examples/threejs/?scene=ID' [--artifacts DIR] [--name NAME] [--move DX,DY,DZ,YAW]");
  process.exit(2);
}
if (!fs.existsSync(args.chromium)) {
  console.error(`no Chromium at ${args.chromium}: install the Debian package \`chromium\` (make test does)`);
  process.exit(2);
}
const move = args.move.split(',').map(Number);
if (move.length !== 4 || !move.every(Number.isFinite)) {
  console.error(`--move takes DX,DY,DZ,YAW_DEGREES, not ${args.move}`);
  process.exit(2);
}
const TIMEOUT_MS = Number(args.timeout) * 1000;
fs.mkdirSync(args.artifacts, { recursive: true });
const shot = (what) => path.join(args.artifacts, `${args.name}-${what}.png`);

const started = Date.now();
const elapsed = () => `${((Date.now() - started) / 1000).toFixed(1)}s`;
const results = [];
const problems = []; // console errors and the like, any time
function check(name, ok, detail) {
  results.push({ name, ok });
  console.log(`${ok ? 'ok  ' : 'FAIL'} ${name}${detail ? ` — ${detail}` : ''} [${elapsed()}]`);
  return ok;
}

/** The pose `pose` translated by `d` and turned by `yaw` radians about y
 * (applied after its rotation). */
function moved(pose, [dx, dy, dz, yawDegrees]) {
  const half = (yawDegrees * Math.PI) / 360;
  const [qx, qy, qz, qw] = [0, Math.sin(half), 0, Math.cos(half)];
  const [x, y, z, w] = pose.rotation;
  return {
    translation: [pose.translation[0] + dx, pose.translation[1] + dy, pose.translation[2] + dz],
    rotation: [
      qw * x + qx * w + qy * z - qz * y,
      qw * y - qx * z + qy * w + qz * x,
      qw * z + qx * y - qy * x + qz * w,
      qw * w - qx * x - qy * y - qz * z,
    ],
    scale: pose.scale,
  };
}

const userDataDir = fs.mkdtempSync(path.join(os.tmpdir(), 'lightwire-chromium-'));
const context = await chromium.launchPersistentContext(userDataDir, {
  executablePath: args.chromium,
  headless: true,
  viewport: { width: 1280, height: 800 },
  env: { ...process.env, XDG_RUNTIME_DIR: userDataDir },
  args: [
    '--headless',
    '--no-sandbox',
    '--disable-gpu',
    '--disable-quic',
    '--no-first-run',
    '--disable-background-networking',
    '--disable-component-update',
    '--disable-sync',
    // WebGL2 without a GPU: ANGLE on SwiftShader's software Vulkan.
    '--use-angle=swiftshader',
    '--enable-unsafe-swiftshader',
  ],
});

let exitCode = 1;
try {
  const page = context.pages()[0] ?? (await context.newPage());
  page.setDefaultTimeout(TIMEOUT_MS);
  page.on('console', (m) => {
    if (m.type() === 'error') problems.push(`console error: ${m.text()}`);
  });
  page.on('pageerror', (e) => problems.push(`page error: ${e.message}`));
  page.on('requestfailed', (r) => {
    if (r.resourceType() !== 'websocket') problems.push(`request failed: ${r.url()} ${r.failure()?.errorText}`);
  });
  page.on('response', (r) => {
    if (r.status() >= 400) problems.push(`HTTP ${r.status()} for ${r.url()}`);
  });
  const snapshot = () => page.evaluate(() => window.lightwireExample?.snapshot() ?? null);
  const waitFor = async (what, predicate, arg) => {
    try {
      await page.waitForFunction(predicate, arg, { timeout: TIMEOUT_MS, polling: 100 });
      return true;
    } catch {
      console.log(`timed out waiting for ${what}: ${JSON.stringify(await snapshot())}`);
      return false;
    }
  };
  /** Waits until the lightmap version has stood still for `ms`. */
  const settle = (what, ms = 2000) =>
    waitFor(
      what,
      (hold) => {
        const s = window.lightwireExample.state;
        const w = (window.__settle ??= { version: -1, since: 0 });
        if (s.version !== w.version || s.litFrames === 0) {
          w.version = s.version;
          w.since = performance.now();
          return false;
        }
        return performance.now() - w.since > hold;
      },
      ms,
    );
  /** Waits for two more rendered frames (the frame loop draws on demand). */
  const drawn = async () => {
    await page.evaluate(() => new Promise((done) => requestAnimationFrame(() => requestAnimationFrame(done))));
    await page.waitForTimeout(100);
  };
  /**
   * Reads the WebGL canvas back (the renderer keeps its drawing buffer) as
   * `window.__shots[name]` and returns, over all pixels: the share that is
   * the clear colour, near black, lit (neither), and the standard deviation
   * of the lit pixels' brightness (0..255).
   */
  const read = (name) =>
    page.evaluate((name) => {
      const gl = document.querySelector('#view canvas');
      const c = document.createElement('canvas');
      c.width = gl.width;
      c.height = gl.height;
      const ctx = c.getContext('2d');
      ctx.drawImage(gl, 0, 0);
      const data = ctx.getImageData(0, 0, c.width, c.height).data;
      (window.__shots ??= {})[name] = { data, width: c.width, height: c.height };
      const bg = [0x12, 0x14, 0x1a];
      let background = 0;
      let black = 0;
      let lit = 0;
      let sum = 0;
      let sum2 = 0;
      for (let i = 0; i < data.length; i += 4) {
        const [r, g, b] = [data[i], data[i + 1], data[i + 2]];
        if (Math.abs(r - bg[0]) + Math.abs(g - bg[1]) + Math.abs(b - bg[2]) <= 12) background++;
        else if (r + g + b <= 30) black++;
        else {
          lit++;
          const y = (r + g + b) / 3;
          sum += y;
          sum2 += y * y;
        }
      }
      const n = c.width * c.height;
      const mean = lit ? sum / lit : 0;
      return {
        width: c.width,
        height: c.height,
        background: background / n,
        black: black / n,
        lit: lit / n,
        spread: lit ? Math.sqrt(Math.max(0, sum2 / lit - mean * mean)) : 0,
      };
    }, name);
  /** The share of pixels that differ between two reads, and the count of
   * those outside the rectangles `skip` (canvas pixels, grown by 4). */
  const diff = (a, b, skip = []) =>
    page.evaluate(
      ([a, b, skip]) => {
        const { data: x, width, height } = window.__shots[a];
        const y = window.__shots[b].data;
        let changed = 0;
        let outside = 0;
        for (let p = 0; p < width * height; p++) {
          const i = p * 4;
          if (Math.abs(x[i] - y[i]) + Math.abs(x[i + 1] - y[i + 1]) + Math.abs(x[i + 2] - y[i + 2]) <= 12) continue;
          changed++;
          const [px, py] = [p % width, Math.floor(p / width)];
          if (!skip.some((r) => px >= r.x0 - 4 && px <= r.x1 + 4 && py >= r.y0 - 4 && py <= r.y1 + 4)) outside++;
        }
        return { changed: changed / (width * height), outside };
      },
      [a, b, skip],
    );
  const pct = (x) => `${(x * 100).toFixed(1)}%`;

  // 1. Load, and the placeholder frame.
  const url = new URL(args.url);
  url.searchParams.set('autoconnect', '0');
  const response = await page.goto(url.href, { waitUntil: 'load' });
  check('page loads', response?.ok() === true, `HTTP ${response?.status()} ${url.pathname}${url.search}`);
  const csp = response?.headers()['content-security-policy'] ?? '';
  check('the page forbids other origins (CSP)', csp.includes("default-src 'self'") && !csp.includes('unsafe'), csp);
  const ready = await waitFor('the glTF to load', () => window.lightwireExample?.state.state === 'ready' && window.lightwireExample.state.frames > 0);
  let snap = await snapshot();
  check('three.js loads the scene\'s glTF and draws it', ready, `three r${snap?.three}, scene ${snap?.scene}`);
  await drawn();
  const placeholder = await read('placeholder');
  check(
    'before any lightmap, the placeholder shows the scene (flat grey)',
    placeholder.lit > 0.1 && placeholder.spread < 8 && (await snapshot()).version === 0,
    `${placeholder.width}x${placeholder.height}, ${pct(placeholder.lit)} drawn, brightness spread ${placeholder.spread.toFixed(1)}`,
  );
  await page.screenshot({ path: shot('placeholder') });

  // 2. Connect; the stream lights the scene.
  await page.evaluate(() => window.lightwireExample.connect());
  const connected = await waitFor('Welcome', () => window.lightwireExample.state.role !== null);
  snap = await snapshot();
  check('WebSocket connects and the server welcomes the page', connected, `scene ${snap.scene}, role ${snap.role}, protocol ${snap.protocol}`);
  check('the page may drive (development mode or a driver token)', ['Driver', 'Admin'].includes(snap.role), snap.role);
  const settled = await settle('the lightmap to arrive and settle');
  await drawn();
  snap = await snapshot();
  check(
    'a keyframe arrives and the lightmap settles',
    settled && snap.version > 0 && snap.keyframes > 0 && snap.litFrames > 0,
    `version ${snap.version} (${snap.lightmapFormat}), ${snap.keyframes} keyframes, ${snap.deltas} deltas, exposure ${snap.exposure.toPrecision(3)}`,
  );
  const lit = await read('lit');
  check(
    'the scene is drawn lit: not black, not the clear colour, not flat',
    lit.lit > 0.25 && lit.spread > 12,
    `${pct(lit.lit)} lit, ${pct(lit.black)} black, ${pct(lit.background)} clear colour, brightness spread ${lit.spread.toFixed(1)}`,
  );
  const fromPlaceholder = await diff('placeholder', 'lit');
  check('the lit image is not the placeholder', fromPlaceholder.changed > 0.2, `${pct(fromPlaceholder.changed)} of pixels differ`);
  await page.screenshot({ path: shot('lit') });

  // 3. A driver moves the dynamic object.
  const object = snap.dynamicObjects[0];
  const before = snap.poses[object];
  check('the scene has a dynamic object, drawn at its pose', object !== undefined && before !== undefined, `object ${object} at ${JSON.stringify(before?.translation)}`);
  const target = moved(before, move);
  const rectBefore = await page.evaluate((i) => window.lightwireExample.objectScreenRect(i), object);
  const versionBefore = snap.version;
  const seq = await page.evaluate(([i, pose]) => window.lightwireExample.move(i, pose), [object, target]);
  const reflected = await waitFor(
    'a version reflecting the move, with the object drawn there',
    ([i, s, t]) => {
      const st = window.lightwireExample.state;
      const p = st.poses[i];
      const near = (a, b) => a.every((v, k) => Math.abs(v - b[k]) < 1e-4);
      return (st.reflected[i] ?? 0) >= s && p && near(p.translation, t.translation) && near(p.rotation, t.rotation);
    },
    [object, seq, target],
  );
  snap = await snapshot();
  check(
    'a newer lightmap version reflects the move and the object is drawn where the server has it',
    reflected && snap.version > versionBefore,
    `seq ${seq}, version ${versionBefore} -> ${snap.version}, object at ${JSON.stringify(snap.poses[object]?.translation)}`,
  );
  const settledAgain = await settle('the light to settle after the move');
  await drawn();
  const after = await read('moved');
  const rectAfter = await page.evaluate((i) => window.lightwireExample.objectScreenRect(i), object);
  const change = await diff('lit', 'moved', [rectBefore, rectAfter].filter(Boolean));
  snap = await snapshot();
  check(
    'the image changes after the move, also away from the object (the light moved)',
    settledAgain && change.changed > 0.005 && change.outside > 200 && after.lit > 0.25,
    `${pct(change.changed)} of pixels differ, ${change.outside} outside the object's bounds; version ${snap.version}, ${snap.deltas} deltas`,
  );
  await page.screenshot({ path: shot('moved') });

  check('the server refused nothing', snap.errors.length === 0, JSON.stringify(snap.errors));
  check('no console errors, page errors or failed requests', problems.length === 0, problems.join('; ') || 'none');
  exitCode = results.every((r) => r.ok) ? 0 : 1;
} catch (e) {
  check('the test ran to its end', false, e.stack ?? String(e));
} finally {
  await context.close().catch(() => {});
  fs.rmSync(userDataDir, { recursive: true, force: true });
}
const failed = results.filter((r) => !r.ok).length;
console.log(`three.js e2e: ${results.length - failed} passed, ${failed} failed in ${elapsed()}; screenshots in ${args.artifacts}`);
process.exit(failed ? 1 : exitCode);
