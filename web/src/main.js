// The live view's page: connects to the world, builds the scene graph from the world's
// description, moves it with every frame, draws it from the user's eye or an orbit camera, and
// shows the heads-up display. `window.spidarView` lets tests (and a curious operator's console)
// look at what is drawn.
import * as THREE from 'three';
import { CSS2DRenderer } from 'three/addons/renderers/CSS2DRenderer.js';
import { connect } from './connection.js';
import { World } from './world.js';
import { Crowd } from './crowd.js';
import { Humanoids } from './humanoid.js';
import { Rig } from './rig.js';
import { Cameras, toggleFullScreen } from './cameras.js';
import { Hud } from './hud.js';
import { Playback } from './playback.js';
import { Study } from './study.js';
import { AgeReporter, stamp } from './age.js';
import { showTargets } from './place.js';
import { Headset, Interpolator, MAX_LEAD_MS } from './xr.js';
import { lambertShading, useLambert } from './materials.js';

const params = new URLSearchParams(location.search);

// The name of the WebGL renderer if it is a software one, else null.
function softwareRenderer() {
  try {
    const gl = document.createElement('canvas').getContext('webgl2') || document.createElement('canvas').getContext('webgl');
    if (!gl) return null;
    const info = gl.getExtension('WEBGL_debug_renderer_info');
    const name = String(gl.getParameter(info ? info.UNMASKED_RENDERER_WEBGL : gl.RENDERER));
    const lose = gl.getExtension('WEBGL_lose_context');
    if (lose) lose.loseContext();
    return /swiftshader|llvmpipe|softpipe|software/i.test(name) ? name : null;
  } catch {
    return null;
  }
}
const container = document.getElementById('view');
// A software WebGL (no GPU: SwiftShader, llvmpipe) pays for every pixel on the CPU, and the
// browser hands the page its frames only as fast as it finishes pictures: there the page draws
// without multisampling, at one pixel per CSS pixel and with Lambert shading (materials.js), which
// makes each picture less than half as costly and the picture younger (docs/view.md, the
// picture's age). `?aa=1|0` and `?shading=standard|lambert` choose.
const softwareGl = softwareRenderer();
const antialias = params.has('aa') ? params.get('aa') !== '0' : !softwareGl;
useLambert(params.has('shading') ? params.get('shading') === 'lambert' : !!softwareGl);
const renderer = new THREE.WebGLRenderer({ antialias, preserveDrawingBuffer: true });
renderer.setPixelRatio(softwareGl ? 1 : Math.min(window.devicePixelRatio || 1, 2));
container.appendChild(renderer.domElement);
const labelRenderer = new CSS2DRenderer();
labelRenderer.domElement.style.position = 'absolute';
labelRenderer.domElement.style.top = '0';
labelRenderer.domElement.style.pointerEvents = 'none';
if (params.get('labels') === '0') labelRenderer.domElement.style.display = 'none';
container.appendChild(labelRenderer.domElement);

const scene = new THREE.Scene();
scene.background = new THREE.Color(0x1c1e22);
scene.add(new THREE.HemisphereLight(0xdfe8ff, 0x3a3530, 1.6));
const sun = new THREE.DirectionalLight(0xffffff, 1.6);
sun.position.set(2, 5, 3);
scene.add(sun);

const cameras = new Cameras(renderer.domElement);
const rig = new Rig(scene);
// The headset (WebXR), registered against the grips as drawn.
const headset = new Headset(renderer, scene, {
  grips: () => rig.grips.map((g) => (g.visible ? g.position.toArray() : null)),
  onChange: () => { labelRenderer.domElement.style.display = headset.session || params.get('labels') === '0' ? 'none' : ''; },
});
headset.showMarkers(params.get('xrmarkers') !== '0');
const hud = new Hud(document.getElementById('hud'), {
  onCamera: (c) => { cameraChosen = true; setCamera(c); },
  onFullScreen: toggleFullScreen,
  onToggle: (t) => toggleRig(t),
});
// The rig's toggles (HUD buttons, keys `w` and `n`): the feasible workspace, the near strings.
function toggleRig(t) {
  if (t === 'workspace') rig.setWorkspaceShown(!rig.showWorkspace);
  else if (t === 'near') rig.setNearShown(!rig.showNear);
  hud.setToggle('workspace', rig.showWorkspace);
  hud.setToggle('near', rig.showNear);
}
if (params.get('hud') === '0') document.getElementById('hud').style.display = 'none';
if (params.get('place') === '1') showTargets(document.body);

