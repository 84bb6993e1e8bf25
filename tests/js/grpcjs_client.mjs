// A Node.js @grpc/grpc-js client of caveclod.v1.Lod (run by tests/test_grpcjs.py).
//
//   node tests/js/grpcjs_client.mjs HOST:PORT [MESH]
//
// @grpc/grpc-js and @grpc/proto-loader are found through NODE_PATH (or a
// node_modules above the working directory). Calls ListMeshes; runs one
// Session (Open with RAW frames and FLOAT32 vertices, SessionInfo, every
// VertexChunk checked against vertex_payload_crc32, 5 poses looking down at
// the terrain, each sent once a frame has answered the previous one, every
// frame applied to index buffers whose CRC-32 is checked and acked, then
// Close and the stream's OK status); makes calls that must fail (unknown
// mesh, a pose before Open, an unknown method, health of an unknown
// service) and checks their status codes; and asks grpc.health.v1.Health
// for "" and "caveclod.v1.Lod". It prints one JSON summary on stdout;
// every failure is listed in its "errors", and the exit status is 0 only
// when there are none.

import { createRequire } from "node:module";
import { fileURLToPath } from "node:url";
import path from "node:path";
import zlib from "node:zlib";

// ES modules ignore NODE_PATH; require() honours it.
const require = createRequire(path.join(process.cwd(), "noop.js"));
const grpc = require("@grpc/grpc-js");
const protoLoader = require("@grpc/proto-loader");

const HERE = path.dirname(fileURLToPath(import.meta.url));
const PROTOS = path.resolve(HERE, "..", "..", "protos");
const TARGET = process.argv[2];
const MESH = process.argv[3] || "";
const POSES = 5;
const DEADLINE_MS = 60000;

if (!TARGET) {
  console.error("usage: node grpcjs_client.mjs HOST:PORT [MESH]");
  process.exit(2);
}

const LOADER = { keepCase: true, longs: Number, enums: String, defaults: true, oneofs: true,
                 includeDirs: [PROTOS] };
const lodPkg = grpc.loadPackageDefinition(protoLoader.loadSync("caveclod/v1/caveclod.proto", LOADER));
const healthPkg = grpc.loadPackageDefinition(protoLoader.loadSync("grpc/health/v1/health.proto", LOADER));

const summary = {
  target: TARGET, grpc_js: require("@grpc/grpc-js/package.json").version, errors: [],
  list_meshes: null, session: null, error_calls: null, health: null,
};

// CRC-32 (zlib.crc32, ISO-HDLC); node:zlib has it from Node 20.15 / 22.2.
const CRC_TABLE = Array.from({ length: 256 }, (_, n) => {
  let c = n;
  for (let k = 0; k < 8; k++) c = c & 1 ? 0xedb88320 ^ (c >>> 1) : c >>> 1;
  return c >>> 0;
});
function crc32(buf) {
  if (zlib.crc32) return zlib.crc32(buf) >>> 0;
  let c = 0xffffffff;
  for (let i = 0; i < buf.length; i++) c = CRC_TABLE[(c ^ buf[i]) & 0xff] ^ (c >>> 8);
  return (c ^ 0xffffffff) >>> 0;
}

// uint32 little-endian view of a protobuf bytes field (copied: it may sit at any offset).
function u32(bytes) {
  const b = Buffer.from(bytes);
  if (b.length % 4) throw new Error(`a uint32 array of ${b.length} bytes`);
  const out = new Uint32Array(b.length / 4);
  for (let i = 0; i < out.length; i++) out[i] = b.readUInt32LE(4 * i);
  return out;
}

function deadline() {
  return new Date(Date.now() + DEADLINE_MS);
}

function statusName(code) {
  return Object.keys(grpc.status).find((k) => grpc.status[k] === code) ?? String(code);
}

function unary(client, method, request) {
  return new Promise((resolve, reject) => {
    client[method](request, { deadline: deadline() }, (err, reply) => (err ? reject(err) : resolve(reply)));
  });
}

