// The connection to the world: one WebSocket to the frames port the page was served with, the
// scene description first, then binary frames and JSON status messages. Reconnects after the
// world restarts; says so through onState. A replay (`spidar replay`) also sends its playback
// state (onPlayback), the reaction study (`spidar study reactions`) its state (onStudy), and both
// take the page's commands (`send`).
//
// Where the frames wait: a page's script runs on the browser's main thread, which also makes the
// pictures; while it does, the browser hands the script no message, so a frame received there
// waits behind the drawing (a software renderer's drawing takes most of a display frame). So
// when the page may share memory with a worker (it is cross-origin isolated: the view serves it
// so, on localhost or over HTTPS), a worker owns the WebSocket and keeps the newest frame in
// shared memory, and the page takes it when it draws (`poll`): the newest frame that came, however
// busy the main thread was. Elsewhere (plain HTTP from another machine) the page receives the
// frames itself, as before.

const MAGIC = 0x31565053; // "SPV1" little-endian

// The shared memory's layout: 32-bit words, the newest slot (index + 1; 0: none), the frames the
// worker received, and per slot its version (odd while the worker writes it), its frame's
// publication number and its length in bytes; then per slot the frame's arrival (f64, ms on the
// wall clock: the worker's `performance.timeOrigin + performance.now()`); then the slots' bytes.
const SLOTS = 3;
const NEWEST = 0;
const RECEIVED = 1;
const SLOT_AT = 2;
const SLOT_WORDS = 3;
const ARRIVALS_AT = 8 * Math.ceil((4 * (SLOT_AT + SLOTS * SLOT_WORDS)) / 8); // bytes
const DATA_AT = ARRIVALS_AT + 8 * SLOTS; // bytes
// Frames' hands kept (at a frame a step, about 0.4 s).
const RING = 128;
const LAYOUT = { SLOTS, NEWEST, RECEIVED, SLOT_AT, SLOT_WORDS, ARRIVALS_AT, DATA_AT, RING };

// The worker's code, started from its own source (the page stays one file). Self-contained: it
// refers to nothing outside itself. Messages in: {url, layout} (the shared memory's layout
// above), {send: text}; out: {state}, {text}, and {shared, slotBytes} whenever it made the shared
// memory (again for a frame bigger than a slot).
function receiver() {
  let L = null;
  let ws = null;
  let url = null;
  let retry = 250;
  let ctrl = null;
  let arrivals = null;
  let bytes = null;
  let slotBytes = 0;
  let newest = -1;
  let published = 0;
  // The scene's frame layout (from its description) and the ring of every frame's hands.
  let frameLayout = null;
  let ringCount = null;
  let ring = null;
  const share = (need) => {
    slotBytes = 8 * Math.ceil(Math.max(65536, 2 * need) / 8);
    const sab = new SharedArrayBuffer(L.DATA_AT + L.SLOTS * slotBytes);
    ctrl = new Int32Array(sab, 0, L.ARRIVALS_AT / 4);
    arrivals = new Float64Array(sab, L.ARRIVALS_AT, L.SLOTS);
    bytes = new Uint8Array(sab, L.DATA_AT);
    newest = -1;
    if (!ring) {
      const hands = new SharedArrayBuffer(8 + 8 * L.RING * 7);
      ringCount = new Int32Array(hands, 0, 1);
      ring = new Float64Array(hands, 8, L.RING * 7);
    }
    postMessage({ shared: sab, slotBytes, hands: ring.buffer });
  };
  // Every frame's hands by their tick's wall-clock time (7 numbers: the time, then both hands'
  // positions), for the headset's velocity and its judging of the drawn grips.
  const keepHands = (data) => {
    const F = frameLayout;
    if (!F || F.stamp_at === undefined || data.byteLength < 4 * (F.hands_at + 2 * F.hand_floats)) return;
    const wallMs = new DataView(data, 4 * (F.stamp_at + 4), 8).getFloat64(0, true);
    if (!(wallMs > 0)) return;
    const f = new Float32Array(data, 0, F.hands_at + 2 * F.hand_floats);
    const n = ringCount[0];
    const o = (n % L.RING) * 7;
    ring[o] = wallMs;
    for (let h = 0; h < 2; h++) for (let i = 0; i < 3; i++) ring[o + 1 + 3 * h + i] = f[F.hands_at + h * F.hand_floats + i];
    Atomics.store(ringCount, 0, n + 1);
  };
  const store = (data, atMs) => {
    const src = new Uint8Array(data);
    if (!ctrl || src.length > slotBytes) share(src.length);
    const k = (newest + 1) % L.SLOTS;
    const o = L.SLOT_AT + k * L.SLOT_WORDS;
    Atomics.add(ctrl, o, 1); // odd: being written
    bytes.set(src, k * slotBytes);
    ctrl[o + 1] = ++published;
    ctrl[o + 2] = src.length;
    arrivals[k] = atMs;
    Atomics.add(ctrl, o, 1); // even: whole
    newest = k;
    Atomics.store(ctrl, L.NEWEST, k + 1);
    Atomics.add(ctrl, L.RECEIVED, 1);
    keepHands(data);
  };
  const open = () => {
    ws = new WebSocket(url);
    ws.binaryType = 'arraybuffer';
    ws.onopen = () => { retry = 250; postMessage({ state: 'connected' }); };
    ws.onmessage = (ev) => {
      if (typeof ev.data === 'string') {
        if (ev.data.includes('"scene"')) {
          try {
            const m = JSON.parse(ev.data);
            if (m.type === 'scene') frameLayout = m.layout;
          } catch { /* the page reports what does not parse */ }
        }
        postMessage({ text: ev.data });
        return;
      }
      store(ev.data, performance.timeOrigin + performance.now());
    };
    ws.onclose = () => {
      postMessage({ state: 'disconnected' });
      setTimeout(open, retry);
      retry = Math.min(retry * 2, 4000);
    };
    ws.onerror = () => ws.close();
  };
  onmessage = (ev) => {
    const m = ev.data;
    if (m.url && !url) { url = m.url; L = m.layout; open(); }
    else if (m.send !== undefined && ws && ws.readyState === WebSocket.OPEN) ws.send(m.send);
  };
}

