// A Foxglove WebSocket client (@foxglove/ws-protocol over the `ws` package) on a live spidar
// session: subscribes to every advertised channel, says `{"subscribed": N}` on stdout, collects
// every message until the server closes, then decodes each with the schema the server advertised
// (@foxglove/rosmsg2-serialization) and compares it with the message of the same topic and time
// in the session's recording (read with @mcap/core). Prints one JSON summary line.
// Usage: node live.mjs ws://HOST:PORT RECORDING.mcap
// It only subscribes, reads (the socket, the recording) and prints; it never writes a file.
import WebSocket from "ws";
import wsProtocol from "@foxglove/ws-protocol";
const { FoxgloveClient } = wsProtocol;
import { allMessages, openRecording, readerFor, plain, say } from "./common.mjs";
import { isDeepStrictEqual } from "node:util";

const [url, recording] = process.argv.slice(2);
const client = new FoxgloveClient({ ws: new WebSocket(url, [FoxgloveClient.SUPPORTED_SUBPROTOCOL]) });
const channels = new Map(); // channel id -> channel
const bySub = new Map(); // subscription id -> channel
const received = [];
let serverInfo = null;
let protocol = null;

client.on("open", () => {});
client.on("serverInfo", (i) => (serverInfo = i));
client.on("advertise", (list) => {
  for (const ch of list) {
    channels.set(ch.id, ch);
    bySub.set(client.subscribe(ch.id), ch);
  }
  say({ subscribed: list.length });
});
client.on("message", ({ subscriptionId, timestamp, data }) => {
  received.push({ ch: bySub.get(subscriptionId), timestamp, data: new Uint8Array(data.buffer, data.byteOffset, data.byteLength).slice() });
});
client.on("error", (e) => say({ error: String(e) }));
const closed = new Promise((resolve) => client.on("close", resolve));
await closed;

const summary = { serverInfo: serverInfo && serverInfo.name, channels: [...channels.values()].map((c) => ({ topic: c.topic, encoding: c.encoding, schemaName: c.schemaName, schemaEncoding: c.schemaEncoding })), received: received.length, perTopic: {}, decodeErrors: [], mismatches: [], matched: 0, recordedFromFirst: 0 };
const rec = await openRecording(recording);
const recorded = await allMessages(rec.reader);
// The recording's schemas are the live channels' schemas.
const recSchemas = {};
for (const ch of rec.reader.channelsById.values()) {
  const sc = rec.reader.schemasById.get(ch.schemaId);
  recSchemas[ch.topic] = { name: sc.name, text: new TextDecoder().decode(sc.data), encoding: sc.encoding, messageEncoding: ch.messageEncoding };
}
summary.schemasDiffer = [...channels.values()].filter((c) => !recSchemas[c.topic] || recSchemas[c.topic].text !== c.schema || recSchemas[c.topic].name !== c.schemaName).map((c) => c.topic);
const index = new Map();
for (const m of recorded) {
  const k = m.topic + "@" + m.logTime;
  if (!index.has(k)) index.set(k, []);
  index.get(k).push(m.value);
}
// The first message received on each topic: a subscription takes effect when the server reads it
// (the rig may already be stepping), and its first message is that topic's newest at that time.
const firstOf = new Map();
for (const r of received) {
  summary.perTopic[r.ch.topic] = (summary.perTopic[r.ch.topic] || 0) + 1;
  let value;
  try {
    value = plain(readerFor(r.ch.schemaName, r.ch.schema).readMessage(r.data));
  } catch (e) {
    summary.decodeErrors.push(r.ch.topic + ": " + e);
    continue;
  }
  const want = index.get(r.ch.topic + "@" + r.timestamp);
  if (want !== undefined && want.some((w) => isDeepStrictEqual(w, value))) {
    summary.matched += 1;
    if (!firstOf.has(r.ch.topic) || r.timestamp < firstOf.get(r.ch.topic)) firstOf.set(r.ch.topic, r.timestamp);
  } else if (summary.mismatches.length < 5) {
    summary.mismatches.push({ topic: r.ch.topic, t: Number(r.timestamp), inRecording: want !== undefined });
  }
}
// What the recording holds of each topic from the first message received on it: the live client
// should have it all, to the end. A topic nothing was received on counts from the latest of the
// topics' first messages (by then every subscription was taken).
const latestFirst = [...firstOf.values()].reduce((a, b) => (b > a ? b : a), null);
summary.recordedFromFirst = latestFirst === null ? 0 : recorded.filter((m) => m.logTime >= (firstOf.has(m.topic) ? firstOf.get(m.topic) : latestFirst)).length;
await rec.close();
say(summary);
