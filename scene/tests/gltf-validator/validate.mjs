// Validates glTF/GLB files with the Khronos glTF validator and prints one
// summary line per file ("FILE errors N warnings N infos N") and every
// message. Exits 1 if any file has an error.
//
//   node validate.mjs FILE...
import { validateBytes } from 'gltf-validator';
import { readFileSync } from 'node:fs';

let failed = 0;
for (const file of process.argv.slice(2)) {
  const report = await validateBytes(new Uint8Array(readFileSync(file)));
  const i = report.issues;
  console.log(`${file} errors ${i.numErrors} warnings ${i.numWarnings} infos ${i.numInfos}`);
  for (const m of i.messages) {
    const severity = ['error', 'warning', 'info', 'hint'][m.severity] ?? m.severity;
    console.log(`  ${severity} ${m.code} ${m.pointer ?? ''} ${m.message}`);
  }
  if (i.numErrors > 0) failed++;
}
process.exit(failed > 0 ? 1 : 0);