function framesUrl() {
  const meta = document.querySelector('meta[name="spidar-ws-port"]');
  const port = meta ? meta.content : '';
  const host = location.hostname || '127.0.0.1';
  // A page served over HTTPS (a headset on the network) may only open secure WebSockets.
  const scheme = location.protocol === 'https:' ? 'wss' : 'ws';
  return `${scheme}://${host.includes(':') ? `[${host}]` : host}:${port}/`;
}

// Whether a worker can hand the page its frames through shared memory.
export function canShareFrames() {
  return typeof SharedArrayBuffer !== 'undefined' && typeof Worker !== 'undefined' && self.crossOriginIsolated === true;
}

// Connects. Handlers: onScene, onRig, onStatus, onPlayback, onStudy (JSON messages), onState
// ('connected' / 'disconnected'), onFrame(buffer, layoutId, seq, arrivedMs): a frame (arrivedMs:
// when it came, on the page's clock); holds(buffer): whether the page still holds a frame's buffer
// (with a worker, frames come in a few buffers used again once the page lets them go; without
// `holds` every frame comes in a new one). Returns { send(cmd), poll(), received(), shared }: the page
// calls `poll` when it is about to draw, which hands it the newest frame that came since (with a
// worker; without one frames are handed over as they come and `poll` does nothing); `received`
// counts the frames that came, `newestSeq` is the newest one's sequence number, `hands` the
// newest frames' hands by their ticks' times (with a worker: every frame's; else null).
export function connect(handlers, { worker = canShareFrames() } = {}) {
  const text = (t) => {
    const m = JSON.parse(t);
    const h = { scene: handlers.onScene, rig: handlers.onRig, status: handlers.onStatus, playback: handlers.onPlayback, study: handlers.onStudy }[m.type];
    if (h) h(m);
  };
  const frame = (data, arrivedMs) => {
    if (data.byteLength < 16) return;
    const words = new Uint32Array(data, 0, 4);
    if (words[0] !== MAGIC) return;
    handlers.onFrame(data, words[1], words[2], arrivedMs);
  };
  const holds = handlers.holds ?? (() => true);
  return worker ? viaWorker(handlers.onState, text, frame, holds) : direct(handlers.onState, text, frame);
}

// The page's own WebSocket: frames handed over as the main thread gets them.
function direct(onState, text, frame) {
  const url = framesUrl();
  let retry = 250;
  let ws = null;
  let received = 0;
  let newest = null;
  const open = () => {
    ws = new WebSocket(url);
    ws.binaryType = 'arraybuffer';
    ws.onopen = () => { retry = 250; onState('connected'); };
    ws.onmessage = (ev) => {
      if (typeof ev.data === 'string') { text(ev.data); return; }
      received++;
      if (ev.data.byteLength >= 16) newest = new Uint32Array(ev.data, 0, 4)[2];
      frame(ev.data, performance.now());
    };
    ws.onclose = () => {
      onState('disconnected');
      setTimeout(open, retry);
      retry = Math.min(retry * 2, 4000);
    };
    ws.onerror = () => ws.close();
  };
  open();
  return {
    shared: false,
    newestSeq: () => newest,
    // A command to the world (JSON); dropped while not connected.
    send: (cmd) => {
      if (ws && ws.readyState === WebSocket.OPEN) ws.send(JSON.stringify(cmd));
    },
    poll: () => {},
    received: () => received,
    hands: () => null,
  };
}