function describe(err) {
  return err && err.code !== undefined ? `${statusName(err.code)}: ${err.details}` : String(err && err.stack || err);
}

async function listMeshes(lod) {
  const reply = await unary(lod, "ListMeshes", {});
  const meshes = reply.meshes || [];
  summary.list_meshes = meshes.map((m) => ({ name: m.name, faces: m.faces, vertices: m.vertices,
                                             bounds_min: m.bounds_min, bounds_max: m.bounds_max }));
  if (!meshes.length) throw new Error("ListMeshes returned no mesh");
  return MESH ? meshes.find((m) => m.name === MESH) : meshes[0];
}

function session(lod, mesh) {
  const out = {
    mesh: mesh.name, session_info: false, frame_encoding: null, vertex_chunks: 0, vertex_bytes: 0,
    vertex_payload_bytes: null, vertex_crc_ok: null, frames: 0, frame_parts: 0, acks: 0,
    keyframes: 0, triangles_written: 0, triangles: 0, crc_checks: 0, crc_mismatches: 0,
    poses_sent: 0, poses_answered: [], last_pose_seq: 0, close_sent: false, status: null, details: null,
  };
  summary.session = out;
  const lo = mesh.bounds_min, hi = mesh.bounds_max;
  const c = { x: (lo.x + hi.x) / 2, y: (lo.y + hi.y) / 2, z: (lo.z + hi.z) / 2 };
  const extent = Math.max(hi.x - lo.x, hi.y - lo.y, hi.z - lo.z);
  // The terrain is z-up: look down at its centre from above, a little off
  // the vertical so that `up` (+y) is never parallel to the view.
  const pose = (seq) => ({
    camera: 0, pose_seq: seq,
    eye: { x: c.x + 0.05 * extent * seq, y: c.y - 0.3 * extent, z: hi.z + extent * (0.6 + 0.1 * seq) },
    target: c, up: { x: 0, y: 1, z: 0 },
  });

  return new Promise((resolve, reject) => {
    const call = lod.Session({ deadline: deadline() });
    const chunks = [];
    let info = null, posesSent = false, closed = false, ended = false;
    const seen = new Set();
    // The client's index buffers of camera 0: material -> Uint32Array(count * 3); crc: the server's.
    const buffers = new Map(), expected = new Map();
    let keyframedAt = 0;     // the frame whose first keyframe part emptied the buffers
    const applyCamera = (cam, frameSeq) => {
      if (cam.camera !== 0) throw new Error(`camera ${cam.camera} of a 1-camera session`);
      if (cam.keyframe && keyframedAt !== frameSeq) {
        buffers.clear();
        keyframedAt = frameSeq;
        out.keyframes++;
      }
      for (const d of cam.surfaces) {
        if (d.ops && d.ops.length) throw new Error("an OPS SurfaceDelta in a RAW session");
        const old = buffers.get(d.material) || new Uint32Array(0);
        const buf = new Uint32Array(d.count * 3);
        buf.set(old.subarray(0, Math.min(old.length, buf.length)));
        const tris = u32(d.tris);
        const slots = d.slots.length ? u32(d.slots) : null;
        const k = tris.length / 3;
        if (!Number.isInteger(k) || (slots && slots.length !== k)) throw new Error("malformed SurfaceDelta");
        for (let j = 0; j < k; j++) {
          const slot = slots ? slots[j] : d.first_slot + j;
          if (slot >= d.count) throw new Error(`slot ${slot} past count ${d.count}`);
          buf.set(tris.subarray(3 * j, 3 * j + 3), 3 * slot);
        }
        buffers.set(d.material, buf);
        if (d.crc32 !== null && d.crc32 !== undefined) expected.set(d.material, d.crc32 >>> 0);
        out.triangles_written += k;
      }
    };
    const checkBuffers = (frameSeq) => {
      for (const [m, crc] of expected) {
        const b = buffers.get(m) || new Uint32Array(0);
        const bytes = Buffer.alloc(b.length * 4);
        b.forEach((v, i) => bytes.writeUInt32LE(v, 4 * i));
        const mine = b.length ? crc32(bytes) : 0;
        if (mine !== crc) { out.crc_mismatches++; fail(`frame ${frameSeq} material ${m}: crc ${mine} != ${crc}`); }
        else out.crc_checks++;
      }
      expected.clear();
      let tris = 0;
      for (const b of buffers.values()) tris += b.length / 3;
      out.triangles = tris;
    };
    const fail = (msg) => {
      if (!ended) summary.errors.push(`session: ${msg}`);
      if (!closed) { closed = true; call.cancel(); }
    };

    // One pose at a time, the next once a frame answers the last (latest
    // pose wins: poses sent together may be superseded, never answered).
    const sendPoses = () => {
      posesSent = true;
      if (!closed && out.poses_sent < POSES && (out.poses_sent === 0 || seen.has(out.poses_sent))) {
        out.poses_sent++;
        call.write({ pose: pose(out.poses_sent) });
      }
    };
    const maybeClose = () => {
      if (!closed && out.poses_sent === POSES && seen.has(POSES)) {
        closed = true;
        out.close_sent = true;
        call.write({ close: { reason: "grpcjs_client done" } });
        call.end();
      }
    };

    call.on("data", (msg) => {
      try {
        if (msg.kind === "session_info") {
          if (info) return fail("a second SessionInfo");
          info = msg.session_info;
          out.session_info = true;
          out.frame_encoding = info.frame_encoding;
          out.vertex_payload_bytes = info.vertex_format.payload_bytes;
          out.ack_window = info.ack_window;
          out.acks_on_poses = info.acks_on_poses;
          if (info.vertex_buffer_cached || info.vertex_format.payload_bytes === 0) sendPoses();
        } else if (msg.kind === "vertex_chunk") {
          const ch = msg.vertex_chunk;
          if (!info) return fail("VertexChunk before SessionInfo");
          if (out.frames) return fail("VertexChunk after a Frame");
          if (ch.offset !== out.vertex_bytes) return fail(`chunk offset ${ch.offset}, expected ${out.vertex_bytes}`);
          chunks.push(Buffer.from(ch.data));
          out.vertex_chunks++;
          out.vertex_bytes += ch.data.length;
          if (out.vertex_bytes === ch.total) {
            out.vertex_crc_ok = crc32(Buffer.concat(chunks)) === (info.vertex_payload_crc32 >>> 0);
            if (!posesSent) sendPoses();
          }
        } else if (msg.kind === "frame") {
          const f = msg.frame;
          if (!info) return fail("Frame before SessionInfo");
          out.frame_parts++;
          for (const cam of f.cameras) {
            applyCamera(cam, f.frame_seq);
            if (cam.pose_seq && !seen.has(cam.pose_seq)) { seen.add(cam.pose_seq); out.poses_answered.push(cam.pose_seq); }
          }
          out.last_pose_seq = Math.max(out.last_pose_seq, f.pose_seq);
          if (!f.continued) {
            checkBuffers(f.frame_seq);
            out.frames++;
            if (f.frame_seq !== out.frames) return fail(`frame_seq ${f.frame_seq}, expected ${out.frames}`);
            if (!closed) { call.write({ ack: { frame_seq: f.frame_seq } }); out.acks++; }
          }
          if (posesSent) sendPoses();
          maybeClose();
        } else {
          fail(`unexpected ServerMessage ${msg.kind}`);
        }
      } catch (e) {
        fail(String(e && e.stack || e));
      }
    });
    call.on("status", (st) => {
      ended = true;
      out.status = statusName(st.code);
      out.details = st.details;
      resolve(out);
    });
    call.on("error", (err) => {
      // Followed by "status"; recorded there.
      if (err.code === undefined) reject(err);
    });
    call.write({ open: { mesh: mesh.name, cameras: 1, client: "grpcjs_client.mjs",
                         options: { viewport_width: 640, viewport_height: 480 },
                         frame_encoding: "FRAME_ENCODING_RAW", vertex_encoding: "VERTEX_ENCODING_FLOAT32" } });
  });
}