let desc = null;
let world = null;
let crowd = null;
let people = null;
// Bodies as people (the default) or as their collision shapes (`?bodies=shapes`, key `b`).
let asPeople = params.get('bodies') !== 'shapes';
let root = null;
let rigInfo = null;
let status = null;
let connection = 'connecting';
let latest = null; // { f: Float32Array, seq, t }
let applied = null;
let reported = null; // the newest frame whose drawing was reported (its age)
let paused = false;
let framesReceived = 0;
let rateCount = 0; // frames received when the HUD's rate was last shown
let rateSince = performance.now();
let renders = 0;
const renderWaiters = []; // [the render count to wait for, its promise's resolve]
let playback = null; // the playback bar, when the page shows a replay
let study = null; // the reaction study's panel, when the page serves one
// Each playback message with the newest frame's time when it came (for tests: frames against the
// replay's own clock).
const playbackLog = [];

let cameraChosen = false;
let avatarHidden = params.get('avatar') === '0';
// `?hide=ACTOR,...`: actors not drawn (`avatar`, `virtual human`).
const hiddenActors = (params.get('hide') || '').split(',').filter((a) => a);
rig.showStrings = params.get('strings') !== '0';
function setCamera(name) {
  cameras.use(name);
  hud.setCamera(cameras.active);
  // Labels float over one picture: not over a stereo pair.
  labelRenderer.domElement.style.visibility = cameras.onScreen && cameras.screen.stereo ? 'hidden' : '';
}
setCamera(params.get('camera') || 'orbit');

function onScene(d) {
  if (root) scene.remove(root);
  desc = d;
  root = new THREE.Group();
  scene.add(root);
  world = new World(desc, root);
  world.proxyGroup.visible = params.get('proxies') !== '0' && !study;
  world.hideActor('avatar', avatarHidden);
  for (const a of hiddenActors) world.hideActor(a, true);
  crowd = desc.crowd ? new Crowd(desc, root) : null;
  people = new Humanoids(desc, root, world.meshes);
  setBodies(asPeople);
  people.hideActor('avatar', avatarHidden);
  for (const a of hiddenActors) people.hideActor(a, true);
  latest = null;
  applied = null;
  cameras.place(desc, rigInfo ? rigInfo.eye_m : null);
  headset.place(cameras.eye.position.toArray());
  hud.setScene(desc);
}

function setBodies(asP) {
  asPeople = asP;
  if (world) world.people = asP;
  if (people) people.setShown(asP);
  if (crowd) crowd.setPeople(asP);
}

function onRig(r) {
  rigInfo = r;
  rig.setInfo(r);
  if (desc) cameras.place(desc, r.eye_m);
  headset.place(r.eye_m);
  cameras.setDisplay(r.display, r.eye_m, params.get('stereo'));
  // The page on the rig's screen shows the user's eye unless asked otherwise.
  if (r.display && !params.get('camera') && !cameraChosen) setCamera('eye');
  labelRenderer.domElement.style.visibility = cameras.onScreen && cameras.screen.stereo ? 'hidden' : '';
}

// A frame came (`arrivedMs`: when, on this page's clock).
function onFrame(buffer, layoutId, seq, arrivedMs = performance.now()) {
  if (!desc || layoutId !== desc.layout.id) return;
  const f = new Float32Array(buffer);
  latest = { f, seq, t: f[desc.layout.globals_at], stamp: stamp(f, desc.layout), arrivedMs };
  framesReceived++;
}

