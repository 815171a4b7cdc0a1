// End-to-end test of the dashboard in a real browser: Debian's headless
// Chromium, driven by Playwright (`playwright-core`, which never downloads a
// browser), WebGL2 on SwiftShader (no GPU here).
//
//   node e2e/dashboard.e2e.mjs --url http://127.0.0.1:PORT/ --artifacts DIR [--expect-lights]
//
// The server must already run (in development mode, or with a driver token
// in the URL's `?token=`, so the page may drive; it may be a relay);
// `server/tests/dashboard.rs` starts one and runs this script. Checks, in
// order, each a contract of issue 7:
//
//  1. the page loads and no console error, page error, failed request or
//     HTTP error response happens at any time (checked again at the end);
//  2. the WebSocket connects (Welcome received, role allows driving);
//  3. the convergence chart gets at least three points;
//  4. the atlas view is not blank;
//  5. the 3D view draws pixels other than its background, and, when the
//     scene list counts lights for the scene (always with
//     `--expect-lights`), their gizmos: the lights route's lights as line
//     segments, pixels that the `lights` box hides;
//  6. after the test drags the dynamic box across the 3D view with the
//     mouse, a newer lightmap version arrives that reflects the drag's last
//     transform, and the atlas image changes;
//  7. with `--expect-lights` (a scene lit by its first light alone, such as
//     cornell-point), unticking that light's box in the Lights panel sends
//     `SetLight`, a `Lights` message reflects it and the atlas goes dark;
//     ticking it again brings the atlas back to what it showed;
//  8. with `--expect-lights` (that light a point light above the middle of
//     a room with a `left` and a `right` wall, as cornell-point's), dragging
//     its gizmo towards the left wall with the mouse moves the light there
//     (`SetLight`s, then a `Lights` with the page's last position, the
//     gizmo drawn there) and the lightmap follows: once it settles, the
//     left wall's radiosity has grown against the right wall's.
//
// Screenshots go to the artifacts directory (before and after the move,
// and before and after the light's drag).
// Exits 0 if every check passed, 1 otherwise, printing what failed.

import fs from 'node:fs';
import os from 'node:os';
import path from 'node:path';
import { parseArgs } from 'node:util';

import { chromium } from 'playwright-core';

const { values: args } = parseArgs({
  options: {
    url: { type: 'string' },
    artifacts: { type: 'string', default: 'target/dashboard-artifacts' },
    chromium: { type: 'string', default: process.env.CHROMIUM ?? '/usr/bin/chromium' },
    timeout: { type: 'string', default: '90' },
    'expect-lights': { type: 'boolean', default: false },
  },
});
if (!args.url) {
  console.error('usage: node e2e/dashboard.e2e.mjs --url http://HOST:PORT/ [--artifacts DIR] [--chromium PATH] [--expect-lights]');
  process.exit(2);
}
if (!fs.existsSync(args.chromium)) {
  console.error(`no Chromium at ${args.chromium}: install the Debian package \`chromium\` (make test does)`);
  process.exit(2);
}
const TIMEOUT_MS = Number(args.timeout) * 1000;
fs.mkdirSync(args.artifacts, { recursive: true });

const started = Date.now();
const elapsed = () => `${((Date.now() - started) / 1000).toFixed(1)}s`;
const results = [];
const problems = []; // console errors and the like, any time
function check(name, ok, detail) {
  results.push({ name, ok, detail });
  console.log(`${ok ? 'ok  ' : 'FAIL'} ${name}${detail ? ` — ${detail}` : ''} [${elapsed()}]`);
  return ok;
}

