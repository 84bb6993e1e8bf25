// One caveclod.v1 session over a WebSocket: the browser's thin client.
//
// The same rules as caveclod/client/protocol.py (the Python client): the
// vertex buffer arrives once and is checked against its CRC-32; each frame's
// slot writes patch the (camera, material) index buffers in place; after the
// last part of a frame every buffer it touched is checked against the
// server's CRC-32, and a mismatch or a frame that does not apply asks for a
// keyframe of that camera; acks ride on poses when the server allows it. A
// connection that drops without a Status is resumed with the session token
// (the server keeps the session for SessionInfo.resume_ttl_s), offering the
// vertex buffer it holds so that it is not sent again.

import { crc32 } from "./crc32.js";
import { decodeLinked, decodeOps, linksOf, OpStreamError } from "./opstream.js";
import { PackedVertexError, unpackVertices } from "./vertexpack.js";

const pb = globalThis.protobuf.roots.default.caveclod.v1;
export const CLIENT_NAME = "caveclod-web/0.1";
const SUBPROTOCOL = "caveclod.v1";
const TOKEN_SUBPROTOCOL = "caveclod.bearer.";
// The characters a WebSocket subprotocol may hold (RFC 7230 tchar): a token
// outside them travels as ?token= instead.
const TCHAR = /^[!#$%&'*+\-.^_`|~0-9A-Za-z]+$/;
const MAX_RESUMES = 5; // consecutive tries before the page gives up and says so
const LATENCIES_KEPT = 2000;

export class ProtocolError extends Error {}

/** One (camera, material) index buffer: rows (capacity * 3 uint32), count, and the rows written since the last upload. */
export class IndexBuffer {
  constructor() {
    this.rows = new Uint32Array(64 * 3);
    this.count = 0;
    this.dirtyLo = Infinity; // first and last row written since the renderer last uploaded
    this.dirtyHi = -1;
    this.grown = true; // the renderer must reallocate its GPU buffer
  }

  resize(count) {
    if (3 * count > this.rows.length) {
      const grown = new Uint32Array(3 * Math.max(count, Math.floor(1.5 * (this.rows.length / 3)), 64));
      grown.set(this.rows.subarray(0, 3 * this.count));
      this.rows = grown;
      this.grown = true;
    } else if (count > this.count) {
      this.rows.fill(0, 3 * this.count, 3 * count); // slots the frame must write; never stale data
    }
    this.count = count;
  }

  write(slots, tris) {
    const rows = this.rows;
    for (let i = 0; i < slots.length; i++) {
      const o = 3 * slots[i], t = 3 * i;
      rows[o] = tris[t]; rows[o + 1] = tris[t + 1]; rows[o + 2] = tris[t + 2];
    }
    if (slots.length) {
      this.dirtyLo = Math.min(this.dirtyLo, slots[0]);
      this.dirtyHi = Math.max(this.dirtyHi, slots[slots.length - 1]);
    }
  }

  crc32() {
    return this.count === 0 ? 0 : crc32(new Uint8Array(this.rows.buffer, 0, 12 * this.count));
  }
}

/** A little-endian uint32 array from a `bytes` field (which may sit at any offset: copy first). */
function u32(bytes) {
  return new Uint32Array(bytes.slice().buffer);
}

function percentile(sorted, q) {
  if (!sorted.length) return 0;
  return sorted[Math.min(sorted.length - 1, Math.floor(q * sorted.length))];
}

export class Session {
  /**
   * @param {object} o
   * @param {string} o.url ws(s)://host:port/v1/session
   * @param {string} o.mesh mesh name
   * @param {number} o.cameras 1 to 4
   * @param {object} o.options RefineOptions fields (viewportWidth, viewportHeight, tolerancePx, ...)
   * @param {string} [o.tokenValue] the bearer token (--token-file), or none
   * @param {string} [o.encoding] "ops" (default), "linked" (op streams that name vertices by their
   *   morph targets: about a third fewer bytes; granted with morphTargets, else the server answers ops) or "raw"
   * @param {string} [o.vertices] "packed" (default: quantized and deflated, 1-7 bytes a vertex) or "float32"
   * @param {boolean} [o.morphTargets] ask for each vertex's geomorph target (packed only)
   * @param {function} o.onReady (info, payload Uint8Array) once the vertex buffer is whole
   * @param {function} o.onFrame (update) after each complete frame
   * @param {function} o.onEnd ({code, message}) when the session has ended for good
   */
  constructor(o) {
    Object.assign(this, { onReady() {}, onFrame() {}, onEnd() {} }, o);
    const encodings = { raw: "FRAME_ENCODING_RAW", linked: "FRAME_ENCODING_OPS_LINKED" };
    this.encoding = pb.FrameEncoding[encodings[o.encoding] || "FRAME_ENCODING_OPS"];
    this.vertexEncoding = o.vertices === "float32" ? pb.VertexEncoding.VERTEX_ENCODING_FLOAT32 : pb.VertexEncoding.VERTEX_ENCODING_PACKED;
    this.unpacking = null; // messages that arrived while a packed vertex buffer was being decoded
    this.infoSeq = 0; // +1 per SessionInfo: a decode finished for an older one is dropped
    this.info = null;
    this.affinity = Array.from(crypto.getRandomValues(new Uint8Array(16)), (b) => b.toString(16).padStart(2, "0")).join("");
    this.token = ""; // the session token, for a resume
    this.payload = null; // the vertex buffer (Uint8Array)
    this.buffers = null; // [camera][material] IndexBuffer
    this.lastApplied = 0;
    this.lastAcked = 0;
    this.ackDue = 0;
    this.poseSeq = 0;
    this.sent = [];
    this.answered = [];
    this.latest = [];
    this.hidden = []; // parts each camera's server-side refinement hides (CameraStats.hidden_parts)
    for (let c = 0; c < this.cameras; c++) { this.sent.push(new Map()); this.answered.push(0); this.latest.push(null); this.hidden.push(0); }
    this.asked = new Set();
    this.frame = null;
    this.ended = false;
    this.attempts = 0; // resumes tried since the last SessionInfo
    this.latencies = [];
    this.newLatencies = false; // samples added since the percentiles were computed
    this.stats = {
      frames: 0, divergences: 0, crcChecks: 0, badFrames: 0, keyframeRequests: 0, facesDrawn: 0, hiddenParts: 0,
      latencyMsP50: 0, latencyMsP99: 0, bytesReceived: 0, posesSent: 0, resumes: 0, connected: false,
      status: null, error: null,
      frameBytes: 0, // bytes of frames (all their parts), for bytes per frame
      applyMs: 0, // time this page spent decoding, applying and checking frames (not drawing)
      vertexDownloadBytes: 0, // bytes of the last vertex buffer download (packed or not)
      vertexPacked: false, // whether it came packed (SessionInfo.vertex_packing)
      unpackMs: 0, // time to decode it, when packed
    };
  }

  connect() {
    // The session's affinity key, the same on every resume: a balancer in front
    // of several replicas hashes on it (deploy/nginx/caveclod-web.conf.template).
    let url = `${this.url}?affinity=${this.affinity}`;
    const protocols = [SUBPROTOCOL];
    if (this.tokenValue) {
      if (TCHAR.test(this.tokenValue)) protocols.push(TOKEN_SUBPROTOCOL + this.tokenValue);
      else url += "&token=" + encodeURIComponent(this.tokenValue);
    }
    const ws = new WebSocket(url, protocols);
    ws.binaryType = "arraybuffer";
    this.ws = ws;
    this.status = null;
    ws.onopen = () => {
      this.stats.connected = true;
      this.send({ open: this.openMessage() });
    };
    ws.onmessage = (event) => this.receive(event.data);
    ws.onclose = (event) => this.closed(event);
  }

  /** The children of each vertex under the payload's morph targets (linksOf), made once per payload. */
  links() {
    if (!this.linked || this.linked.payload !== this.payload) {
      const attr = this.info.vertexFormat.attributes.find(
        (a) => a.semantic === pb.AttributeSemantic.ATTRIBUTE_SEMANTIC_MORPH_TARGET);
      if (!attr) throw new OpStreamError("linked op streams, but the vertex buffer came without morph targets");
      const d = Number(this.info.vertexFormat.vertexCount);
      const targets = new Uint32Array(this.payload.buffer, this.payload.byteOffset + Number(attr.offset), d);
      this.linked = { payload: this.payload, ...linksOf(targets) };
    }
    return this.linked;
  }

  openMessage() {
    return {
      mesh: this.mesh, options: this.options, cameras: this.cameras, client: CLIENT_NAME,
      frameEncoding: this.encoding, resumeToken: this.token, lastFrameSeq: this.lastApplied,
      vertexEncoding: this.vertexEncoding, vertexBufferHash: this.payload && this.info ? this.bufferKey() : "",
      morphTargets: Boolean(this.morphTargets) && this.vertexEncoding === pb.VertexEncoding.VERTEX_ENCODING_PACKED,
    };
  }

  /** The held vertex buffer's key: MeshInfo's hash, or VertexPacking's when it came packed. */
  bufferKey() {
    return this.info.vertexPacking ? this.info.vertexPacking.vertexBufferHash : this.info.mesh.vertexBufferHash;
  }

  send(fields) {
    if (!this.ws || this.ws.readyState !== WebSocket.OPEN) return false;
    this.ws.send(pb.ClientMessage.encode(fields).finish()); // plain objects encode as messages
    return true;
  }

  /** Send camera `c`'s pose ({eye, target, up}); its pose_seq, or 0 when not connected. */
  sendPose(c, pose) {
    this.latest[c] = pose;
    if (!this.ready) return 0;
    const seq = ++this.poseSeq;
    this.sent[c].set(seq, performance.now());
    const vec = (v) => ({ x: v[0], y: v[1], z: v[2] });
    const msg = { camera: c, poseSeq: seq, eye: vec(pose.eye), target: vec(pose.target), up: vec(pose.up) };
    if (this.ackDue > this.lastAcked) msg.ackFrameSeq = this.lastAcked = this.ackDue;
    if (!this.send({ pose: msg })) return 0;
    this.stats.posesSent++;
    return seq;
  }

  /** End the session for good (the page is going away). */
  close(reason) {
    if (this.ended) return;
    this.ended = true;
    this.send({ close: { reason } });
    if (this.ws) this.ws.close(1000, "closed");
  }

  fail(message) {
    this.stats.error = message;
    this.ended = true;
    if (this.ws) this.ws.close(1000, "client error");
    this.onEnd({ code: -1, message });
  }

  closed(event) {
    this.stats.connected = false;
    this.ready = false;
    if (this.ended) return;
    if (this.status) {
      this.ended = true;
      if (this.status.code !== 0) this.stats.error = this.status.message;
      this.onEnd(this.status);
    } else if (this.token && this.attempts < MAX_RESUMES) {
      // Dropped without a status: the session is still on the server. Resume it,
      // backing off over consecutive failures (a SessionInfo starts them over).
      this.attempts++;
      this.stats.resumes++;
      setTimeout(() => this.connect(), 250 * 2 ** this.attempts);
    } else {
      this.ended = true;
      this.stats.error = `the connection to the server was lost (WebSocket close ${event.code}${event.reason ? ": " + event.reason : ""})`;
      this.onEnd({ code: -1, message: this.stats.error });
    }
  }

  receive(data) {
    if (this.unpacking) { this.unpacking.push(data); return; } // applied once the buffer is decoded
    this.stats.bytesReceived += data.byteLength;
    let msg;
    try {
      msg = pb.ServerMessage.decode(new Uint8Array(data));
    } catch (err) {
      return this.fail(`a message from the server does not decode (${err.message}); reload the page`);
    }
    try {
      switch (msg.kind) {
        case "sessionInfo": return this.sessionInfo(msg.sessionInfo);
        case "vertexChunk": return this.vertexChunk(msg.vertexChunk);
        case "frame": return this.framePart(msg.frame, data.byteLength);
        case "status": this.status = { code: msg.status.code, message: msg.status.message }; this.stats.status = this.status; return;
        default: throw new ProtocolError("a ServerMessage this viewer does not know; reload the page for a newer viewer");
      }
    } catch (err) {
      if (err instanceof ProtocolError) return this.fail(err.message);
      throw err;
    }
  }

  sessionInfo(info) {
    this.attempts = 0;
    this.infoSeq++;
    const resumed = info.resumed && this.info !== null;
    this.info = info;
    this.token = info.sessionToken;
    const materials = info.mesh.materials.length || 1;
    if (!resumed) {
      this.buffers = [];
      for (let c = 0; c < this.cameras; c++) this.buffers.push(Array.from({ length: materials }, () => new IndexBuffer()));
      this.lastApplied = 0;
      this.asked.clear();
      this.answered.fill(0);
      this.sent.forEach((m) => m.clear());
    } else if (info.lastFrameSeq > this.lastApplied) {
      this.lastApplied = info.lastFrameSeq; // frames lost with the old connection: a keyframe follows
    }
    this.lastAcked = this.lastApplied;
    this.ackDue = 0;
    this.frame = null;
    this.poseSeq = Math.max(this.poseSeq, info.lastPoseSeq);
    this.chunks = null;
    if (info.vertexBufferCached) {
      if (!this.payload || crc32(this.payload) !== info.vertexPayloadCrc32 >>> 0) {
        throw new ProtocolError("the server took the vertex buffer as held, but this page does not hold it intact; reload the page");
      }
      this.becomeReady();
    } else {
      const total = info.vertexPacking ? info.vertexPacking.packedBytes : info.vertexFormat.payloadBytes;
      this.chunks = new Uint8Array(total);
      this.received = 0;
      if (total === 0) this.finishVertexBuffer();
    }
  }

  vertexChunk(chunk) {
    if (!this.chunks || chunk.offset !== this.received || chunk.total !== this.chunks.length ||
        chunk.offset + chunk.data.length > this.chunks.length) {
      throw new ProtocolError(`vertex chunk at offset ${chunk.offset} out of order (expected ${this.received})`);
    }
    this.chunks.set(chunk.data, chunk.offset);
    this.received += chunk.data.length;
    if (this.received === this.chunks.length) this.finishVertexBuffer();
  }

  finishVertexBuffer() {
    const info = this.info;
    this.stats.vertexDownloadBytes = this.chunks.length;
    this.stats.vertexPacked = Boolean(info.vertexPacking);
    if (info.vertexPacking) return this.unpack(info);
    if (crc32(this.chunks) !== info.vertexPayloadCrc32 >>> 0) {
      throw new ProtocolError("the vertex buffer's CRC-32 differs from the server's; it was damaged in transit: reload the page");
    }
    this.payload = this.chunks;
    this.chunks = null;
    this.becomeReady();
  }

  /** Decode a packed vertex buffer (asynchronous: inflating is a stream); messages wait meanwhile. */
  unpack(info) {
    const packed = this.chunks;
    this.chunks = null;
    if (crc32(packed) !== info.vertexPacking.packedCrc32 >>> 0) {
      throw new ProtocolError("the packed vertex buffer's CRC-32 differs from the server's; it was damaged in transit: reload the page");
    }
    const seq = this.infoSeq;
    const t0 = performance.now();
    this.unpacking = [];
    unpackVertices(info.vertexPacking, info.vertexFormat, packed).then((payload) => {
      if (seq !== this.infoSeq || this.ended) return;
      this.stats.unpackMs = performance.now() - t0;
      if (crc32(payload) !== info.vertexPayloadCrc32 >>> 0) {
        throw new PackedVertexError("this page decodes the packed vertex buffer unlike the server (CRC-32 of the decoded buffer differs); report it, and open the page with ?vertices=float32 meanwhile");
      }
      this.payload = payload;
      this.becomeReady();
    }).then(() => {
      const waiting = this.unpacking || [];
      this.unpacking = null;
      for (const data of waiting) { if (!this.ended) this.receive(data); }
    }, (err) => {
      this.unpacking = null;
      this.fail(err instanceof PackedVertexError ? err.message : `decoding the packed vertex buffer failed: ${err.message}`);
    });
  }

  becomeReady() {
    this.ready = true;
    this.onReady(this.info, this.payload);
    // Poses sent before (or lost with a broken connection): send each camera's latest again.
    for (let c = 0; c < this.cameras; c++) {
      if (this.latest[c]) { this.sent[c].clear(); this.sendPose(c, this.latest[c]); }
    }
  }

  keyframe(c, reason, detail) {
    const req = { reason, frameSeq: this.lastApplied, detail: detail.slice(0, 200) };
    if (c === null) { for (let k = 0; k < this.cameras; k++) this.asked.add(k); } else { req.camera = c; this.asked.add(c); }
    this.stats.keyframeRequests++;
    this.send({ keyframeRequest: req });
  }

  framePart(frame, nbytes) {
    if (!this.ready) throw new ProtocolError("a Frame before the vertex buffer was complete");
    const now = performance.now();
    try {
      this.applyPart(frame, nbytes, now);
    } finally {
      this.stats.applyMs += performance.now() - now;
    }
  }

  applyPart(frame, nbytes, now) {
    if (!this.frame) {
      if (frame.frameSeq !== this.lastApplied + 1) {
        this.stats.badFrames++;
        this.keyframe(null, pb.KeyframeReason.KEYFRAME_REASON_BAD_FRAME, `frame ${frame.frameSeq} after ${this.lastApplied}`);
      }
      this.frame = { seq: frame.frameSeq, parts: 0, bytes: 0, crcs: new Map(), untrusted: new Set(), diverged: new Set(), cameras: new Map() };
    } else if (frame.frameSeq !== this.frame.seq) {
      throw new ProtocolError(`part of frame ${frame.frameSeq} inside frame ${this.frame.seq}`);
    }
    const update = this.frame;
    update.parts++;
    update.bytes += nbytes;
    this.stats.frameBytes += nbytes;
    for (const cf of frame.cameras) this.cameraPart(cf, update, now);
    if (frame.continued) return;
    this.frame = null;
    this.checkCrcs(update);
    this.lastApplied = update.seq;
    this.stats.frames++;
    const unacked = update.seq - this.lastAcked;
    const window = this.info.ackWindow;
    if (unacked >= Math.max(1, Math.floor(window / 2))) {
      if (this.info.acksOnPoses && unacked < window - 1) {
        this.ackDue = update.seq;
      } else {
        this.send({ ack: { frameSeq: update.seq } });
        this.lastAcked = update.seq;
      }
    }
    let faces = 0;
    for (const row of this.buffers) for (const b of row) faces += b.count;
    this.stats.facesDrawn = faces;
    if (this.newLatencies) this.latencyPercentiles();
    this.onFrame(update);
  }

  cameraPart(cf, update, now) {
    const c = cf.camera;
    if (c >= this.cameras) throw new ProtocolError(`a frame for camera ${c}; the session has ${this.cameras}`);
    if (!update.cameras.has(c)) {
      update.cameras.set(c, { keyframe: cf.keyframe, poseSeq: cf.poseSeq, surfaces: [] });
      if (cf.keyframe) {
        for (const b of this.buffers[c]) { b.resize(0); b.grown = true; }
        this.asked.delete(c);
      }
      if (cf.poseSeq > this.answered[c]) {
        this.answered[c] = cf.poseSeq;
        const sent = this.sent[c].get(cf.poseSeq);
        for (const seq of [...this.sent[c].keys()]) if (seq <= cf.poseSeq) this.sent[c].delete(seq);
        if (sent !== undefined) {
          this.latencies.push(now - sent);
          this.newLatencies = true;
        }
      }
    }
    if (cf.stats) {
      this.hidden[c] = cf.stats.hiddenParts || 0;
      this.stats.hiddenParts = this.hidden.reduce((a, b) => a + b, 0);
    }
    if (update.untrusted.has(c)) return;
    const nVertices = Number(this.info.vertexFormat.vertexCount);
    try {
      for (const sd of cf.surfaces) {
        const m = sd.material;
        if (m >= this.buffers[c].length) throw new OpStreamError(`material ${m} out of range: the mesh has ${this.buffers[c].length} materials`);
        const buffer = this.buffers[c][m];
        let slots, tris;
        if (sd.ops && sd.ops.length) {
          if ((sd.slots && sd.slots.length) || (sd.tris && sd.tris.length)) throw new OpStreamError(`material ${m}: a SurfaceDelta with both ops and slots or tris`);
          ({ slots, tris } = this.info.frameEncoding === pb.FrameEncoding.FRAME_ENCODING_OPS_LINKED
            ? decodeLinked(sd.ops, buffer.rows, buffer.count, sd.count, this.links())
            : decodeOps(sd.ops, buffer.rows, buffer.count, sd.count, nVertices));
        } else {
          ({ slots, tris } = this.rawWrites(sd, nVertices));
        }
        buffer.resize(sd.count);
        buffer.write(slots, tris);
        update.cameras.get(c).surfaces.push({ material: m, count: sd.count, slots, tris }); // for geomorphs
        if (sd.crc32 !== null && sd.crc32 !== undefined) update.crcs.set(`${c}/${m}`, [c, m, sd.crc32 >>> 0]);
      }
    } catch (err) {
      if (!(err instanceof OpStreamError)) throw err;
      update.untrusted.add(c);
      this.stats.badFrames++;
      if (!this.asked.has(c)) this.keyframe(c, pb.KeyframeReason.KEYFRAME_REASON_BAD_FRAME, err.message);
    }
  }

  /** The slot writes of a raw SurfaceDelta, checked as the proto requires (OpStreamError when malformed). */
  rawWrites(sd, nVertices) {
    const m = sd.material;
    if (sd.tris.length % 12) throw new OpStreamError(`material ${m}: tris has ${sd.tris.length} bytes, not whole (k, 3) uint32 rows`);
    const tris = u32(sd.tris), k = tris.length / 3;
    let slots;
    if (sd.slots && sd.slots.length) {
      if (sd.slots.length !== 4 * k) throw new OpStreamError(`material ${m}: ${sd.slots.length} bytes of slots for ${k} triangles`);
      slots = u32(sd.slots);
      for (let i = 1; i < k; i++) if (slots[i] <= slots[i - 1]) throw new OpStreamError(`material ${m}: slots are not ascending and unique`);
    } else {
      if (sd.firstSlot + k > sd.count) throw new OpStreamError(`material ${m}: slots ${sd.firstSlot}.. past the count ${sd.count}`);
      slots = new Uint32Array(k);
      for (let i = 0; i < k; i++) slots[i] = sd.firstSlot + i;
    }
    if (k && slots[k - 1] >= sd.count) throw new OpStreamError(`material ${m}: slot ${slots[k - 1]} past the count ${sd.count}`);
    for (let i = 0; i < tris.length; i++) if (tris[i] >= nVertices) throw new OpStreamError(`material ${m}: vertex index ${tris[i]} past the ${nVertices} vertices`);
    return { slots, tris };
  }

  checkCrcs(update) {
    for (const [c, m, crc] of update.crcs.values()) {
      if (update.untrusted.has(c) || this.asked.has(c) || update.diverged.has(c)) continue;
      this.stats.crcChecks++;
      const mine = this.buffers[c][m].crc32();
      if (mine !== crc) {
        this.stats.divergences++;
        update.diverged.add(c);
        this.keyframe(c, pb.KeyframeReason.KEYFRAME_REASON_CHECKSUM_MISMATCH,
          `material ${m}: crc 0x${mine.toString(16)}, server 0x${crc.toString(16)}`);
      }
    }
  }

  /** p50 and p99 of the latest LATENCIES_KEPT pose -> frame latencies: once a frame that answered poses. */
  latencyPercentiles() {
    if (this.latencies.length > LATENCIES_KEPT) this.latencies.splice(0, this.latencies.length - LATENCIES_KEPT);
    const sorted = [...this.latencies].sort((a, b) => a - b);
    this.stats.latencyMsP50 = percentile(sorted, 0.5);
    this.stats.latencyMsP99 = percentile(sorted, 0.99);
    this.newLatencies = false;
  }
}
