// The page: reads its address's parameters, opens a session over WebSocket,
// flies the cameras (a loadtest path, or the user's mouse and keys), draws,
// and keeps the HUD and window.caveclodStats up to date.
//
//   ?mesh=NAME          the mesh (default: the first the server lists)
//   &cameras=N          1-4 cameras in quadrants (with a trajectory)
//   &trajectory=P       flyover | circle | rotate | line (caveclod loadtest's
//                       paths); none: fly one camera yourself
//   &tolerance=PX       screen-space error in pixels (default: the server's)
//   &strict=1           the strict error bound (RefineOptions.strict_bound)
//   &token=T            the server's bearer token (--token-file)
//   &encoding=E         the frame encoding: linked (default with geomorphs, which
//                       download the morph targets it reads), ops (default
//                       without), raw
//   &vertices=packed|float32  how the vertex buffer downloads (default packed)
//   &morph=MS           geomorphs: splits and collapses change shape over MS
//                       milliseconds (default 500; 0: off; needs packed)
//   &morphspeed=PX      geomorphs move PX pixels a second on screen: each lasts
//                       its path over PX, at most MS (give a long &morph=8000)
//   &hz=N               poses a second per camera (default 30)

import { Geomorphs, pointsOf } from "./geomorph.js";
import { PATHS } from "./paths.js";
import { Renderer } from "./render.js";
import { IndexBuffer, Session } from "./session.js";

const pb = globalThis.protobuf.roots.default.caveclod.v1;
const params = new URLSearchParams(location.search);
const hud = document.getElementById("hud");
const errorBox = document.getElementById("error");
const canvas = document.getElementById("view");
const FOV_Y = 60;

const stats = (window.caveclodStats = {
  frames: 0, divergences: 0, crcChecks: 0, facesDrawn: 0, latencyMsP50: 0, latencyMsP99: 0, bytesReceived: 0,
  connected: false, error: null, badFrames: 0, keyframeRequests: 0, posesSent: 0, resumes: 0, status: null,
  fps: 0, mesh: null, cameras: 0, ready: false, ended: false,
  morphing: 0, morphsStarted: 0, // geomorphs under way now; frames' net additions to them so far
  frameEncoding: null, // what the server granted (SessionInfo.frame_encoding's name)
});
const MORPH_TARGET = 5; // AttributeSemantic.ATTRIBUTE_SEMANTIC_MORPH_TARGET

function showError(message) {
  stats.error = message;
  errorBox.textContent = message;
  errorBox.hidden = false;
}

function token() {
  return params.get("token") || "";
}

/** The mesh to open: ?mesh=, or the first the server serves. */
async function chooseMesh() {
  if (params.get("mesh")) return params.get("mesh");
  // A header carries visible ASCII only: fetch refuses a token beyond Latin-1 and sends Latin-1
  // as one byte a character, not the UTF-8 the server compares; such a token goes as ?token=.
  const plain = /^[\x21-\x7e]+$/.test(token());
  const headers = token() && plain ? { Authorization: `Bearer ${token()}` } : {};
  const query = token() && !plain ? `?token=${encodeURIComponent(token())}` : "";
  const answer = await fetch("/v1/meshes" + query, { headers });
  if (!answer.ok) throw new Error(await answer.text());
  const listing = pb.ListMeshesResponse.decode(new Uint8Array(await answer.arrayBuffer()));
  if (!listing.meshes.length) throw new Error("the server serves no mesh");
  return listing.meshes[0].name;
}

/** The user's camera: yaw and pitch from mouse drags, motion from keys. */
class FlyCamera {
  constructor(lo, hi) {
    const extent = Math.max(hi[0] - lo[0], hi[1] - lo[1], 1e-9);
    this.speed = 0.08 * extent; // world units a second
    this.eye = [lo[0] - 0.1 * extent, lo[1] - 0.1 * extent, hi[2] + 0.25 * extent];
    const c = [0.5 * (lo[0] + hi[0]), 0.5 * (lo[1] + hi[1]), 0.5 * (lo[2] + hi[2])];
    const d = [c[0] - this.eye[0], c[1] - this.eye[1], c[2] - this.eye[2]];
    this.yaw = Math.atan2(d[1], d[0]);
    this.pitch = Math.atan2(d[2], Math.hypot(d[0], d[1]));
    this.keys = new Set();
    addEventListener("keydown", (e) => this.keys.add(e.key.toLowerCase()));
    addEventListener("keyup", (e) => this.keys.delete(e.key.toLowerCase()));
    addEventListener("blur", () => this.keys.clear());
    canvas.addEventListener("pointermove", (e) => {
      if (!(e.buttons & 1)) return;
      this.yaw -= e.movementX * 0.004;
      this.pitch = Math.max(-1.5, Math.min(1.5, this.pitch - e.movementY * 0.004));
    });
  }

