// Shared by the Foxglove checks: open a recording with Foxglove's own MCAP reader (@mcap/core,
// zstd from @mcap/support) and decode messages with Foxglove's own ROS 2 parser and CDR reader
// (@foxglove/rosmsg, @foxglove/rosmsg2-serialization), as Foxglove's player does.
// Never writes anything: the Rust test that runs these reads what they print.
import { open } from "node:fs/promises";
import { McapIndexedReader } from "@mcap/core";
import { FileHandleReadable } from "@mcap/nodejs";
import { loadDecompressHandlers } from "@mcap/support";
import { parse } from "@foxglove/rosmsg";
import { MessageReader } from "@foxglove/rosmsg2-serialization";

export async function openRecording(path) {
  const handle = await open(path, "r");
  const reader = await McapIndexedReader.Initialize({
    readable: new FileHandleReadable(handle),
    decompressHandlers: await loadDecompressHandlers(),
  });
  return { reader, close: () => handle.close() };
}

const readers = new Map();
/** A CDR reader for a ros2msg schema's text. */
export function readerFor(schemaName, schemaText) {
  const key = schemaName + "\n" + schemaText;
  if (!readers.has(key)) {
    readers.set(key, new MessageReader(parse(schemaText, { ros2: true })));
  }
  return readers.get(key);
}

/** Plain JSON-comparable value (typed arrays and bigints as numbers). */
export function plain(v) {
  if (typeof v === "bigint") return Number(v);
  if (ArrayBuffer.isView(v)) return Array.from(v);
  if (Array.isArray(v)) return v.map(plain);
  if (v && typeof v === "object") {
    const o = {};
    for (const [k, x] of Object.entries(v)) o[k] = plain(x);
    return o;
  }
  return v;
}

/** Every message of the recording: [{topic, logTime, value}] in log-time order. */
export async function allMessages(reader) {
  const out = [];
  for await (const m of reader.readMessages()) {
    const ch = reader.channelsById.get(m.channelId);
    const sc = reader.schemasById.get(ch.schemaId);
    const text = new TextDecoder().decode(sc.data);
    out.push({ topic: ch.topic, logTime: m.logTime, value: plain(readerFor(sc.name, text).readMessage(m.data)) });
  }
  return out;
}

export function say(obj) {
  process.stdout.write(JSON.stringify(obj) + "\n");
}
