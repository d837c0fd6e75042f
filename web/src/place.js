// The placement targets (`?place=1`, for `spidar place`): numbered rings at fixed fractions of the
// page, which full-screen on the rig's screen are fractions of the screen's width and height from
// its lower-left corner (calib/src/display.rs's TARGETS, in the same order). The person holds the
// right grip's centre on each in turn, the ball touching the screen.

export const TARGETS = [[0.15, 0.15], [0.85, 0.15], [0.85, 0.85], [0.15, 0.85], [0.5, 0.5]];

export function showTargets(container) {
  const layer = document.createElement('div');
  layer.style.cssText = 'position:absolute;inset:0;pointer-events:none;';
  TARGETS.forEach(([a, b], i) => {
    const t = document.createElement('div');
    t.className = 'target';
    t.dataset.target = String(i + 1);
    t.style.cssText = `position:absolute;left:${a * 100}%;top:${(1 - b) * 100}%;width:64px;height:64px;margin:-32px 0 0 -32px;
      border:3px solid #ffd040;border-radius:50%;box-sizing:border-box;color:#ffd040;font:bold 20px system-ui;
      display:flex;align-items:center;justify-content:center;background:radial-gradient(circle,#ffd040 0 4px,transparent 5px);`;
    const n = document.createElement('span');
    n.textContent = String(i + 1);
    n.style.cssText = 'position:absolute;top:-28px;';
    t.append(n);
    layer.append(t);
  });
  container.append(layer);
  return layer;
}