// A worker's WebSocket: the newest frame in shared memory, taken by `poll`.
function viaWorker(onState, text, frame, holds) {
  const src = `(${receiver.toString()})();`;
  const w = new Worker(URL.createObjectURL(new Blob([src], { type: 'text/javascript' })));
  let ctrl = null;
  let bytes = null;
  let arrivals = null;
  let slotBytes = 0;
  let seen = 0; // the publication number of the newest frame handed over
  let ringCount = null;
  let ring = null;
  // The frames handed over, in three buffers used in turn: one the page still holds (`holds`: its
  // newest frame, the frame it drew) is not written again. Each is resized to its frame's length
  // (frames with more contacts are longer); a new one only when that cannot be done, or when the
  // page holds all three. `made` counts the buffers made.
  const buffers = [null, null, null];
  let turn = 0;
  let made = 0;
  const make = (len) => {
    made++;
    return typeof ArrayBuffer.prototype.resize === 'function'
      ? new ArrayBuffer(len, { maxByteLength: Math.max(len, slotBytes) })
      : new ArrayBuffer(len);
  };
  const free = (len) => {
    for (let j = 1; j <= buffers.length; j++) {
      const c = (turn + j) % buffers.length;
      const b = buffers[c];
      if (!b || !holds(b)) {
        if (b && b.resizable && b.maxByteLength >= len) b.resize(len);
        else if (!b || b.byteLength !== len) buffers[c] = make(len);
        turn = c;
        return buffers[c];
      }
    }
    return make(len);
  };
  w.onmessage = (ev) => {
    const m = ev.data;
    if (m.shared) {
      ringCount = new Int32Array(m.hands, 0, 1);
      ring = new Float64Array(m.hands, 8, RING * 7);
      ctrl = new Int32Array(m.shared, 0, ARRIVALS_AT / 4);
      arrivals = new Float64Array(m.shared, ARRIVALS_AT, SLOTS);
      bytes = new Uint8Array(m.shared, DATA_AT);
      slotBytes = m.slotBytes;
      seen = 0;
    } else if (m.state) onState(m.state);
    else if (m.text !== undefined) text(m.text);
  };
  w.postMessage({ url: framesUrl(), layout: LAYOUT });
  // The newest whole frame, if newer than the last one handed over: a copy (the worker writes the
  // slot again two frames later) in a buffer the page does not hold, and its arrival on the page's
  // clock; else null.
  const newest = () => {
    for (let tries = 0; tries < 4; tries++) {
      const k = Atomics.load(ctrl, NEWEST) - 1;
      if (k < 0) return null;
      const o = SLOT_AT + k * SLOT_WORDS;
      const v = Atomics.load(ctrl, o);
      if (v & 1) continue;
      const number = ctrl[o + 1];
      if (number <= seen) return null;
      const len = ctrl[o + 2];
      const into = free(len);
      new Uint8Array(into).set(bytes.subarray(k * slotBytes, k * slotBytes + len));
      const at = arrivals[k];
      if (Atomics.load(ctrl, o) !== v) continue; // overwritten while copied: again
      seen = number;
      return { data: into, arrivedMs: at - performance.timeOrigin };
    }
    return null;
  };
  return {
    shared: true,
    // The sequence number of the newest frame that came (taken by `poll` or not), or null.
    newestSeq: () => {
      const k = ctrl ? Atomics.load(ctrl, NEWEST) - 1 : -1;
      return k < 0 ? null : new DataView(bytes.buffer, bytes.byteOffset + k * slotBytes + 8, 4).getUint32(0, true);
    },
    send: (cmd) => w.postMessage({ send: JSON.stringify(cmd) }),
    poll: () => {
      if (!ctrl) return;
      const f = newest();
      if (f) frame(f.data, f.arrivedMs);
    },
    received: () => (ctrl ? Atomics.load(ctrl, RECEIVED) : 0),
    buffersMade: () => made,
    // The hands of the newest `k` frames that came (at most half the ring: the worker does not
    // reach them while they are read), oldest first: [{ wallMs, p: [6] }].
    hands: (k = RING / 2) => {
      if (!ring) return null;
      const n = Atomics.load(ringCount, 0);
      const out = [];
      for (let j = Math.max(0, n - Math.min(k, RING / 2)); j < n; j++) {
        const o = (j % RING) * 7;
        out.push({ wallMs: ring[o], p: Array.from(ring.subarray(o + 1, o + 7)) });
      }
      return out;
    },
  };
}
