// The Khronos glTF-Validator (npm gltf-validator, clients/web/node_modules)
// on a scan's mesh.glb: passes with 0 errors and 0 warnings (infos and hints
// are printed, not failures), and the asset carries craftscan's provenance
// (glb.h): units, frame, the transform back to the turntable frame.
//
//   node validate_glb.mjs DIR    (DIR holds mesh.glb and report.json)
import { readFileSync } from 'node:fs';
import { join } from 'node:path';
import { createRequire } from 'node:module';

const require = createRequire(import.meta.url);
let validator;
try {
  validator = require('gltf-validator');
} catch (e) {
  console.log(`SKIP: gltf-validator not installed (scripts/setup): ${e.message}`);
  process.exit(77);
}

const dir = process.argv[2];
if (!dir) {
  console.error('usage: node validate_glb.mjs DIR');
  process.exit(2);
}
const bytes = new Uint8Array(readFileSync(join(dir, 'mesh.glb')));
const report = JSON.parse(readFileSync(join(dir, 'report.json'), 'utf8'));
const failures = [];
const expect = (ok, what) => { if (!ok) failures.push(what); };

const result = await validator.validateBytes(bytes, { maxIssues: 0 });
const { numErrors, numWarnings, numInfos, numHints, messages } = result.issues;
console.log(`mesh.glb: ${bytes.length} bytes; validator ${result.validatorVersion}: ` +
            `${numErrors} errors, ${numWarnings} warnings, ${numInfos} infos, ${numHints} hints`);
const severity = ['error', 'warning', 'info', 'hint'];
for (const m of messages) {
  console.log(`  ${severity[m.severity]} ${m.code} ${m.pointer ?? ''}: ${m.message}`);
}
expect(numErrors === 0, `${numErrors} errors`);
expect(numWarnings === 0, `${numWarnings} warnings`);
expect(result.mimeType === 'model/gltf-binary', `mime type ${result.mimeType}`);
const info = result.info ?? {};
expect(info.version === '2.0', `asset.version ${info.version}`);
expect(info.drawCallCount === 1, `draw calls ${info.drawCallCount}`);
expect(info.totalVertexCount === report.mesh.vertices,
       `vertices ${info.totalVertexCount} vs report.json ${report.mesh.vertices}`);
expect(info.totalTriangleCount === report.mesh.faces,
       `triangles ${info.totalTriangleCount} vs report.json ${report.mesh.faces}`);

// The JSON chunk: the provenance glb.h promises.
const view = new DataView(bytes.buffer, bytes.byteOffset, bytes.byteLength);
const jsonLength = view.getUint32(12, true);
const gltf = JSON.parse(new TextDecoder().decode(bytes.subarray(20, 20 + jsonLength)));
const prov = gltf.asset?.extras?.craftscan ?? {};
expect(prov.format === 'craftscan-model-provenance', `provenance format ${prov.format}`);
expect(prov.units === 'm' && prov.up === '+Y', `units ${prov.units}, up ${prov.up}`);
expect(prov.source_frame === report.frame, `source_frame ${prov.source_frame} vs ${report.frame}`);
expect(Array.isArray(prov.source_from_gltf) && prov.source_from_gltf.length === 16,
       'source_from_gltf has 16 numbers');
expect(prov.vertices === report.mesh.vertices && prov.triangles === report.mesh.faces,
       'provenance counts match report.json');
expect(typeof prov.software === 'string' && prov.software.length > 0, 'software recorded');
// POSITION bounds (metres) are report.json's mesh bounds (mm) turned to +Y up.
const position = gltf.accessors[gltf.meshes[0].primitives[0].attributes.POSITION];
const b = report.mesh.bounds_mm;
const m = prov.source_from_gltf;
if (b && m && report.frame === 'turntable') {
  // turntable (x, y, z) = 1000 · (x, −z, y)_gltf
  const lo = [position.min[0] * 1000, -position.max[2] * 1000, position.min[1] * 1000];
  const hi = [position.max[0] * 1000, -position.min[2] * 1000, position.max[1] * 1000];
  for (let k = 0; k < 3; ++k) {
    expect(Math.abs(lo[k] - b.min[k]) < 1e-3 && Math.abs(hi[k] - b.max[k]) < 1e-3,
           `axis ${k}: glTF bounds ${lo[k]}..${hi[k]} mm vs report ${b.min[k]}..${b.max[k]} mm`);
  }
} else {
  failures.push('report.json has no mesh.bounds_mm or the frame is not the turntable');
}

if (failures.length) {
  console.error(`FAIL:\n  ${failures.join('\n  ')}`);
  process.exit(1);
}
console.log('PASS: 0 errors, 0 warnings; provenance and bounds as report.json says');
