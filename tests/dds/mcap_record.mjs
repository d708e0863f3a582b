// `craftscan-record --mcap`, read back by an independent reader. Reads the
// recording craftscan_ros_wire_capture made of a live scan (--out; CTest
// runs that first, fixture ros_capture) with @mcap/core and checks:
//  - the indexed reader accepts the file: header profile "ros2", footer,
//    summary (its CRC checked by @mcap/core), statistics whose per-channel
//    counts match the messages; the data section CRC recomputed here;
//  - each channel: ROS 2 topic name, message encoding "cdr", a "ros2msg"
//    schema named as ROS 2 names the type;
//  - the streaming reader (CRCs validated) yields every message, and each
//    decodes with @foxglove/rosmsg2-serialization from the schema text in
//    the file itself, consuming every byte but Cyclone's declared padding;
//  - the messages per topic are those the test's own readers took off the
//    wire, byte for byte and in order.
//
//   node mcap_record.mjs --out DIR
import fs from 'node:fs';
import path from 'node:path';

import { check, CheckError, parseArgs, requireWeb, schemaReader } from './ros_lib.mjs';

const args = parseArgs(process.argv.slice(2));
check(args.out, 'usage: node mcap_record.mjs --out DIR');

async function main() {
  const start = Date.now();
  const { McapIndexedReader, McapStreamReader } = requireWeb('@mcap/core');
  const { crc32 } = requireWeb('@foxglove/crc');
  const manifest = JSON.parse(fs.readFileSync(path.join(args.out, 'expected.json'), 'utf8'));
  const file = path.join(args.out, 'recording.mcap');
  const bytes = new Uint8Array(fs.readFileSync(file));

  // The summary, through the reader that seeks.
  const readable = {
    size: async () => BigInt(bytes.length),
    read: async (offset, length) => bytes.subarray(Number(offset), Number(offset + length)),
  };
  const indexed = await McapIndexedReader.Initialize({ readable });
  check(indexed.header.profile === 'ros2', `profile '${indexed.header.profile}'`);
  check(indexed.statistics, 'no Statistics record in the summary');
  // DataEnd (13 bytes) ends the data section; its CRC covers all before it.
  const dataEnd = Number(indexed.footer.summaryStart) - 13;
  check(bytes[dataEnd] === 0x0f, 'no DataEnd record before the summary');
  const view = new DataView(bytes.buffer, bytes.byteOffset, bytes.byteLength);
  const dataCrc = view.getUint32(dataEnd + 9, true);
  check(dataCrc !== 0 && dataCrc === crc32(bytes.subarray(0, dataEnd)),
        `data section CRC ${dataCrc} ≠ ${crc32(bytes.subarray(0, dataEnd))}`);
  const channelTopic = new Map();
  for (const [id, channel] of indexed.channelsById) {
    const schema = indexed.schemasById.get(channel.schemaId);
    check(channel.messageEncoding === 'cdr', `${channel.topic}: message encoding ${channel.messageEncoding}`);
    check(schema && schema.encoding === 'ros2msg' && /^\w+\/msg\/\w+$/.test(schema.name),
          `${channel.topic}: schema ${schema?.name} (${schema?.encoding})`);
    check(channel.topic.startsWith('/'), `channel ${channel.topic}: not a ROS 2 name`);
    check(channel.metadata.get('offered_qos_profiles')?.includes('reliability: 1'),
          `${channel.topic}: no offered_qos_profiles`);
    channelTopic.set(id, channel.topic);
  }

  // Every message, through the streaming reader, decoded with the schema
  // the file carries.
  const stream = new McapStreamReader({ validateCrcs: true });
  stream.append(bytes);
  const schemas = new Map();
  const channels = new Map();
  const readers = new Map();
  const messages = new Map();  // topic → [bytes]
  let footer = false;
  for (let record; (record = stream.nextRecord());) {
    if (record.type === 'Schema') schemas.set(record.id, record);
    if (record.type === 'Channel') channels.set(record.id, record);
    if (record.type === 'Footer') footer = true;
    if (record.type !== 'Message') continue;
    const channel = channels.get(record.channelId);
    check(channel, `a message on unknown channel ${record.channelId}`);
    if (!readers.has(channel.schemaId)) {
      const schema = schemas.get(channel.schemaId);
      readers.set(channel.schemaId, schemaReader(new TextDecoder().decode(schema.data)));
    }
    const reader = readers.get(channel.schemaId);
    const decoded = reader.readMessage(record.data);
    const padding = record.data[3] & 3;
    check(bytes.length > 0 && record.data.length - reader.lastReadByteLength() === padding,
          `${channel.topic} message ${record.sequence}: bytes left after decoding with its schema`);
    check(decoded.header !== undefined || decoded.transforms !== undefined,
          `${channel.topic}: decoded to ${Object.keys(decoded)}`);
    if (!messages.has(channel.topic)) messages.set(channel.topic, []);
    messages.get(channel.topic).push(record.data);
  }
  check(footer && stream.done(), 'the stream does not end with a footer');

  // Counts per topic: what the test's readers took, and the statistics.
  const counts = Object.fromEntries([...messages].map(([t, list]) => [t, list.length]));
  console.log('messages per topic:', JSON.stringify(counts));
  for (const [topic, want] of Object.entries(manifest.topic_counts)) {
    check((counts[topic] ?? 0) === want, `${topic}: ${counts[topic] ?? 0} messages recorded, ${want} sent`);
  }
  check(Object.keys(counts).length === Object.keys(manifest.topic_counts).length,
        `recorded topics ${Object.keys(counts)} ≠ sent ${Object.keys(manifest.topic_counts)}`);
  let total = 0;
  for (const [id, n] of indexed.statistics.channelMessageCounts) {
    check((counts[channelTopic.get(id)] ?? 0) === Number(n), `statistics: ${channelTopic.get(id)} ${n}`);
    total += Number(n);
  }
  check(Number(indexed.statistics.messageCount) === total, 'statistics: message count');

  // Byte for byte: the k-th message of a topic is the k-th sample taken off the wire.
  const wire = new Map();
  for (const sample of manifest.samples) {
    const topic = sample.topic.slice(2);
    if (!wire.has(topic)) wire.set(topic, []);
    wire.get(topic).push(sample.file);
  }
  for (const [topic, files] of wire) {
    files.forEach((name, k) => {
      const sent = fs.readFileSync(path.join(args.out, name));
      check(Buffer.compare(sent, Buffer.from(messages.get(topic)[k])) === 0,
            `${topic} message ${k} differs from the sample on the wire (${name})`);
    });
  }
  console.log(`ros_mcap: ${total} messages on ${channelTopic.size} channels decoded from ` +
              `${(bytes.length / 1e6).toFixed(1)} MB in ${((Date.now() - start) / 1000).toFixed(1)} s`);
}

main().catch((e) => {
  console.error(e instanceof CheckError ? `ros_mcap: FAILED: ${e.message}` : e);
  process.exit(1);
});