// A Session stream that must end with an error status: its code and details.
function failingSession(lod, first) {
  return new Promise((resolve) => {
    const call = lod.Session({ deadline: deadline() });
    const got = [];
    call.on("data", (msg) => got.push(msg.kind));
    call.on("error", () => {});
    call.on("status", (st) => resolve({ status: statusName(st.code), details: st.details, messages: got }));
    call.write(first);
    call.end();
  });
}

async function expectError(name, promise) {
  try {
    const r = await promise;
    return r && r.status ? r : { status: "OK", details: "", reply: r };
  } catch (e) {
    return e && e.code !== undefined ? { status: statusName(e.code), details: e.details } : { status: `threw ${e}` };
  }
}

// Errors the server must report as gRPC statuses (trailers-only responses
// and grpc-message included).
async function errorCalls(lod, target) {
  const result = {};
  result.session_unknown_mesh = await expectError("unknown mesh", failingSession(lod, {
    open: { mesh: "no-such-mesh", cameras: 1, options: { viewport_width: 640, viewport_height: 480 } } }));
  result.session_pose_first = await expectError("pose first", failingSession(lod, {
    pose: { camera: 0, pose_seq: 1, eye: { x: 0, y: 0, z: 10 }, target: { x: 0, y: 0, z: 0 },
            up: { x: 0, y: 1, z: 0 } } }));
  const raw = new grpc.Client(target, grpc.credentials.createInsecure());
  try {
    result.unknown_method = await expectError("unknown method", new Promise((resolve, reject) => {
      raw.makeUnaryRequest("/caveclod.v1.Lod/NoSuchMethod", (b) => b, (b) => b, Buffer.alloc(0),
                           { deadline: deadline() }, (err, reply) => (err ? reject(err) : resolve(reply)));
    }));
  } finally {
    raw.close();
  }
  const h = new healthPkg.grpc.health.v1.Health(target, grpc.credentials.createInsecure());
  try {
    result.health_unknown_service = await expectError("health", unary(h, "Check", { service: "no.such.Service" }));
  } finally {
    h.close();
  }
  summary.error_calls = result;
  const want = { session_unknown_mesh: "NOT_FOUND", session_pose_first: "INVALID_ARGUMENT",
                 unknown_method: "UNIMPLEMENTED", health_unknown_service: "NOT_FOUND" };
  for (const [k, code] of Object.entries(want)) {
    if (result[k].status !== code) summary.errors.push(`${k}: ${result[k].status} (${result[k].details}), expected ${code}`);
  }
}

