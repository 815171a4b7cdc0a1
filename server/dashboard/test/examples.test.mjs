// The three.js example (src/examples/threejs/): three.js is vendored byte for
// byte from the npm package pinned in package-lock.json, with its license,
// and the page's inline import map is the one the server's Content Security
// Policy allows by hash (service/dashboard.rs, EXAMPLE_CSP): a page whose
// import map changed without the hash would load nothing.

import assert from 'node:assert/strict';
import crypto from 'node:crypto';
import fs from 'node:fs';
import path from 'node:path';
import test from 'node:test';
import { fileURLToPath } from 'node:url';

const root = path.resolve(path.dirname(fileURLToPath(import.meta.url)), '..');
const lock = JSON.parse(fs.readFileSync(path.join(root, 'package-lock.json'), 'utf8'));

/** The files of the package the page loads, as vendored under src/vendor/three/. */
const THREE_FILES = [
  'build/three.module.js',
  'build/three.core.js',
  'examples/jsm/loaders/GLTFLoader.js',
  'examples/jsm/utils/BufferGeometryUtils.js',
  'examples/jsm/utils/SkeletonUtils.js',
  'examples/jsm/controls/OrbitControls.js',
  'LICENSE',
];

test('src/vendor/three/ holds the pinned three package\'s files, unchanged', () => {
  const pkg = path.join(root, 'node_modules/three');
  assert.ok(fs.existsSync(pkg), 'node_modules/three is missing: run `npm ci` in server/dashboard (make test does)');
  const installed = JSON.parse(fs.readFileSync(path.join(pkg, 'package.json'), 'utf8')).version;
  assert.equal(installed, lock.packages['node_modules/three'].version, 'installed three is the locked version');
  for (const file of THREE_FILES) {
    assert.ok(
      fs.readFileSync(path.join(pkg, file)).equals(fs.readFileSync(path.join(root, 'src/vendor/three', file))),
      `src/vendor/three/${file} differs from the package: copy node_modules/three/${file} over it`,
    );
  }
  const vendored = fs.readdirSync(path.join(root, 'src/vendor/three'), { recursive: true, withFileTypes: true })
    .filter((e) => e.isFile())
    .map((e) => path.relative(path.join(root, 'src/vendor/three'), path.join(e.parentPath ?? e.path, e.name)));
  assert.deepEqual(vendored.sort(), [...THREE_FILES].sort(), 'src/vendor/three/ holds exactly the files the page loads');
});

test('the example\'s import map is the one its Content-Security-Policy allows', () => {
  const page = fs.readFileSync(path.join(root, 'src/examples/threejs/index.html'), 'utf8');
  const map = page.match(/<script type="importmap">([\s\S]*?)<\/script>/);
  assert.ok(map, 'index.html has an inline import map');
  const hash = crypto.createHash('sha256').update(map[1], 'utf8').digest('base64');
  const rust = fs.readFileSync(path.join(root, '../src/service/dashboard.rs'), 'utf8');
  const csp = rust.match(/const EXAMPLE_CSP: &str = "([^"]*)"/);
  assert.ok(csp, 'service/dashboard.rs defines EXAMPLE_CSP');
  assert.ok(
    csp[1].includes(`'sha256-${hash}'`),
    `EXAMPLE_CSP must allow the import map: put 'sha256-${hash}' in its script-src`,
  );
  const imports = JSON.parse(map[1]).imports;
  assert.equal(imports.three, '/dashboard/vendor/three/build/three.module.js');
});
