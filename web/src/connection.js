// The connection to the world: one WebSocket to the frames port the page was served with, the
// scene description first, then binary frames and JSON status messages. Reconnects after the
// world restarts; says so through onState. A replay (`spidar replay`) also sends its playback
// state (onPlayback), the reaction study (`spidar study reactions`) its state (onStudy), and both
// take the page's commands (`send`).

const MAGIC = 0x31565053; // "SPV1" little-endian

export function connect({ onScene, onRig, onStatus, onFrame, onState, onPlayback, onStudy }) {
  const meta = document.querySelector('meta[name="spidar-ws-port"]');
  const port = meta ? meta.content : '';
  const host = location.hostname || '127.0.0.1';
  // A page served over HTTPS (a headset on the network) may only open secure WebSockets.
  const scheme = location.protocol === 'https:' ? 'wss' : 'ws';
  const url = `${scheme}://${host.includes(':') ? `[${host}]` : host}:${port}/`;
  let retry = 250;
  let ws = null;
  const open = () => {
    ws = new WebSocket(url);
    ws.binaryType = 'arraybuffer';
    ws.onopen = () => { retry = 250; onState('connected'); };
    ws.onmessage = (ev) => {
      if (typeof ev.data === 'string') {
        const m = JSON.parse(ev.data);
        if (m.type === 'scene') onScene(m);
        else if (m.type === 'rig') onRig(m);
        else if (m.type === 'status') onStatus(m);
        else if (m.type === 'playback' && onPlayback) onPlayback(m);
        else if (m.type === 'study' && onStudy) onStudy(m);
        return;
      }
      const words = new Uint32Array(ev.data, 0, 4);
      if (words[0] !== MAGIC) return;
      onFrame(ev.data, words[1], words[2]);
    };
    ws.onclose = () => {
      onState('disconnected');
      setTimeout(open, retry);
      retry = Math.min(retry * 2, 4000);
    };
    ws.onerror = () => ws.close();
  };
  open();
  // A command to the replay (JSON); dropped while not connected.
  return {
    send: (cmd) => {
      if (ws && ws.readyState === WebSocket.OPEN) ws.send(JSON.stringify(cmd));
    },
  };
}