async function health(target) {
  const client = new healthPkg.grpc.health.v1.Health(target, grpc.credentials.createInsecure());
  try {
    const result = {};
    for (const service of ["", "caveclod.v1.Lod"]) {
      result[service || "(server)"] = (await unary(client, "Check", { service })).status;
    }
    summary.health = result;
  } finally {
    client.close();
  }
}

async function main() {
  const lod = new lodPkg.caveclod.v1.Lod(TARGET, grpc.credentials.createInsecure());
  try {
    const mesh = await listMeshes(lod);
    if (!mesh) throw new Error(`no mesh named ${MESH}`);
    await session(lod, mesh);
    await errorCalls(lod, TARGET);
  } catch (e) {
    summary.errors.push(`lod: ${describe(e)}`);
  } finally {
    lod.close();
  }
  try {
    await health(TARGET);
  } catch (e) {
    summary.errors.push(`health: ${describe(e)}`);
  }
  const s = summary.session;
  if (s) {
    if (s.status !== "OK") summary.errors.push(`session ended ${s.status}: ${s.details}`);
    if (s.poses_answered.length === 0) summary.errors.push("no pose answered");
  }
  process.stdout.write(JSON.stringify(summary) + "\n");
  process.exitCode = summary.errors.length ? 1 : 0;
}

main();