// The reaction study: nothing drawn but the virtual human and the scenery (the clips carry no
// hands, strings, contacts or labels either), from the user's eye, no HUD, no keys but full screen.
function onStudy(s) {
  if (!study) {
    study = new Study(document.getElementById('study'), conn.send);
    avatarHidden = true;
    if (world) {
      world.hideActor('avatar', true);
      people.hideActor('avatar', true);
      world.proxyGroup.visible = false;
    }
    rig.group.visible = false;
    document.getElementById('hud').style.display = 'none';
    labelRenderer.domElement.style.display = 'none';
    if (!params.get('camera')) { cameraChosen = true; setCamera('eye'); }
  }
  study.setState(s);
}

const conn = connect({
  onScene,
  onRig,
  onStatus: (s) => { status = s; hud.setStatus(s); },
  onFrame,
  // The frames the page holds: the newest and the one drawn (a headset keeps copies of its own).
  holds: (buffer) => (latest !== null && latest.f.buffer === buffer) || (applied !== null && applied.f.buffer === buffer),
  onState: (s) => { connection = s; hud.setConnection(s); },
  onPlayback: (p) => {
    conn.poll(); // the frame that came before this message
    if (!playback) playback = new Playback(document.getElementById('playback'), conn.send);
    playback.setState(p);
    playbackLog.push({ clock_s: p.clock_s, t_s: p.t_s, frame_t: latest ? latest.t : null, playing: p.playing, speed: p.speed });
    if (playbackLog.length > 400) playbackLog.shift();
  },
  onStudy,
});

const ages = new AgeReporter((m) => conn.send(m));

function resize() {
  if (renderer.xr.isPresenting) return;
  const w = container.clientWidth;
  const h = container.clientHeight;
  renderer.setSize(w, h);
  labelRenderer.setSize(w, h);
  cameras.resize(w, h);
}
window.addEventListener('resize', resize);
resize();

window.addEventListener('keydown', (e) => {
  if (e.key === 'f' && !(study && e.target.tagName === 'INPUT')) toggleFullScreen();
  else if (study) return;
  else if (e.key === 'c') { cameraChosen = true; setCamera(cameras.active === 'eye' ? 'orbit' : 'eye'); }
  else if (e.key === 'p' && world) world.proxyGroup.visible = !world.proxyGroup.visible;
  else if (e.key === 'a' && world) { avatarHidden = !avatarHidden; world.hideActor('avatar', avatarHidden); people.hideActor('avatar', avatarHidden); }
  else if (e.key === 'b') setBodies(!asPeople);
  else if (e.key === 'w') toggleRig('workspace');
  else if (e.key === 'n') toggleRig('near');
  else if (e.key === ' ') paused = !paused;
});

// `?fps=N` caps the drawing rate (a slow machine, or one shared with other work).
const minFrameMs = params.get('fps') ? 1000 / Number(params.get('fps')) : 0;
let lastDraw = 0;

// How long a headset's picture takes to draw (ms, smoothed): the grips are extrapolated to when
// it is shown.
let xrDrawMs = 0;

