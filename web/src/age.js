// How late the picture is: every frame carries the world step, the rig tick whose hand sample it
// shows and that tick's wall-clock time (its stamp); when the page draws a frame for the first
// time it reports it back over the WebSocket with its age, from that tick to now on this
// machine's wall clock, and how far behind the tick the drawn hands are (less when the headset
// extrapolates them). The world keeps the reports (the status's `picture_age`, `spidar bench
// view`). A replay's frames carry no wall-clock time and are not reported.

// The frame's stamp: step, tick, the tick's wall-clock time in ms (0: not known); null for a
// description without a stamp (an older recording).
export function stamp(f, layout) {
  if (layout.stamp_at === undefined) return null;
  const w = new Uint32Array(f.buffer, f.byteOffset, layout.stamp_at + 6);
  const at = layout.stamp_at;
  const wall = new DataView(f.buffer, f.byteOffset + 4 * (at + 4), 8).getFloat64(0, true);
  return { step: w[at] + w[at + 1] * 2 ** 32, tick: w[at + 2] + w[at + 3] * 2 ** 32, wallMs: wall };
}

export const wallNowMs = () => performance.timeOrigin + performance.now();

export class AgeReporter {
  constructor(send) {
    this.send = send;
    this.last = null; // the newest report, for tests and the HUD
    this.reports = 0;
  }

  // `frame` was just drawn for the first time (seq, stamp); `leadMs`: how far ahead of the
  // frame's tick the drawn hands were extrapolated (0: not).
  // `drawMs`: how long the drawing itself took (the page's rendering, which a software renderer
  // makes long).
  // `arrivedMs`, `drawStartMs` (page clock, performance.now()): when the frame's message came and
  // when its drawing began, which split the age into the way here (the tick to the message's
  // arrival: the world, the link, the broadcaster and the socket), the wait for the browser's next
  // frame, and the drawing.
  // `judged`: how far an earlier picture's grips were from the measured hands when it was shown
  // ({ err, still } mm: as drawn, and as the newest frame had them; null: none judged since).
  drawn(seq, st, xr, leadMs = 0, drawMs = 0, arrivedMs = null, drawStartMs = null, judged = null) {
    if (!st || !(st.wallMs > 0)) return;
    const age = wallNowMs() - st.wallMs;
    this.last = { type: 'drawn', seq, step: st.step, tick: st.tick, age_ms: age, hand_lag_ms: age - leadMs, draw_ms: drawMs, xr };
    if (arrivedMs !== null && drawStartMs !== null) {
      this.last.arrive_ms = performance.timeOrigin + arrivedMs - st.wallMs;
      this.last.wait_ms = drawStartMs - arrivedMs;
    }
    if (judged) {
      this.last.hand_err_mm = judged.err;
      this.last.hand_still_err_mm = judged.still;
    }
    this.reports++;
    this.send(this.last);
  }
}
