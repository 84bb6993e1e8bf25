// Geomorphs for the page: splits and collapses drawn as smooth changes of shape.
// A port of caveclod/client/geomorph.py (its module doc says how and why), step
// for step, so that the page draws what the Python renderer draws:
// tests/test_web_chromium.py feeds both the same frames and compares their
// display buffers and positions.

/** The points of a vertex buffer: vertices with equal coordinates share one; each point's target point. */
export function pointsOf(positions, targets) {
  const d = targets.length;
  const bits = new Uint32Array(positions.buffer, positions.byteOffset, 3 * d);
  const ids = new Map();
  const point = new Int32Array(d);
  const first = [];
  for (let v = 0; v < d; v++) {
    const key = `${bits[3 * v]},${bits[3 * v + 1]},${bits[3 * v + 2]}`;
    let p = ids.get(key);
    if (p === undefined) { p = first.length; ids.set(key, p); first.push(v); }
    point[v] = p;
  }
  const e = first.length;
  const start = new Int32Array(e + 1);
  for (let v = 0; v < d; v++) start[point[v] + 1]++;
  for (let p = 0; p < e; p++) start[p + 1] += start[p];
  const fill = start.slice(0, e), members = new Int32Array(d);
  for (let v = 0; v < d; v++) members[fill[point[v]]++] = v;
  const pointTarget = new Int32Array(e);
  for (let p = 0; p < e; p++) pointTarget[p] = point[targets[first[p]]];
  return { point, pointTarget, start, members };
}

function apart(a, b) {
  const x = b[0] - a[0], y = b[1] - a[1], z = b[2] - a[2];
  return Math.sqrt(x * x + y * y + z * z);
}

/** A camera's writes of one frame with one entry per material: the pieces of a frame larger than a
 * part (row ranges of one surface, each with the buffer's count) joined in order (geomorph.py's joined). */
export function joined(surfaces) {
  const pieces = new Map();
  for (const s of surfaces) {
    const list = pieces.get(s.material);
    if (list) list.push(s); else pieces.set(s.material, [s]);
  }
  const out = [];
  for (const [m, ps] of pieces) {
    if (ps.length === 1) { out.push(ps[0]); continue; }
    const n = ps.reduce((a, p) => a + p.slots.length, 0);
    const slots = new Uint32Array(n), tris = new Uint32Array(3 * n);
    let o = 0;
    for (const p of ps) { slots.set(p.slots, o); tris.set(p.tris, 3 * o); o += p.slots.length; }
    out.push({ material: m, count: ps[ps.length - 1].count, slots, tris });
  }
  return out;
}

function key(a, b, c) {
  // A triangle up to rotation: whichever corner comes first.
  if (a <= b && a <= c) return `${a},${b},${c}`;
  if (b <= a && b <= c) return `${b},${c},${a}`;
  return `${c},${a},${b}`;
}

/** Seconds the shortest morph takes with a speed (caveclod/client/geomorph.py's MIN_SPAN). */
const MIN_SPAN = 1e-3;

export class Geomorphs {
  /**
   * @param {Float32Array} positions (3d) the vertex buffer's positions
   * @param {Uint32Array} targets (d) morph targets
   * @param {number} materials index buffers per camera
   * @param {number} duration seconds a morph takes; with `speed`, the most it takes
   * @param {object} points pointsOf(positions, targets), shared by the cameras
   * @param {number|null} speed pixels a second: each morph then takes its path on screen over it
   *   (from where lookFrom last put the camera), at most `duration`
   */
  constructor(positions, targets, materials, duration, points, speed = null) {
    this.positions = positions;
    this.targets = targets;
    this.materials = materials;
    this.duration = duration;
    this.speed = speed;
    this.eye = null;
    this.kappa = 0;
    Object.assign(this, points);
    this.pointRefs = new Int32Array(this.pointTarget.length);
    this.rows = Array.from({ length: materials }, () => new Uint32Array(0));
    this.unposed = false; // showing a keyframe that answered no pose
    this.held = Array.from({ length: materials }, () => new Map());
    this.kept = Array.from({ length: materials }, () => []);
    this.active = new Map();
    this.shownKept = new Array(materials).fill(0);
    this.moved = new Set();
    this.snaps = 0;
  }

  own(p) {
    const v = this.members[this.start[p]];
    return [this.positions[3 * v], this.positions[3 * v + 1], this.positions[3 * v + 2]];
  }

  vertices(p) {
    return this.members.subarray(this.start[p], this.start[p + 1]);
  }