function frameLoop(time, xrFrame) {
  // The newest frame that came (from the receiving worker's shared memory, when there is one).
  conn.poll();
  const now = performance.now();
  const inHeadset = headset.presenting;
  // A headset draws every frame it is given (a frame not drawn there shows nothing).
  if (!inHeadset && minFrameMs && now - lastDraw < minFrameMs - 1) return;
  const sinceDraw = lastDraw ? (now - lastDraw) / 1000 : 0;
  lastDraw = now;
  let leadMs = 0;
  if (inHeadset && !paused && latest && !playback) {
    // Interpolated to the headset's rate, the grips extrapolated to when the picture is shown:
    // the runtime's predicted display time, or once drawn at the soonest.
    const predicted = xrFrame && xrFrame.predictedDisplayTime > 0 ? xrFrame.predictedDisplayTime : 0;
    const x = headset.frame(latest, desc, now, Math.max(predicted, now + xrDrawMs), conn.hands());
    leadMs = x.leadMs;
    world.apply(x.f, sinceDraw);
    if (crowd) crowd.apply(x.f);
    people.apply(x.f);
    rig.apply(x.f, desc.layout);
    applied = latest;
  } else if (!paused && latest && latest !== applied) {
    const dt = applied ? Math.max(0, latest.t - applied.t) : 0;
    world.apply(latest.f, dt);
    if (crowd) crowd.apply(latest.f);
    people.apply(latest.f);
    rig.apply(latest.f, desc.layout);
    applied = latest;
    if (playback) playback.setTime(applied.t);
    if (study) study.frameDrawn();
  }
  if (now - rateSince >= 1000) {
    const received = conn.received();
    hud.setFrameRate(((received - rateCount) * 1000) / (now - rateSince));
    rateCount = received;
    rateSince = now;
  }
  cameras.update();
  // From the user's eye, their own avatar's head is in the way.
  const eyeAt = inHeadset ? headset.eyePosition(tmpEye) : cameras.active === 'eye' ? cameras.eye.position : null;
  if (world) world.hideNear(eyeAt, 0.3);
  if (people) people.hideNear(eyeAt, 0.3);
  const drawStart = performance.now();
  if (inHeadset) renderer.render(scene, headset.camera);
  else {
    cameras.render(renderer, scene);
    labelRenderer.render(scene, cameras.camera);
  }
  const drawMs = performance.now() - drawStart;
  if (inHeadset) xrDrawMs += 0.1 * (drawMs - xrDrawMs);
  if (applied && applied !== reported && !playback) {
    reported = applied;
    ages.drawn(applied.seq, applied.stamp, inHeadset, leadMs, drawMs, applied.arrivedMs, drawStart, inHeadset ? headset.judged() : null);
  }
  renders++;
  for (let i = renderWaiters.length - 1; i >= 0; i--) if (renders >= renderWaiters[i][0]) renderWaiters.splice(i, 1)[0][1]();
}
const tmpEye = new THREE.Vector3();
renderer.setAnimationLoop(frameLoop);

// ---- for tests and the console ----
const tmp = new THREE.Vector3();
function project(p) {
  tmp.set(p[0], p[1], p[2]).project(cameras.camera);
  const r = renderer.domElement.getBoundingClientRect();
  return { x: r.left + ((tmp.x + 1) / 2) * r.width, y: r.top + ((1 - tmp.y) / 2) * r.height, z: tmp.z };
}