  pose(dt) {
    const k = this.keys, f = [Math.cos(this.pitch) * Math.cos(this.yaw), Math.cos(this.pitch) * Math.sin(this.yaw), Math.sin(this.pitch)];
    const right = [Math.sin(this.yaw), -Math.cos(this.yaw), 0];
    const step = this.speed * dt * (k.has("shift") ? 5 : 1);
    const move = (v, s) => { for (let i = 0; i < 3; i++) this.eye[i] += v[i] * s; };
    if (k.has("w") || k.has("arrowup")) move(f, step);
    if (k.has("s") || k.has("arrowdown")) move(f, -step);
    if (k.has("d") || k.has("arrowright")) move(right, step);
    if (k.has("a") || k.has("arrowleft")) move(right, -step);
    if (k.has("e")) move([0, 0, 1], step);
    if (k.has("q")) move([0, 0, 1], -step);
    return { eye: [...this.eye], target: this.eye.map((v, i) => v + f[i]), up: [0, 0, 1] };
  }
}

function samePose(a, b) {
  return a && b && a.eye.every((v, i) => v === b.eye[i]) && a.target.every((v, i) => v === b.target[i]);
}

async function main() {
  const trajectory = params.get("trajectory");
  if (trajectory && !PATHS[trajectory]) throw new Error(`unknown trajectory '${trajectory}': use ${Object.keys(PATHS).join(", ")}`);
  const cameras = trajectory ? Math.max(1, Math.min(4, parseInt(params.get("cameras") || "1", 10) || 1)) : 1;
  const hz = Math.max(1, Math.min(120, parseFloat(params.get("hz") || "30")));
  const renderer = new Renderer(canvas);
  const dpr = window.devicePixelRatio || 1;
  canvas.width = Math.max(2, Math.round(canvas.clientWidth * dpr));
  canvas.height = Math.max(2, Math.round(canvas.clientHeight * dpr));
  const mesh = await chooseMesh();
  const quadrant = cameras === 1 ? [canvas.width, canvas.height] : [canvas.width / 2, cameras === 2 ? canvas.height : canvas.height / 2];
  const options = { viewportWidth: Math.floor(quadrant[0]), viewportHeight: Math.floor(quadrant[1]), fovYDeg: FOV_Y };
  if (params.get("tolerance")) options.tolerancePx = parseFloat(params.get("tolerance"));
  if (params.get("strict") === "1") options.strictBound = true;
  stats.mesh = mesh;
  stats.cameras = cameras;
  document.getElementById("help").hidden = Boolean(trajectory);

  let lo = null, hi = null, fly = null;
  const poses = new Array(cameras).fill(null);
  const url = `${location.protocol === "https:" ? "wss" : "ws"}://${location.host}/v1/session`;
  const morphMs = Math.max(0, parseFloat(params.get("morph") ?? "500") || 0);
  const morphSpeed = parseFloat(params.get("morphspeed") ?? "") > 0 ? parseFloat(params.get("morphspeed")) : null;
  const kappa = options.viewportHeight / (2 * Math.tan((FOV_Y * Math.PI) / 360)); // pixels a unit spans at distance 1
  // Geomorphs (caveclod/web/geomorph.js): per camera, the display buffers drawn instead of the
  // session's, and the positions of the vertices on their way.
  let morphs = null, display = null;
  const applyDisplay = (c, changes) => {
    if (changes.reset) for (const b of display[c]) { b.resize(0); b.grown = true; }
    for (const w of changes.writes) {
      const b = display[c][w.material];
      b.resize(w.count);
      b.write(w.slots, w.tris);
    }
  };
  const session = new Session({
    url, mesh, cameras, options, tokenValue: token(), encoding: params.get("encoding") || (morphMs > 0 ? "linked" : "ops"),
    vertices: params.get("vertices") || "packed", morphTargets: morphMs > 0,
    onReady(info, payload) {
      stats.frameEncoding = pb.FrameEncoding[info.frameEncoding] ?? String(info.frameEncoding);
      const b = (v) => [v.x, v.y, v.z];
      lo = b(info.mesh.boundsMin);
      hi = b(info.mesh.boundsMax);
      const morphAttr = info.vertexFormat.attributes.find((a) => a.semantic === MORPH_TARGET);
      if (morphMs > 0 && morphAttr && !morphs) {
        const d = Number(info.vertexFormat.vertexCount), materials = info.mesh.materials.length || 1;
        const positions = new Float32Array(payload.buffer, payload.byteOffset, 3 * d);
        const targets = new Uint32Array(payload.buffer, payload.byteOffset + Number(morphAttr.offset), d);
        const points = pointsOf(positions, targets);
        morphs = Array.from({ length: cameras }, () => new Geomorphs(positions, targets, materials, morphMs / 1000, points, morphSpeed));
        display = Array.from({ length: cameras }, () => Array.from({ length: materials }, () => new IndexBuffer()));
        session.buffers.forEach((row, c) => { // what the session holds already appears as it is
          const held = row.map((buf, m) => ({ material: m, count: buf.count, slots: Uint32Array.from({ length: buf.count }, (_, i) => i), tris: buf.rows.subarray(0, 3 * buf.count) }));
          applyDisplay(c, morphs[c].apply(held, true, performance.now() / 1000));
        });
      }
      renderer.setVertexBuffer(info.vertexFormat, payload, lo, hi, info.mesh.materials, morphs ? cameras : 0);
      if (!trajectory && !fly) fly = new FlyCamera(lo, hi);
      stats.ready = true;
    },
    onFrame(update) {
      if (!morphs) return;
      const t = performance.now() / 1000;
      for (const [c, cu] of update.cameras) {
        if (poses[c]) morphs[c].lookFrom(poses[c].eye, kappa); // morphs timed from where the camera is
        const started = morphs[c].active.size;
        applyDisplay(c, morphs[c].apply(cu.surfaces, cu.keyframe, t, cu.poseSeq > 0));
        stats.morphsStarted += Math.max(0, morphs[c].active.size - started);
      }
    },
    onEnd(status) {
      syncStats();
      stats.ended = true;
      if (status.code !== 0) showError(status.message);
    },
  });
  window.caveclodSession = session; // for the console
  const syncStats = () => Object.assign(stats, session.stats, { error: stats.error || session.stats.error });
  addEventListener("pagehide", () => session.close("the page was closed"));
  session.connect();

  const t0 = performance.now();
  let lastPose = -Infinity, lastTick = t0, fpsFrames = 0, fpsSince = t0;
  function tick(now) {
    const dt = Math.min(0.1, (now - lastTick) / 1000);
    lastTick = now;
    if (session.ready && lo) {
      for (let c = 0; c < cameras; c++) {
        poses[c] = trajectory ? PATHS[trajectory](lo, hi, c, (now - t0) / 1000) : fly.pose(dt);
      }
      if (now - lastPose >= 1000 / hz) {
        lastPose = now;
        poses.forEach((pose, c) => { if (!samePose(pose, session.latest[c])) session.sendPose(c, pose); });
      }
    }
    if (morphs && renderer.vao) {
      const t = now / 1000;
      let active = 0;
      morphs.forEach((g, c) => {
        applyDisplay(c, g.tick(t));
        const moving = g.moving(t);
        renderer.writePositions(c, moving.vertices, moving.positions);
        active += g.active.size;
      });
      stats.morphing = active;
      renderer.sync(display);
      renderer.draw(poses, display.map((row) => row.map((b) => b.count)), FOV_Y);
    } else if (session.buffers && renderer.vao) {
      renderer.sync(session.buffers);
      renderer.draw(poses, session.buffers.map((row) => row.map((b) => b.count)), FOV_Y);
    }
    fpsFrames++;
    if (now - fpsSince >= 1000) { stats.fps = (1000 * fpsFrames) / (now - fpsSince); fpsFrames = 0; fpsSince = now; }
    syncStats();
    hud.textContent = [
      `${mesh} · ${cameras} camera${cameras > 1 ? "s" : ""}${trajectory ? " · " + trajectory : ""}${session.stats.connected ? "" : " · offline"}`,
      `faces ${stats.facesDrawn.toLocaleString()}${stats.hiddenParts ? `   hidden parts ${stats.hiddenParts.toLocaleString()}` : ""}   frames ${stats.frames}   ${stats.fps.toFixed(0)} fps`,
      `latency p50 ${stats.latencyMsP50.toFixed(1)} ms   p99 ${stats.latencyMsP99.toFixed(1)} ms`,
      `received ${(stats.bytesReceived / 1048576).toFixed(2)} MiB   divergences ${stats.divergences}`,
    ].join("\n");
    if (!session.ended) requestAnimationFrame(tick);
  }
  requestAnimationFrame(tick);
}

main().catch((err) => showError(err.message || String(err)));
