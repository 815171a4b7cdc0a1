// The zstd decoder is vendored (served from the binary, no CDN): it must be
// byte for byte the file of the npm package pinned in package-lock.json, and
// ship with its license.

import assert from 'node:assert/strict';
import fs from 'node:fs';
import path from 'node:path';
import test from 'node:test';
import { fileURLToPath } from 'node:url';

const root = path.resolve(path.dirname(fileURLToPath(import.meta.url)), '..');
const lock = JSON.parse(fs.readFileSync(path.join(root, 'package-lock.json'), 'utf8'));

test('src/vendor/fzstd.js is the pinned fzstd package\'s esm/index.mjs, with its license', () => {
  const pkg = path.join(root, 'node_modules/fzstd');
  assert.ok(fs.existsSync(pkg), 'node_modules/fzstd is missing: run `npm ci` in server/dashboard (make test does)');
  const installed = JSON.parse(fs.readFileSync(path.join(pkg, 'package.json'), 'utf8')).version;
  assert.equal(installed, lock.packages['node_modules/fzstd'].version, 'installed fzstd is the locked version');
  assert.ok(
    fs.readFileSync(path.join(pkg, 'esm/index.mjs')).equals(fs.readFileSync(path.join(root, 'src/vendor/fzstd.js'))),
    'src/vendor/fzstd.js differs from the package: copy node_modules/fzstd/esm/index.mjs over it',
  );
  assert.ok(
    fs.readFileSync(path.join(pkg, 'LICENSE')).equals(fs.readFileSync(path.join(root, 'src/vendor/fzstd.LICENSE'))),
    'src/vendor/fzstd.LICENSE differs from the package\'s LICENSE',
  );
});