window.spidarView = {
  state: () => ({
    connection,
    scene: desc ? desc.name : null,
    layoutId: desc ? desc.layout.id : null,
    hasRig: !!rigInfo,
    // Frames that came (handed to the page, or fed by a test), and whether a worker receives them.
    framesReceived: conn.shared ? conn.received() : framesReceived,
    framesWorker: conn.shared,
    frameBuffersMade: conn.shared ? conn.buffersMade() : null,
    seq: applied ? applied.seq : null,
    t: applied ? applied.t : null,
    receivedT: latest ? latest.t : null,
    paused,
    camera: cameras.active,
    status,
    renders,
    replay: !!playback,
    stamp: applied ? applied.stamp : null,
    drawnReport: ages.last,
    // How the page draws: multisampled or not, and the software renderer's name (null: a GPU).
    gl: { antialias, software: softwareGl, shading: lambertShading() ? 'lambert' : 'standard' },
  }),
  // A replay's state (its last `playback` message) and the bar's text, or null when live.
  playback: () => playback && { ...playback.state, shown: playback.k.time.textContent, button: playback.k.play.textContent },
  playbackLog: () => playbackLog.slice(),
  // The reaction study's state, the clips shown (with the frames drawn of each) and the answers given, or null.
  study: () => study && study.report(),
  // The sequence number of the newest frame that came, drawn or not yet.
  newestSeq: () => conn.newestSeq(),
  pause: () => { paused = true; return { seq: applied ? applied.seq : null, t: applied ? applied.t : null }; },
  resume: () => { paused = false; },
  // Resolves after the next two renders (the screen then shows the applied frame).
  rendered: () => new Promise((res) => renderWaiters.push([renders + 2, res])),
  setCamera,
  orbitTo: (pos, target) => {
    cameras.orbit.position.fromArray(pos);
    cameras.controls.target.fromArray(target);
    cameras.controls.update();
  },
  project,
  // Where each eye's picture of the rig's screen puts scene point p (page px), or null without one.
  projectEyes: (p) => {
    if (!cameras.hasScreen) return null;
    const r = renderer.domElement.getBoundingClientRect();
    return cameras.screen.project(p, r.width, r.height).map((e) => ({ ...e, x: e.x + r.left, y: e.y + r.top }));
  },
  rigInfo: () => rigInfo,
  // The rig's workspace clouds and near strings as drawn (see rig.js), and its toggles.
  rigView: () => rig.report(),
  toggleRig,
  // The headset: its state, entering a session, registering with the controllers on the grips.
  xr: { state: () => headset.state(), enter: () => headset.enter(), register: () => headset.register(),
    // The headset's blend of frames (words, each with its stamp and time) that came `gapMs` apart,
    // drawn `sinceMs` after the last came for a picture shown `showMs` after that, with the
    // world's frames `frameMs` apart.
    blend: (frames, gapMs, sinceMs, showMs, frameMs) => {
      const x = new Interpolator();
      x.frameMs = frameMs;
      frames.forEach((w, k) => {
        const f = new Float32Array(w);
        // Each frame's tick `gapMs` after the last's, on this page's clock.
        const st = { ...stamp(f, desc.layout), wallMs: performance.timeOrigin + k * gapMs };
        x.push({ f, t: f[desc.layout.globals_at], stamp: st, arrivedMs: k * gapMs }, k * gapMs, desc.layout);
      });
      const last = (frames.length - 1) * gapMs;
      const r = x.at(last + sinceMs, desc, last + sinceMs + showMs);
      return { f: Array.from(r.f), leadMs: r.leadMs };
    },
    controllers: () => headset.controllers()?.map((p) => p.toArray()) ?? null,
    maxLeadMs: MAX_LEAD_MS },
  screen: () => ({ on: cameras.onScreen, format: cameras.screen.format, display: rigInfo && rigInfo.display }),
  // A drawn shape: its mesh's world position and where it is on the screen, and the frame's numbers.
  shape: (name) => {
    const i = desc.shapes.findIndex((s) => s.name === name);
    if (i < 0) return null;
    const m = world.meshes[i];
    m.getWorldPosition(tmp);
    const pos = [tmp.x, tmp.y, tmp.z];
    const o = desc.layout.shapes_at + i * desc.layout.shape_floats;
    return { index: i, pos, screen: project(pos), frame: Array.from(applied.f.subarray(o, o + 7)), flash: m.userData.flash, visible: m.visible,
      force: applied.f[desc.layout.shape_force_at + i] };
  },
  // A body drawn as a person: each joint as its two pieces draw it; where its eyes look.
  // For tests: the description and the applied frame's numbers, and a page fed a description and
  // a frame of the test's making (the live frames of another layout are then ignored).
  desc: () => desc,
  frameWords: () => (applied ? Array.from(applied.f) : null),
  feed: (d, words) => {
    onScene(d);
    const f = new Float32Array(words);
    const u = new Uint32Array(f.buffer);
    onFrame(f.buffer, u[1], u[2]);
  },
  personJoints: (name) => people && people.joints(name),
  personEyes: (name) => people && people.eyeDirections(name),
  setBodies,
  characterJoints: (i) => crowd.drawnJoints(i).map((p) => ({ pos: p, screen: p && project(p) })),
  // Character i drawn as a person: each joint as the pieces meeting there draw it, its extent.
  characterPerson: (i) => crowd.people.drawn(i),
  character: (i) => {
    const L = desc.layout;
    const o = L.characters_at + i * L.character_floats;
    return Array.from(applied.f.subarray(o, o + L.character_floats));
  },
  hud: () => Object.fromEntries(Array.from(document.querySelectorAll('#hud [data-hud], #hud [data-counter]'))
    .map((e) => [e.dataset.hud ?? `counter:${e.dataset.counter}`, e.textContent])),
  labels: () => Array.from(document.querySelectorAll('.label')).map((e) => ({
    label: e.dataset.label ?? null, character: e.dataset.character ?? null, state: e.dataset.state, text: e.textContent })),
  grips: () => rig.grips.map((g, h) => {
    const o = desc.layout.hands_at + h * desc.layout.hand_floats;
    return { visible: g.visible, pos: g.position.toArray(), force: applied ? Array.from(applied.f.subarray(o + 3, o + 6)) : null };
  }),
};
