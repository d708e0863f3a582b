// ROS 2 on the wire, checked by an independent decoder. Reads what
// craftscan_ros_wire_capture left in --out (craftscand on the sim through a
// scan: the raw CDR of every rt/... sample plus the field values the daemon
// meant to send; CTest runs it first, fixture ros_capture), decodes each sample with @foxglove/rosmsg2-serialization and
// the standard ROS 2 definitions (@foxglove/rosmsg-msgs-common, Humble) and
// checks:
//  - every field equals what was sent (byte arrays by length and FNV-1a);
//  - the encapsulation is CDR little endian and the whole body is consumed;
//  - what ROS tools rely on: each Image has a CameraInfo of the same stamp
//    and frame_id (both cameras); /tf has one turntable transform per view
//    with the image's stamp and the view's angle; /tf_static holds the
//    station's tree (REP 103/105 names); units are metres;
//  - counts per topic for the scan.
//
//   node ros_wire.mjs --out DIR
import fs from 'node:fs';
import path from 'node:path';

import { check, CheckError, firstDifference, parseArgs, standardReader, summarize } from './ros_lib.mjs';

const args = parseArgs(process.argv.slice(2));
check(args.out, 'usage: node ros_wire.mjs --out DIR');

function main() {
  const start = Date.now();
  const manifest = JSON.parse(fs.readFileSync(path.join(args.out, 'expected.json'), 'utf8'));
  const { station, views, step_deg: stepDeg, frames } = manifest;
  const readers = new Map();
  const byTopic = new Map();
  for (const sample of manifest.samples) {
    const bytes = fs.readFileSync(path.join(args.out, sample.file));
    const where = `${sample.file} (${sample.topic})`;
    // Encapsulation: 0x0001 = CDR little endian (XCDR1, what ROS 2 sends).
    check(bytes[0] === 0 && bytes[1] === 1, `${where}: encapsulation ${bytes[0]},${bytes[1]} is not CDR_LE`);
    check(!sample.expected.error, `${where}: the sender side could not rebuild it: ${sample.expected.error}`);
    if (!readers.has(sample.type)) readers.set(sample.type, standardReader(sample.type));
    const reader = readers.get(sample.type);
    const message = reader.readMessage(bytes);
    // Cyclone pads the body to 4 bytes and says how much in the options'
    // two low bits (XCDR); anything beyond that was not decoded.
    const padding = bytes[3] & 3;
    const left = bytes.length - reader.lastReadByteLength();
    check(left === padding, `${where}: ${left} bytes left after decoding, ${padding} of them ` +
          'declared padding: our IDL and the standard definition differ');
    const difference = firstDifference(summarize(message), sample.expected);
    check(difference === null, `${where}: ${difference}`);
    if (!byTopic.has(sample.topic)) byTopic.set(sample.topic, []);
    byTopic.get(sample.topic).push(message);
  }

  const topic = (leaf) => `rt/craftscan/${station}/${leaf}`;
  const of = (name) => byTopic.get(name) ?? [];
  const stampKey = (h) => `${h.stamp.sec}.${h.stamp.nanosec}|${h.frame_id}`;
  const counts = {};
  for (const [name, list] of byTopic) counts[name] = list.length;
  console.log('samples per topic:', JSON.stringify(counts));

  // Counts: one image, disparity and /tf per view; a cloud per view and the
  // fused one; camera_info with each image plus the latched one.
  for (const side of ['left', 'right']) {
    check(of(topic(`${side}/image_raw`)).length === views, `${side} images: ${of(topic(`${side}/image_raw`)).length}, want ${views}`);
    check(of(topic(`${side}/camera_info`)).length >= views + 1, `${side} camera_info: too few`);
  }
  check(of(topic('disparity')).length === views, `disparity: ${of(topic('disparity')).length}, want ${views}`);
  check(of(topic('cloud')).length === views + 1, `cloud: ${of(topic('cloud')).length}, want ${views + 1}`);
  check(of('rt/tf').length === views, `/tf: ${of('rt/tf').length}, want ${views}`);
  check(of('rt/tf_static').length >= 1, 'no /tf_static');

  // Stamp pairing, as image_proc, stereo_image_proc and rviz2 do it.
  for (const side of ['left', 'right']) {
    const infos = new Map(of(topic(`${side}/camera_info`)).map((m) => [stampKey(m.header), m]));
    of(topic(`${side}/image_raw`)).forEach((image, k) => {
      check(infos.has(stampKey(image.header)),
            `${side} image ${k} (${stampKey(image.header)}): no camera_info with its stamp and frame`);
      check(image.header.frame_id === frames[side], `${side} image frame ${image.header.frame_id}`);
      check(image.encoding === 'bgr8' && image.step === image.width * 3 &&
            image.data.length === image.step * image.height, `${side} image ${k}: not packed bgr8`);
      const info = infos.get(stampKey(image.header));
      check(info.width === image.width && info.height === image.height, `${side} camera_info size`);
      check(info.distortion_model === 'plumb_bob' && info.d.length === 5, `${side} distortion model`);
    });
  }
  // Right P: translation −fx·baseline in metres (REP 104): a few cm to 1 m.
  const rightInfo = of(topic('right/camera_info'))[0];
  const baselineM = -rightInfo.p[3] / rightInfo.p[0];
  check(baselineM > 0.01 && baselineM < 1, `right P baseline ${baselineM} m is not in metres`);

  // Disparity: 32FC1, f in px, T the same baseline in metres.
  for (const d of of(topic('disparity'))) {
    check(d.image.encoding === '32FC1' && d.header.frame_id === frames.rig, 'disparity encoding/frame');
    check(Math.abs(d.t - baselineM) < 1e-4 * baselineM + 1e-6, `disparity T ${d.t} ≠ baseline ${baselineM}`);
    check(d.f > 0 && d.min_disparity < d.max_disparity, 'disparity f and range');
  }
  // Clouds: x, y, z, rgb FLOAT32 at 0, 4, 8, 12 (the fused one with
  // normal_x/y/z after them); points in metres.
  of(topic('cloud')).forEach((c, k) => {
    const layout = c.fields.map((f) => `${f.name}:${f.offset}:${f.datatype}:${f.count}`).join(',');
    const want = k < views ? ['x:0:7:1,y:4:7:1,z:8:7:1,rgb:12:7:1', 16]
      : ['x:0:7:1,y:4:7:1,z:8:7:1,rgb:12:7:1,normal_x:16:7:1,normal_y:20:7:1,normal_z:24:7:1', 28];
    check(layout === want[0] && c.point_step === want[1], `cloud ${k} fields ${layout}, point_step ${c.point_step}`);
    check(c.header.frame_id === (k < views ? frames.rig : frames.turntable_base), `cloud ${k} frame ${c.header.frame_id}`);
    const view = new DataView(c.data.buffer, c.data.byteOffset, c.data.byteLength);
    let maxAbs = 0;
    for (let i = 0; i < c.width; i += Math.max(1, Math.floor(c.width / 500))) {
      for (let a = 0; a < 3; ++a) maxAbs = Math.max(maxAbs, Math.abs(view.getFloat32(i * c.point_step + a * 4, true)));
    }
    check(maxAbs > 0.01 && maxAbs < 2, `cloud ${k}: coordinates up to ${maxAbs}, not metres of a station`);
  });

  // /tf_static: the station's tree; /tf: the turntable per view.
  const edges = new Set(of('rt/tf_static').at(-1).transforms.map((t) => `${t.header.frame_id}>${t.child_frame_id}`));
  for (const [parent, child] of [['base', 'rig'], ['rig', 'left'], ['rig', 'right'], ['rig', 'turntable_base']]) {
    check(edges.has(`${frames[parent]}>${frames[child]}`), `/tf_static lacks ${frames[parent]} → ${frames[child]}`);
  }
  for (const f of Object.values(frames)) {
    check(f.startsWith(`${station}_`), `frame ${f} is not named after the station`);
  }
  check(frames.left.endsWith('_optical_frame') && frames.right.endsWith('_optical_frame') &&
        frames.rig.endsWith('_optical_frame') && frames.base.endsWith('_base_link'), 'REP 103/105 frame names');
  const leftImages = of(topic('left/image_raw'));
  of('rt/tf').forEach((m, k) => {
    check(m.transforms.length === 1, `/tf ${k}: ${m.transforms.length} transforms`);
    const t = m.transforms[0];
    check(t.header.frame_id === frames.turntable_base && t.child_frame_id === frames.turntable, `/tf ${k} frames`);
    check(stampKey({ ...t.header, frame_id: '' }) === stampKey({ ...leftImages[k].header, frame_id: '' }),
          `/tf ${k}: stamp differs from view ${k}'s images`);
    const q = t.transform.rotation;
    check(Math.abs(Math.hypot(q.x, q.y, q.z, q.w) - 1) < 1e-9 && q.x === 0 && q.y === 0, `/tf ${k}: not a turn about z`);
    const angleDeg = (2 * Math.atan2(q.z, q.w) * 180) / Math.PI;
    const want = k * stepDeg;
    const wrapped = ((angleDeg - want + 540) % 360) - 180;
    check(Math.abs(wrapped) < 1e-9, `/tf ${k}: turntable at ${angleDeg}°, want ${want}°`);
  });
  console.log(`ros_wire: ${manifest.samples.length} samples decoded field for field in ${((Date.now() - start) / 1000).toFixed(1)} s`);
}

try {
  main();
} catch (e) {
  console.error(e instanceof CheckError ? `ros_wire: FAILED: ${e.message}` : e);
  process.exit(1);
}