  /** Where point `p` is drawn at `now` (an anchor followed where it is drawn). */
  pointAt(p, now, depth = 0) {
    const m = this.active.get(p);
    const own = this.own(p);
    if (m === undefined || depth > 64) return own;
    const u = Math.min(Math.max((now - m.t0) / m.span, 0), 1);
    const a = m.start < 0 ? m.fixed : this.pointAt(m.start, now, depth + 1);
    const b = m.end < 0 ? own : this.pointAt(m.end, now, depth + 1);
    return [a[0] + (b[0] - a[0]) * u, a[1] + (b[1] - a[1]) * u, a[2] + (b[2] - a[2]) * u];
  }

  /** The display buffer of material `m` (count + kept rows), as the renderer holds it. */
  display(m) {
    const kept = this.kept[m];
    const out = new Uint32Array(this.rows[m].length + 3 * kept.length);
    out.set(this.rows[m]);
    for (const [slot, t] of this.held[m]) out.set(t, 3 * slot);
    kept.forEach((t, i) => out.set(t, this.rows[m].length + 3 * i));
    return out;
  }

  /** {vertices: Int32Array, positions: Float32Array}: the position rows that changed since the last call. */
  moving(now) {
    const pts = [...new Set([...this.active.keys(), ...this.moved])].sort((a, b) => a - b);
    this.moved = new Set(this.active.keys());
    const verts = [], where = [];
    const memo = new Map();
    for (const p of pts) {
      let at = memo.get(p);
      if (at === undefined) { at = this.pointAt(p, now); memo.set(p, at); }
      for (const v of this.vertices(p)) { verts.push(v); where.push(at[0], at[1], at[2]); }
    }
    return { vertices: Int32Array.from(verts), positions: Float32Array.from(where) };
  }

  /** One frame's writes of this camera ([{material, count, slots, tris}]); the display writes.
   * `posed`: the frame answers a pose (poseSeq > 0). A frame after a keyframe that answered none (a
   * session's first, the base mesh) is shown as it is, as a keyframe is, not grown out of the base
   * mesh over the morph time (as caveclod/client/geomorph.py). */
  apply(surfaces, keyframe, now, posed = true) {
    surfaces = joined(surfaces); // a material's pieces (a frame cut across parts) as one
    const out = this.tick(now);
    if (keyframe || this.unposed) {
      if (!keyframe) surfaces = this.whole(surfaces);
      this.unposed = !posed;
      return this.restart(surfaces, out);
    }
    const before = this.pointRefs.slice();
    const touched = new Set(), lost = [], newAt = new Map();
    for (const s of surfaces) {
      const m = s.material, count = s.count, rows = this.rows[m], n = rows.length / 3;
      const gone = [];
      for (const slot of s.slots) if (slot < n) gone.push(slot);
      for (let slot = count; slot < n; slot++) gone.push(slot);
      for (const slot of gone) {
        const shown = this.held[m].get(slot);
        this.held[m].delete(slot);
        lost.push([m, shown !== undefined ? shown : rows.subarray(3 * slot, 3 * slot + 3).slice()]);
        for (let k = 0; k < 3; k++) { const p = this.point[rows[3 * slot + k]]; this.pointRefs[p]--; touched.add(p); }
      }
      for (let i = 0; i < s.tris.length; i++) { const p = this.point[s.tris[i]]; this.pointRefs[p]++; touched.add(p); }
      const grown = new Uint32Array(3 * count);
      grown.set(rows.subarray(0, 3 * Math.min(count, n)));
      const where = new Map();
      for (let i = 0; i < s.slots.length; i++) {
        const o = 3 * s.slots[i];
        grown[o] = s.tris[3 * i]; grown[o + 1] = s.tris[3 * i + 1]; grown[o + 2] = s.tris[3 * i + 2];
        where.set(key(s.tris[3 * i], s.tris[3 * i + 1], s.tris[3 * i + 2]), s.slots[i]);
      }
      this.rows[m] = grown;
      newAt.set(m, where);
    }
    const changed = [...touched].sort((a, b) => a - b);
    for (const p of changed) if (before[p] === 0 && this.pointRefs[p] > 0) this.appear(p, before, now);
    for (const p of changed) if (before[p] > 0 && this.pointRefs[p] === 0) this.go(p, now);
    this.replace(lost, newAt);
    this.emit(out, surfaces, new Set());
    return out;
  }

