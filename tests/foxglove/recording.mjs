// Checks a spidar recording as Foxglove opens it, with Foxglove's own libraries (@mcap/core,
// @foxglove/rosmsg, @foxglove/rosmsg2-serialization, @foxglove/schemas):
// - the time range: the smallest chunk start (what Foxglove and Lichtblick take as the start)
//   is the first message's time, and the range is the session's (not 1970);
// - a seek: at points across the range, the newest message of each scene topic at or before the
//   point (all a 3D panel keeps after a seek) holds every entity ever drawn on that topic, in
//   frames the newest transforms at that point know, under one root;
// - the root is z-up: the world (y up) hangs below it turned +90 degrees about x;
// - labels stand above their bodies: a label's frame sits at its body, unturned, the text above;
// - the Foxglove types' field lists are the released ones (@foxglove/schemas' ROS 2 definitions).
// Usage: node recording.mjs FILE.mcap [seeks]. Prints one JSON line.
// It only reads the file and prints; it never writes.
import { openRecording, allMessages, say } from "./common.mjs";
import { parse } from "@foxglove/rosmsg";
import schemasInternal from "@foxglove/schemas/internal.js";
const schemas = schemasInternal;

const [path, seeksArg] = process.argv.slice(2);
const seeks = Number(seeksArg || 50);
const { reader, close } = await openRecording(path);
const out = { chunks: reader.chunkIndexes.length, problems: [] };
const bad = (p) => out.problems.length < 20 && out.problems.push(p);

// Time range, as Foxglove's player computes it.
let start = null, end = null;
for (const c of reader.chunkIndexes) {
  if (start === null || c.messageStartTime < start) start = c.messageStartTime;
  if (end === null || c.messageEndTime > end) end = c.messageEndTime;
}
const messages = await allMessages(reader);
const firstTime = messages.length ? messages[0].logTime : null;
let metaStart = null;
for await (const m of reader.readMetadata({ name: "spidar" })) metaStart = BigInt(m.metadata.get("start_unix_ns"));
out.startNs = Number(start);
out.firstMessageNs = Number(firstTime);
out.sessionStartNs = Number(metaStart);
out.durationS = Number(end - start) / 1e9;
out.startYear = new Date(Number(start / 1000000n)).getUTCFullYear();

// Released field lists: every Foxglove type named in the recording's schemas.
const released = (name) => {
  const s = schemas.foxgloveMessageSchemas[name];
  return parse(schemas.generateRosMsgMergedSchema(s, { rosVersion: 2 }), { ros2: true });
};
const norm = (defs, root) => Object.fromEntries(defs.map((d) => [(d.name ?? root).replace("/msg/", "/"), d.definitions.filter((f) => !f.isConstant).map((f) => `${f.type}${f.isArray ? "[]" : ""} ${f.name}`).join("; ")]));
out.fieldLists = {};
for (const ch of reader.channelsById.values()) {
  const sc = reader.schemasById.get(ch.schemaId);
  if (!sc.name.startsWith("foxglove_msgs/")) continue;
  const ours = norm(parse(new TextDecoder().decode(sc.data), { ros2: true }), sc.name);
  const theirs = norm(released(sc.name.split("/").pop()), sc.name);
  for (const [type, fields] of Object.entries(theirs)) {
    const same = ours[type] === undefined || ours[type] === fields;
    out.fieldLists[type] = same && ours[type] !== undefined ? "released" : (ours[type] === undefined ? "unused" : "differs");
    if (!same) bad(`${type}: ours [${ours[type]}], released [${fields}]`);
  }
}

// Seeks.
const sceneTopics = ["/world/scene", "/world/labels", "/world/skeletons"];
const everIds = Object.fromEntries(sceneTopics.map((t) => [t, new Set()]));
for (const m of messages) if (everIds[m.topic]) for (const e of m.value.entities) everIds[m.topic].add(e.id);
out.entities = Object.fromEntries(sceneTopics.map((t) => [t, everIds[t].size]));
const newest = (topic, t) => {
  let best = null;
  for (const m of messages) {
    if (m.topic !== topic || m.logTime > t) continue;
    best = m;
  }
  return best;
};
out.seeks = 0;
const hasWorld = [...reader.channelsById.values()].some((c) => c.topic === "/world/tf");
for (let i = 0; hasWorld && i < seeks; i++) {
  const t = start + ((end - start) * BigInt(i)) / BigInt(Math.max(1, seeks - 1));
  const tf = newest("/world/tf", t);
  if (!tf) { bad(`seek ${t}: no transforms`); continue; }
  const frames = new Map(tf.value.transforms.map((x) => [x.child_frame_id, x]));
  const roots = new Set(tf.value.transforms.map((x) => x.parent_frame_id).filter((p) => !frames.has(p)));
  if (roots.size !== 1 || !roots.has("z_up")) bad(`seek ${t}: roots ${[...roots]}`);
  const up = frames.get("world");
  const h = Math.SQRT1_2;
  if (!up || up.parent_frame_id !== "z_up" || Math.abs(up.rotation.x - h) > 1e-12 || Math.abs(up.rotation.w - h) > 1e-12) bad(`seek ${t}: world is not the z-up root turned +90 degrees about x`);
  for (const topic of sceneTopics) {
    if (everIds[topic].size === 0) continue;
    const m = newest(topic, t);
    const ids = new Set(m ? m.value.entities.map((e) => e.id) : []);
    const missing = [...everIds[topic]].filter((id) => !ids.has(id));
    if (missing.length) bad(`seek ${t}: ${topic} lacks ${missing.length} of ${everIds[topic].size} (${missing.slice(0, 3)})`);
    for (const e of m ? m.value.entities : []) {
      if (e.frame_id !== "world" && !frames.has(e.frame_id)) bad(`seek ${t}: ${e.id} in unknown frame ${e.frame_id}`);
    }
  }
  // Labels above their bodies, in the world's up (+y).
  const labels = newest("/world/labels", t);
  for (const e of labels ? labels.value.entities : []) {
    const f = frames.get(e.frame_id);
    const q = f.rotation;
    const unturned = q.x === 0 && q.y === 0 && q.z === 0 && q.w === 1 && f.parent_frame_id === "world";
    const y = e.texts[0].pose.position.y;
    const bodyAt = [...frames.values()].some((b) => b !== f && b.parent_frame_id === "world" && b.child_frame_id !== "link" && !b.child_frame_id.startsWith("label/") && b.translation.x === f.translation.x && b.translation.y === f.translation.y && b.translation.z === f.translation.z);
    if (!unturned || !(y > 0.1) || !bodyAt) bad(`seek ${t}: label ${e.id} not above its body (unturned ${unturned}, +${y} m, at a body ${bodyAt})`);
  }
  out.seeks += 1;
}
await close();
say(out);