const userDataDir = fs.mkdtempSync(path.join(os.tmpdir(), 'lightwire-chromium-'));
const context = await chromium.launchPersistentContext(userDataDir, {
  executablePath: args.chromium,
  headless: true,
  viewport: { width: 1400, height: 1000 },
  // Chromium complains on stderr without a runtime directory; give it one.
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
    // A WebSocket closed by the server at teardown is not a failure of the page.
    if (r.resourceType() !== 'websocket') problems.push(`request failed: ${r.url()} ${r.failure()?.errorText}`);
  });
  page.on('response', (r) => {
    if (r.status() >= 400) problems.push(`HTTP ${r.status()} for ${r.url()}`);
  });
  const snapshot = () => page.evaluate(() => window.lightwire.snapshot());
  const waitFor = async (what, predicate, arg) => {
    try {
      await page.waitForFunction(predicate, arg, { timeout: TIMEOUT_MS, polling: 100 });
      return true;
    } catch {
      console.log(`timed out waiting for ${what}: ${JSON.stringify(await snapshot())}`);
      return false;
    }
  };

  // 1. Load.
  const response = await page.goto(args.url, { waitUntil: 'load' });
  check('page loads', response?.ok() === true, `HTTP ${response?.status()}`);
  const csp = response?.headers()['content-security-policy'] ?? '';
  check('the page forbids other origins (CSP)', csp.includes("default-src 'self'"), csp);
  await page.waitForFunction(() => window.lightwire !== undefined);

  // 2. WebSocket.
  const connected = await waitFor('Welcome', () => window.lightwire.snapshot().state === 'connected');
  let snap = await snapshot();
  check('WebSocket connects and the server welcomes the page', connected, `scene ${snap.scene}, role ${snap.role}`);
  check('WebGL2 works (SwiftShader in headless Chromium)', !!snap.renderer, snap.renderer);
  check('development mode lets the page drive', ['Driver', 'Admin'].includes(snap.role), snap.role);

  // 3. Chart.
  const points = await waitFor('three chart points', () => window.lightwire.snapshot().chartPoints >= 3);
  snap = await snapshot();
  check('the convergence chart gets at least three points', points, `${snap.chartPoints} points`);

  // Waits until the lightmap version stands still for 2 s (the solver
  // publishes while it shoots and while it corrects).
  const settle = async () => {
    await page.evaluate(() => {
      window.__settle = { version: -1, since: 0 };
    });
    return waitFor('the lightmap to settle', () => {
      const s = window.lightwire.snapshot();
      const w = window.__settle;
      if (s.version !== w.version || !s.hasLightmap) {
        w.version = s.version;
        w.since = performance.now();
        return false;
      }
      return performance.now() - w.since > 2000;
    });
  };
  // Let the first solve converge, so that later changes are the move's.
  const settled = await settle();
  snap = await snapshot();
  check('a first lightmap arrives and settles', settled && snap.version > 0, `version ${snap.version}`);
  await page.waitForTimeout(300); // a couple of animation frames

  // 4. Atlas not blank.
  const atlas = await page.evaluate(() => {
    const c = document.getElementById('atlas');
    const data = c.getContext('2d').getImageData(0, 0, c.width, c.height).data;
    window.__atlasBefore = data;
    let lit = 0;
    for (let i = 0; i < data.length; i += 4) if (data[i] + data[i + 1] + data[i + 2] > 24) lit++;
    return { width: c.width, height: c.height, lit, fraction: lit / (c.width * c.height) };
  });
  check('the atlas view is not blank', atlas.fraction > 0.05, `${atlas.width}x${atlas.height}, ${(atlas.fraction * 100).toFixed(1)}% of texels lit`);

  // 5. 3D view draws.
  const readView = () =>
    page.evaluate(() => {
      const gl = document.getElementById('view');
      const c = document.createElement('canvas');
      c.width = gl.width;
      c.height = gl.height;
      const ctx = c.getContext('2d');
      ctx.drawImage(gl, 0, 0);
      const data = ctx.getImageData(0, 0, c.width, c.height).data;
      const bg = [0.07, 0.08, 0.1].map((v) => Math.round(v * 255));
      let drawn = 0;
      for (let i = 0; i < data.length; i += 4) {
        if (Math.abs(data[i] - bg[0]) + Math.abs(data[i + 1] - bg[1]) + Math.abs(data[i + 2] - bg[2]) > 12) drawn++;
      }
      return { width: c.width, height: c.height, fraction: drawn / (c.width * c.height) };
    });
  const view = await readView();
  check('the 3D view draws non-background pixels', view.fraction > 0.1, `${view.width}x${view.height}, ${(view.fraction * 100).toFixed(1)}% not background`);

  // 5b. The scene's lights as gizmos, when the server lists any.
  const listedLights = await page.evaluate(async (scene) => {
    // The token the page itself uses (its field; a relay wants one).
    const token = document.getElementById('token').value.trim();
    const r = await fetch('/api/scenes', { headers: token ? { Authorization: `Bearer ${token}` } : {} });
    if (!r.ok) throw new Error(`GET /api/scenes: HTTP ${r.status}`);
    return (await r.json()).find((s) => s.id === scene)?.lights ?? 0;
  }, snap.scene);
  if (args['expect-lights'] || listedLights > 0) {
    const gizmos = await waitFor('the light gizmos', () => window.lightwire.snapshot().lightGizmoSegments > 0);
    // The pixels the gizmos cover: the view with them, then without.
    const changed = async () => {
      await page.waitForTimeout(300);
      return page.evaluate(() => {
        const gl = document.getElementById('view');
        const c = document.createElement('canvas');
        [c.width, c.height] = [gl.width, gl.height];
        const ctx = c.getContext('2d');
        ctx.drawImage(gl, 0, 0);
        const data = ctx.getImageData(0, 0, c.width, c.height).data;
        const before = window.__gizmoView;
        window.__gizmoView = data;
        if (!before) return 0;
        let n = 0;
        for (let i = 0; i < data.length; i += 4) if (data[i] !== before[i] || data[i + 1] !== before[i + 1] || data[i + 2] !== before[i + 2]) n++;
        return n;
      });
    };
    await changed();
    await page.uncheck('#show-lights');
    const hidden = await changed();
    await page.check('#show-lights');
    const shown = await changed();
    snap = await snapshot();
    check(
      'the scene\'s lights are drawn as gizmos that the lights box hides',
      listedLights > 0 && gizmos && hidden > 0 && shown > 0,
      `${listedLights} listed, ${snap.lightGizmoSegments} segments, ${hidden} pixels hidden, ${shown} shown again`,
    );
    // The same reply gives the scene file's states, which the Lights
    // panel's sliders are anchored on (gizmos.js's lightAnchor).
    if (snap.lightControls > 0) {
      check(
        'the Lights panel\'s sliders are anchored on the scene file\'s states',
        snap.lightAnchorsFromFile.length === snap.lightControls && snap.lightAnchorsFromFile.every(Boolean),
        JSON.stringify(snap.lightAnchorsFromFile),
      );
    }
  }

  await page.screenshot({ path: path.join(args.artifacts, 'dashboard-before.png'), fullPage: true });
  await page.locator('#view').screenshot({ path: path.join(args.artifacts, 'view-before.png') });
  await page.locator('#atlas').screenshot({ path: path.join(args.artifacts, 'atlas-before.png') });

  // 6. Drag the box with the mouse, as a person would.
  const versionBefore = snap.version;
  const box = snap.dynamicObjects[0];
  check('the scene has a dynamic object', box !== undefined, `object ${box}`);
  const from = await page.evaluate((i) => window.lightwire.objectScreenPoint(i), box);
  const to = { x: from.x + 140, y: from.y + 25 };
  await page.mouse.move(from.x, from.y);
  await page.mouse.down();
  for (let k = 1; k <= 12; k++) {
    await page.mouse.move(from.x + ((to.x - from.x) * k) / 12, from.y + ((to.y - from.y) * k) / 12);
    await page.waitForTimeout(40);
  }
  await page.mouse.up();
  await page.waitForTimeout(100); // the last transform leaves after the throttle period
  snap = await snapshot();
  const seq = snap.lastSentSeq;
  const moved = await page.evaluate((i) => window.lightwire.objectScreenPoint(i), box);
  check('dragging the box moves it and sends transforms', seq > 0 && Math.hypot(moved.x - from.x, moved.y - from.y) > 50, `seq ${seq}, box now at (${moved.x.toFixed(0)}, ${moved.y.toFixed(0)}), was (${from.x.toFixed(0)}, ${from.y.toFixed(0)})`);

  const reflected = await waitFor(
    'a version reflecting the move',
    ([object, s]) => (window.lightwire.snapshot().reflected[object] ?? 0) >= s,
    [box, seq],
  );
  await page.waitForTimeout(300); // let the frame loop redraw
  snap = await snapshot();
  check(
    'the lightmap version increases and reflects the last transform',
    reflected && snap.version > versionBefore,
    `version ${versionBefore} -> ${snap.version}, reflected seq ${snap.reflected[box]}, move -> light ${snap.latencyMs?.toFixed(0)} ms`,
  );
  // A second page that moved nothing draws the box where the first moved
  // it: the server's Poses (asked for in Hello), not the scene file's pose.
  const watcher = await context.newPage();
  watcher.on('pageerror', (e) => problems.push(`watcher page error: ${e.message}`));
  await watcher.goto(args.url, { waitUntil: 'load' });
  let watched = false;
  try {
    await watcher.waitForFunction(
      ([object, s]) => (window.lightwire?.snapshot().poses?.poses ?? []).some((p) => p.object === object && p.seq >= s),
      [box, seq],
      { timeout: TIMEOUT_MS, polling: 100 },
    );
    watched = true;
  } catch {
    console.log(`timed out waiting for the watcher's Poses: ${JSON.stringify(await watcher.evaluate(() => window.lightwire?.snapshot()))}`);
  }
  await watcher.waitForTimeout(300); // let its frame loop draw
  // Relative to each page's 3D view (the pages' layouts above it may differ).
  const inView = (i) => {
    const p = window.lightwire.objectScreenPoint(i);
    const r = document.getElementById('view').getBoundingClientRect();
    return { x: p.x - r.left, y: p.y - r.top };
  };
  const seen = await watcher.evaluate(inView, box);
  const here = await page.evaluate(inView, box);
  const origin = await page.evaluate(() => {
    const r = document.getElementById('view').getBoundingClientRect();
    return { x: r.left, y: r.top };
  });
  const start = { x: from.x - origin.x, y: from.y - origin.y };
  check(
    'a page that did not drive draws the box where the driver moved it (Poses)',
    watched && Math.hypot(seen.x - here.x, seen.y - here.y) < 3 && Math.hypot(seen.x - start.x, seen.y - start.y) > 50,
    `in the view: watcher (${seen.x.toFixed(0)}, ${seen.y.toFixed(0)}), driver (${here.x.toFixed(0)}, ${here.y.toFixed(0)}), scene file (${start.x.toFixed(0)}, ${start.y.toFixed(0)})`,
  );
  await watcher.close();

  const diff = await page.evaluate(() => {
    const c = document.getElementById('atlas');
    const now = c.getContext('2d').getImageData(0, 0, c.width, c.height).data;
    const before = window.__atlasBefore;
    let changed = 0;
    for (let i = 0; i < now.length; i += 4) {
      if (Math.abs(now[i] - before[i]) + Math.abs(now[i + 1] - before[i + 1]) + Math.abs(now[i + 2] - before[i + 2]) > 6) changed++;
    }
    return { changed, fraction: changed / (c.width * c.height) };
  });
  check('the atlas changes after the move', diff.changed > 50, `${diff.changed} texels (${(diff.fraction * 100).toFixed(1)}%) changed`);

  // 7. Switch the first light off and on again in the Lights panel.
  if (args['expect-lights']) {
    const brightness = () => page.evaluate(() => {
      const c = document.getElementById('atlas');
      const d = c.getContext('2d').getImageData(0, 0, c.width, c.height).data;
      let sum = 0;
      for (let i = 0; i < d.length; i += 4) sum += d[i] + d[i + 1] + d[i + 2];
      return sum / (c.width * c.height);
    });
    const panel = await waitFor('the light controls', () => {
      const s = window.lightwire.snapshot();
      return s.lightControls > 0 && s.lightControlsEnabled;
    });
    const toggle = page.locator('#light-list input[type=checkbox]').first();
    const shownLight = (on) => waitFor(
      `a Lights message with the first light ${on ? 'on' : 'off'}`,
      (want) => {
        const l = window.lightwire.snapshot().lights?.lights?.[0];
        return l !== undefined && Number(l.seq) > 0 && l.state.on === want;
      },
      on,
    );
    const lit = await brightness();
    await toggle.uncheck();
    const off = await shownLight(false);
    await page.waitForTimeout(600); // the version after it, and a redraw
    const dark = await brightness();
    await toggle.check();
    const on = await shownLight(true);
    await page.waitForTimeout(600);
    const back = await brightness();
    check(
      'switching the light off darkens the atlas and on again brings it back',
      panel && off && on && dark < 0.05 * lit && Math.abs(back - lit) < 0.05 * lit,
      `mean atlas brightness ${lit.toFixed(1)} -> off ${dark.toFixed(1)} -> on ${back.toFixed(1)}`,
    );
    await page.locator('#atlas').screenshot({ path: path.join(args.artifacts, 'atlas-light-on-again.png') });

    // 8. Drag the light's gizmo towards the left wall, as a person would.
    await settle();
    const walls = () => page.evaluate(() => ({
      left: window.lightwire.surfaceRadiosity('left'),
      right: window.lightwire.surfaceRadiosity('right'),
    }));
    const before = await walls();
    await page.locator('#view').screenshot({ path: path.join(args.artifacts, 'view-light-before-drag.png') });
    snap = await snapshot();
    const startPosition = snap.lightStates[0].position;
    const grab = await page.evaluate(() => window.lightwire.lightScreenPoint(0));
    await page.mouse.move(grab.x, grab.y);
    await page.mouse.down();
    for (let k = 1; k <= 12; k++) {
      await page.mouse.move(grab.x - (80 * k) / 12, grab.y);
      await page.waitForTimeout(40);
    }
    await page.mouse.up();
    await page.waitForTimeout(100); // the last SetLight leaves after the throttle period
    snap = await snapshot();
    const sentSeq = snap.lightSeqsSent[0];
    const dropped = snap.lightStates[0].position;
    const movedBy = dropped.map((v, a) => v - startPosition[a]);
    const gizmo = await page.evaluate(() => window.lightwire.lightScreenPoint(0));
    check(
      'dragging the light\'s gizmo moves the light towards the left wall, on its plane',
      sentSeq !== undefined && movedBy[0] < -0.5 && movedBy[1] === 0 && Math.hypot(gizmo.x - grab.x, gizmo.y - grab.y) > 40,
      `seq ${sentSeq}, light moved by (${movedBy.map((v) => v.toFixed(2)).join(', ')}) m, gizmo now at (${gizmo.x.toFixed(0)}, ${gizmo.y.toFixed(0)}), was (${grab.x.toFixed(0)}, ${grab.y.toFixed(0)})`,
    );
    const followed = await waitFor(
      'a Lights message with the dragged position',
      ([seq, position]) => {
        const l = window.lightwire.snapshot().lights?.lights?.[0];
        return l !== undefined && Number(l.seq) >= Number(seq) && l.state.position.every((v, a) => Math.abs(v - position[a]) < 1e-4);
      },
      [sentSeq, dropped],
    );
    const relit = followed && (await settle());
    await page.waitForTimeout(300); // a redraw
    const after = await walls();
    const gain = after.left / after.right / (before.left / before.right);
    check(
      'the lightmap follows the dragged light: the left wall brightens against the right',
      relit && gain > 1.5,
      `left/right radiosity ${before.left.toFixed(2)}/${before.right.toFixed(2)} -> ${after.left.toFixed(2)}/${after.right.toFixed(2)} (x${gain.toFixed(2)})`,
    );
    await page.locator('#view').screenshot({ path: path.join(args.artifacts, 'view-light-dragged.png') });
    await page.locator('#atlas').screenshot({ path: path.join(args.artifacts, 'atlas-light-dragged.png') });
  }

  await page.screenshot({ path: path.join(args.artifacts, 'dashboard-after.png'), fullPage: true });
  await page.locator('#view').screenshot({ path: path.join(args.artifacts, 'view-after.png') });
  await page.locator('#atlas').screenshot({ path: path.join(args.artifacts, 'atlas-after.png') });

  snap = await snapshot();
  check('the server refused nothing and every frame decoded', snap.errors.length === 0 && snap.counters.decodeErrors === 0, JSON.stringify({ errors: snap.errors, counters: snap.counters }));
  check('no console errors, page errors or failed requests', problems.length === 0, problems.join('; ') || 'none');
  exitCode = results.every((r) => r.ok) ? 0 : 1;
} catch (e) {
  check('the test ran to its end', false, e.stack ?? String(e));
} finally {
  await context.close().catch(() => {});
  fs.rmSync(userDataDir, { recursive: true, force: true });
}
const failed = results.filter((r) => !r.ok).length;
console.log(`dashboard e2e: ${results.length - failed} passed, ${failed} failed in ${elapsed()}; screenshots in ${args.artifacts}`);
process.exit(failed ? 1 : exitCode);
