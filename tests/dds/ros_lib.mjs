// Helpers of the node-driven ROS 2 checks (ros_wire.mjs, mcap_record.mjs):
// the npm packages from clients/web/node_modules (pinned by scripts/setup),
// decoding CDR with @foxglove/rosmsg2-serialization, and the JSON layout
// the C++ side writes its expected field values in.
import { createRequire } from 'node:module';
import path from 'node:path';
import { fileURLToPath } from 'node:url';

const here = path.dirname(fileURLToPath(import.meta.url));
export const sourceDir = path.resolve(here, '..', '..');
// require() from clients/web: its node_modules, whatever NODE_PATH says.
export const requireWeb = createRequire(path.join(sourceDir, 'clients', 'web', 'package.json'));

export class CheckError extends Error {}

/** Throws (failing the test) with `message` unless `condition`. */
export function check(condition, message) {
  if (!condition) throw new CheckError(message);
}

/** FNV-1a, 32 bits, of a byte array (as ros_wire_capture.cc computes it). */
export function fnv1a32(bytes) {
  let h = 2166136261;
  for (let i = 0; i < bytes.length; ++i) h = Math.imul(h ^ bytes[i], 16777619) >>> 0;
  return h >>> 0;
}

/**
 * A decoded message in the layout of ros_wire_capture.cc's JSON: byte arrays
 * (uint8[]) as {length, fnv1a32}, other typed arrays as plain arrays.
 */
export function summarize(value) {
  if (value instanceof Uint8Array || value instanceof Int8Array) {
    return { length: value.length, fnv1a32: fnv1a32(value) };
  }
  if (ArrayBuffer.isView(value)) return Array.from(value);
  if (Array.isArray(value)) return value.map(summarize);
  if (value !== null && typeof value === 'object') {
    const out = {};
    for (const [k, v] of Object.entries(value)) out[k] = summarize(v);
    return out;
  }
  return value;
}

/** The first difference between two JSON-like values, as "path: a ≠ b", or null. */
export function firstDifference(actual, expected, where = '') {
  if (typeof expected !== 'object' || expected === null) {
    return Object.is(actual, expected) || actual === expected
      ? null
      : `${where || '(root)'}: decoded ${JSON.stringify(actual)} ≠ sent ${JSON.stringify(expected)}`;
  }
  if (typeof actual !== 'object' || actual === null) {
    return `${where}: decoded ${JSON.stringify(actual)}, sent an object`;
  }
  const keys = new Set([...Object.keys(expected), ...Object.keys(actual)]);
  for (const k of keys) {
    if (!(k in actual)) return `${where}.${k}: missing from the decoded message`;
    if (!(k in expected)) return `${where}.${k}: decoded but not sent`;
    const d = firstDifference(actual[k], expected[k], `${where}.${k}`);
    if (d) return d;
  }
  return null;
}

/**
 * A decoder of `type` ("sensor_msgs/msg/Image") with the standard ROS 2
 * definitions (@foxglove/rosmsg-msgs-common, Humble).
 */
export function standardReader(type) {
  const { MessageReader } = requireWeb('@foxglove/rosmsg2-serialization');
  const { ros2humble } = requireWeb('@foxglove/rosmsg-msgs-common');
  const name = type.replace('/msg/', '/');
  const root = ros2humble[name];
  check(root, `no standard definition of ${type}`);
  return new MessageReader([root, ...Object.values(ros2humble)]);
}

/** A decoder from a full message definition text (MCAP "ros2msg" schema). */
export function schemaReader(text) {
  const { MessageReader } = requireWeb('@foxglove/rosmsg2-serialization');
  const { parse } = requireWeb('@foxglove/rosmsg');
  return new MessageReader(parse(text, { ros2: true }));
}

/** Parses "--key value" pairs into an object. */
export function parseArgs(argv) {
  const args = {};
  for (let i = 0; i + 1 < argv.length; i += 2) args[argv[i].replace(/^--/, '')] = argv[i + 1];
  return args;
}