  /** End the morphs that are over at `now` (call before drawing); the display writes. */
  tick(now) {
    const out = { writes: [], reset: false };
    const done = [...this.active.entries()].filter(([, m]) => now - m.t0 >= m.span * (1 - 1e-9))
      .sort((a, b) => a[1].t0 - b[1].t0 || a[0] - b[0]);
    if (!done.length) return out;
    const arrived = new Map();
    for (const [p, m] of done) {
      this.active.delete(p);
      this.moved.add(p);
      if (m.end >= 0) arrived.set(p, m.end);
    }
    const touched = new Set();
    if (arrived.size) this.handOn(arrived, touched);
    this.emit(out, [], touched);
    return out;
  }

  /** Every material's buffer once `surfaces`' writes are applied to it, as a keyframe's. */
  whole(surfaces) {
    const rows = this.rows.slice();
    for (const s of surfaces) {
      const n = rows[s.material].length / 3;
      const grown = new Uint32Array(3 * s.count);
      grown.set(rows[s.material].subarray(0, 3 * Math.min(s.count, n)));
      for (let i = 0; i < s.slots.length; i++) grown.set(s.tris.subarray(3 * i, 3 * i + 3), 3 * s.slots[i]);
      rows[s.material] = grown;
    }
    return rows.map((r, m) => ({ material: m, count: r.length / 3, slots: Uint32Array.from({ length: r.length / 3 }, (_, i) => i), tris: r }));
  }

  restart(surfaces, out) {
    for (const p of this.active.keys()) this.moved.add(p);
    this.active.clear();
    this.pointRefs.fill(0);
    for (let m = 0; m < this.materials; m++) {
      this.rows[m] = new Uint32Array(0);
      this.held[m].clear();
      this.kept[m] = [];
      this.shownKept[m] = 0;
    }
    out.reset = true;
    out.writes = [];
    for (const s of surfaces) {
      const rows = new Uint32Array(3 * s.count);
      for (let i = 0; i < s.slots.length; i++) rows.set(s.tris.subarray(3 * i, 3 * i + 3), 3 * s.slots[i]);
      this.rows[s.material] = rows;
      for (let i = 0; i < s.tris.length; i++) this.pointRefs[this.point[s.tris[i]]]++;
      out.writes.push({ material: s.material, count: s.count, slots: Uint32Array.from(s.slots), tris: Uint32Array.from(s.tris) });
    }
    return out;
  }

  anchor(p, refs) {
    let t = p;
    for (let i = 0; i < 256; i++) {
      const next = this.pointTarget[t];
      if (next === t) return -1;
      t = next;
      if (refs[t] > 0) return t;
    }
    return -1;
  }

  appear(p, before, now) {
    const back = this.active.get(p);
    if (back !== undefined && back.end >= 0) {
      const here = this.pointAt(p, now);
      this.active.set(p, { t0: now, start: -1, fixed: here, end: -1, span: this.span(here, this.own(p)) });
      this.dropTrianglesOf(p);
      return;
    }
    const a = this.anchor(p, before);
    if (a >= 0) this.active.set(p, { t0: now, start: a, fixed: null, end: -1, span: this.span(this.pointAt(a, now), this.own(p)) });
    this.moved.add(p);
  }

  go(p, now) {
    const a = this.anchor(p, this.pointRefs);
    if (a < 0) { this.active.delete(p); this.moved.add(p); return; }
    const here = this.pointAt(p, now);
    this.active.set(p, { t0: now, start: -1, fixed: here, end: a, span: this.span(here, this.pointAt(a, now)) });
  }

  /** Where the camera is, for the morphs the next frames begin (with a speed): eye [x, y, z] and
   * kappa, pixels a unit spans at distance 1 (height / (2 tan(fovY / 2))). */
  lookFrom(eye, kappa) {
    this.eye = [eye[0], eye[1], eye[2]];
    this.kappa = kappa;
  }

  /** Seconds a morph from a to b takes: the duration, or its length on screen (at the nearer end) over the speed. */
  span(a, b) {
    if (this.speed === null || this.eye === null) return this.duration;
    const pixels = apart(a, b) * this.kappa / Math.max(Math.min(apart(a, this.eye), apart(b, this.eye)), 1e-9);
    return Math.min(this.duration, Math.max(pixels / this.speed, MIN_SPAN));
  }

  anchorVertex(v, end) {
    let t = v;
    for (let i = 0; i < 256; i++) {
      if (this.point[t] === end) return t;
      const next = this.targets[t];
      if (next === t) break;
      t = next;
    }
    return this.members[this.start[end]];
  }

  isGoing(v) {
    const m = this.active.get(this.point[v]);
    return m !== undefined && m.end >= 0;
  }

  closure(tri) {
    return Array.from(tri, (v) => {
      for (let i = 0; i < 64; i++) {
        const m = this.active.get(this.point[v]);
        if (m === undefined || m.end < 0) break;
        v = this.anchorVertex(v, m.end);
      }
      return v;
    });
  }

  replace(lost, newAt) {
    for (const [m, tri] of lost) {
      if (!(this.isGoing(tri[0]) || this.isGoing(tri[1]) || this.isGoing(tri[2]))) continue;
      const moved = this.closure(tri);
      const whole = moved[0] !== moved[1] && moved[1] !== moved[2] && moved[0] !== moved[2];
      const slot = whole && newAt.has(m) ? newAt.get(m).get(key(moved[0], moved[1], moved[2])) : undefined;
      if (slot !== undefined && !this.held[m].has(slot)) this.held[m].set(slot, Uint32Array.from(tri));
      else this.kept[m].push(Uint32Array.from(tri));
    }
  }

  handOn(arrived, touched) {
    const final = (p) => { for (let i = 0; i < 64 && arrived.has(p); i++) p = arrived.get(p); return p; };
    const resolved = new Map([...arrived].map(([p, a]) => [p, final(a)]));
    for (const m of this.active.values()) {
      if (resolved.has(m.start)) m.start = resolved.get(m.start);
      if (resolved.has(m.end)) m.end = resolved.get(m.end);
    }
    const swap = new Map();
    for (const [p, a] of resolved) for (const v of this.vertices(p)) swap.set(v, this.anchorVertex(v, a));
    const sw = (tri) => Uint32Array.from(tri, (v) => (swap.has(v) ? swap.get(v) : v));
    for (let mat = 0; mat < this.materials; mat++) {
      for (const [slot, tri] of [...this.held[mat]]) {
        if (!(swap.has(tri[0]) || swap.has(tri[1]) || swap.has(tri[2]))) continue;
        const now = sw(tri);
        if (this.isGoing(now[0]) || this.isGoing(now[1]) || this.isGoing(now[2])) {
          this.held[mat].set(slot, now);
        } else {
          this.held[mat].delete(slot);
          const r = this.rows[mat];
          if (now[0] !== r[3 * slot] || now[1] !== r[3 * slot + 1] || now[2] !== r[3 * slot + 2]) this.snaps++;
        }
        touched.add(`${mat}/${slot}`);
      }
      const kept = [];
      for (const tri of this.kept[mat]) {
        const now = swap.has(tri[0]) || swap.has(tri[1]) || swap.has(tri[2]) ? sw(tri) : tri;
        if (this.isGoing(now[0]) || this.isGoing(now[1]) || this.isGoing(now[2])) kept.push(now);
        else if (now[0] !== now[1] && now[1] !== now[2] && now[0] !== now[2]) this.snaps++;
      }
      this.kept[mat] = kept;
    }
  }

  dropTrianglesOf(p) {
    const verts = new Set(this.vertices(p));
    const has = (t) => verts.has(t[0]) || verts.has(t[1]) || verts.has(t[2]);
    for (let mat = 0; mat < this.materials; mat++) {
      for (const [slot, t] of [...this.held[mat]]) if (has(t)) this.held[mat].delete(slot);
      this.kept[mat] = this.kept[mat].filter((t) => !has(t));
    }
  }

  emit(out, surfaces, touched) {
    const mats = new Set(surfaces.map((s) => s.material));
    for (const t of touched) mats.add(Number(t.split("/")[0]));
    for (let m = 0; m < this.materials; m++) if (this.kept[m].length || this.shownKept[m]) mats.add(m);
    for (const m of [...mats].sort((a, b) => a - b)) {
      const count = this.rows[m].length / 3;
      const slots = new Set();
      for (const s of surfaces) if (s.material === m) for (const x of s.slots) slots.add(x);
      for (const t of touched) { const [mm, slot] = t.split("/").map(Number); if (mm === m && slot < count) slots.add(slot); }
      for (const slot of this.held[m].keys()) slots.add(slot);
      const sorted = [...slots].sort((a, b) => a - b);
      const kept = this.kept[m];
      const n = sorted.length, k = kept.length;
      const outSlots = new Uint32Array(n + (k || this.shownKept[m] ? k : 0));
      const outTris = new Uint32Array(3 * outSlots.length);
      sorted.forEach((slot, i) => {
        outSlots[i] = slot;
        const held = this.held[m].get(slot);
        outTris.set(held !== undefined ? held : this.rows[m].subarray(3 * slot, 3 * slot + 3), 3 * i);
      });
      kept.forEach((t, i) => { outSlots[n + i] = count + i; outTris.set(t, 3 * (n + i)); });
      this.shownKept[m] = k;
      out.writes.push({ material: m, count: count + k, slots: outSlots, tris: outTris });
    }
  }
}
