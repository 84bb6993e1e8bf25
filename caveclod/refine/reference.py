"""A slow, plainly written reference of the per-camera refinement.

Used only by tests, to check the compiled kernels of
:mod:`caveclod.kernels.refine` decision by decision. Everything here is plain
Python (lists, dicts, sets); the static arrays are read once, up front, into
Python ints and floats. It is written from the rules (DESIGN.md section 3,
Hoppe 1997 "View-dependent refinement of progressive meshes"), so it reads as
the specification of one update:

1. Sort the active-node list by node id, then walk it front to back. Nodes
   appended during the walk (the children of a split, the parent of a
   collapse) go to the back and are visited in the same walk; a node that is
   no longer active when reached is dropped. A node is appended only if it is
   not in the list already.
2. An internal active node that needs detail is split, forcing first the
   splits its split requires (Hoppe's stack).
3. Otherwise, if it is its parent's stationary child (the stationary child
   speaks for the pair), the parent does not need detail and the collapse
   back into the parent is legal, the pair collapses and the parent joins
   the list.
4. After a collapse, the collapses it may have made possible are tried at
   once, last pushed first: the collapsed node's parent and the nodes that
   created its four required faces (each pushed once, while it is split).
   A candidate collapses when both its children are active, it does not
   need detail and its collapse is legal; its own candidates are pushed in
   turn.
5. Once the operation budget is spent, nodes are kept as they are.
6. Parts (connected components of the base mesh) that the view need not
   draw vanish: before the walk, each hidden part that is to be drawn
   comes back (its roots active and listed, its base faces added); after
   it, each visible part that is not to be drawn is hidden, however refined
   (every face on its positions removed, its nodes inactive, its roots
   hidden; their list entries stay, to be dropped by the next walk as
   inactive, or visited where they stand if the node is active again by
   then: a shown root keeps its entry). With pruning allowed, a part is not drawn
   when the sphere (c, r) around its original positions lies wholly outside
   a frustum plane (culling on), or projects smaller than the tolerance:
   the node test with an error of 2 r.
7. With the strict bound (``strict_bound=True``), no active node stands
   beside a position collapsed away before the node was made (node ids are
   in build order): a split first splits, in the order of
   :meth:`ReferenceCamera.split_blockers`, the active nodes newer than it
   beside its floating child's position; a collapse is legal only if no
   position beside the node's two was gone before it; after a collapse the
   parents, newer than it, of the active nodes beside it are pushed as
   candidates too (after rule 4's). The ring test is off.

Node ids: leaves ``0 .. e-1`` are positions; internal node ``x`` has its
static data at index ``x - e``. A split of ``s`` into ``t`` (stationary, at
s's position) and ``u`` (floating) creates ``fl = (t, u, vl)`` and
``fr = (u, t, vr)`` (either may be absent on a border) and requires the
neighbour faces ``fn = (fl_u, fl_t, fr_u, fr_t)``::

        vl
       /  \\          fl_u across fl's edge u -> vl, fl_t across vl -> t
      / fl \\         fr_u across fr's edge vr -> u, fr_t across t -> vr
     t ---- u
      \\ fr /
       \\  /
        vr

Faces keep their corners as *positions* and edge ``k`` of a face runs from
corner ``k`` to corner ``k + 1``; ``nbr[k]`` is the face across edge ``k``
(-1 on a border).
"""

from __future__ import annotations

import math

INACTIVE, ACTIVE, SPLIT, HIDDEN = "inactive", "active", "split", "hidden"


class ReferenceCamera:
    """One camera's refinement state, in plain Python.

    Args:
        mesh: a :class:`caveclod.StaticMesh`.
        max_ops: at most this many splits + collapses per update (None: no limit).
        max_faces: a split is made only while ``active faces + 2 <= max_faces``
            (a budget of at least the mesh's faces is none).
        strict_bound: rule 7 of the module doc.
    """

    def __init__(self, mesh, max_ops=None, max_faces=None, strict_bound=False):
        self.max_ops = math.inf if max_ops is None else int(max_ops)
        # A face budget the mesh cannot reach is no budget (as CameraState has it): one mixed pass.
        self.max_faces = math.inf if max_faces is None or max_faces >= mesh.n_faces else int(max_faces)
        self._read_static(mesh)
        self.strict = bool(strict_bound)
        if self.strict:
            self.ring = None                  # the strict bound does the ring test's work (and more)
            # The last node at each position: the nodes at a position form one chain of stationary
            # children, and the last one's parent is the collapse that took the position away.
            self.top = list(range(self.e))
            for j, p in enumerate(self.node_pos):
                self.top[p] = max(self.top[p], self.e + j)
        # Per-camera state.
        self.state = {}                       # node -> ACTIVE / SPLIT (absent: INACTIVE)
        self.faces = {}                       # face -> {"pos": [p0, p1, p2], "nbr": [f0, f1, f2]}
        self.faces_at = {}                    # position -> set of active faces with a corner there
        self.active = []                      # the active-node list, in visiting order
        self.in_list = set()                  # nodes currently in self.active
        self.splits = self.collapses = 0
        self.parts_shown = self.parts_hidden = 0
        for x in range(self.n_nodes):         # the roots form the base mesh's front
            if self.parent[x] < 0:
                self.state[x] = ACTIVE
                self.active.append(x)
                self.in_list.add(x)
        for f, nodes, nbrs in self.base:
            self._add_face(f, [self.position(x) for x in nodes], list(nbrs))
        self._find_parts(mesh)
        self.hidden = set()                   # parts hidden (small, or out of view)

    def _read_static(self, mesh):
        def ints(name):
            return [int(v) for v in getattr(mesh, name)]

        def rows(name, conv):
            return [tuple(conv(v) for v in row) for row in getattr(mesh, name)]

        self.e = mesh.n_positions
        self.n_nodes = mesh.n_nodes
        self.parent = ints("node_parent")
        self.children = rows("node_children", int)        # (t, u), by node - e
        self.node_pos = ints("node_position")
        self.new_faces = rows("node_faces", int)          # (fl, fr)
        self.required = rows("node_fn", int)              # (fl_u, fl_t, fr_u, fr_t)
        self.sphere = rows("node_sphere", float)          # float32 -> exact Python floats
        self.error = [float(v) for v in mesh.node_error]
        self.cone = rows("node_cone", float)
        ring = mesh.arrays.get("node_ring")                # (reach, error); files from before it have none
        self.ring = rows("node_ring", float) if ring is not None and len(ring) else None
        self.creator = ints("face_creator")
        self.rotation = ints("face_rotation")            # where a split's first corner goes
        self.material = ints("face_material")
        self.sgid = ints("face_sgid")
        self.base = list(zip(ints("base_faces"), rows("base_face_nodes", int), rows("base_face_nbrs", int)))
        # D3Dindex: (surface group id, position) -> the first vertex-buffer entry.
        start, vsg = ints("pos_vstart"), ints("vertex_sgid")
        self.vertex_of = {}
        for p in range(self.e):
            for i in range(start[p], start[p + 1]):
                self.vertex_of.setdefault((vsg[i], p), i)

    def _find_parts(self, mesh):
        """Parts: base faces joined through shared nodes, numbered in order of
        their first base face; each part's roots, base faces and sphere."""
        part_of = {}                          # node -> part, by flooding from each base face in order
        faces_at = {}
        for i, (_, nodes, _) in enumerate(self.base):
            for x in nodes:
                faces_at.setdefault(x, []).append(i)
        self.part_faces, self.part_roots = [], []
        for i, (_, nodes, _) in enumerate(self.base):
            if nodes[0] in part_of:
                continue
            k = len(self.part_faces)
            todo, seen = [i], {i}
            while todo:
                j = todo.pop()
                for x in self.base[j][1]:
                    part_of[x] = k
                    for g in faces_at[x]:
                        if g not in seen:
                            seen.add(g)
                            todo.append(g)
            self.part_faces.append(sorted(seen))
            self.part_roots.append(sorted({x for j in seen for x in self.base[j][1]}))
        # The sphere around each part's original positions (leaves): the box's
        # middle, then the farthest position's distance from it.
        pos = [[float(v) for v in row] for row in mesh.positions]
        lo = [[math.inf] * 3 for _ in self.part_faces]
        hi = [[-math.inf] * 3 for _ in self.part_faces]
        self.node_part = []                   # the part of every node (-1: a root in no base face)
        for x in range(self.n_nodes):
            top = x
            while self.parent[top] >= 0:
                top = self.parent[top]
            self.node_part.append(part_of.get(top, -1))
        leaf_part = self.node_part[:self.e]
        for x in range(self.e):
            k = leaf_part[x]
            if k >= 0:
                for j in range(3):
                    lo[k][j] = min(lo[k][j], pos[x][j])
                    hi[k][j] = max(hi[k][j], pos[x][j])
        centre = [[0.5 * (a + b) for a, b in zip(lo[k], hi[k])] for k in range(len(lo))]
        radius = [0.0] * len(lo)
        for x, k in enumerate(leaf_part):
            if k >= 0:
                dx, dy, dz = (pos[x][j] - centre[k][j] for j in range(3))
                radius[k] = max(radius[k], math.sqrt(dx * dx + dy * dy + dz * dz))
        self.part_sphere = [(*centre[k], radius[k]) for k in range(len(lo))]

    # -- small facts ----------------------------------------------------------
    def position(self, x):
        """Position of node ``x``: its own id for a leaf, its stationary child's otherwise."""
        return x if x < self.e else self.node_pos[x - self.e]

    def is_leaf(self, x):
        return x < self.e

    def node_state(self, x):
        return self.state.get(x, INACTIVE)

    def face_active(self, f):
        return f in self.faces

    def n_faces(self):
        return len(self.faces)

    def ops(self):
        return self.splits + self.collapses

    # -- face records ---------------------------------------------------------
    def _add_face(self, f, pos, nbr, rot=0):
        """Face ``f`` on positions ``pos``, neighbour ``nbr[i]`` across
        ``pos[i] -> pos[i+1]``, listed from corner ``rot`` on (the source
        face's order)."""
        assert f not in self.faces and len(set(pos)) == 3
        order = [(i - rot) % 3 for i in range(3)]        # record corner k holds pos[order[k]]
        self.faces[f] = {"pos": [pos[i] for i in order], "nbr": [nbr[i] for i in order]}
        for p in pos:
            self.faces_at.setdefault(p, set()).add(f)

    def _remove_face(self, f):
        for p in self.faces.pop(f)["pos"]:
            self.faces_at[p].discard(f)

    def _move_corner(self, f, old, new):
        """Face ``f``'s corner at position ``old`` now sits at ``new``."""
        pos = self.faces[f]["pos"]
        pos[pos.index(old)] = new
        self.faces_at[old].discard(f)
        self.faces_at.setdefault(new, set()).add(f)

    def _corner(self, f, p):
        return self.faces[f]["pos"].index(p)

    def _after(self, f, p):
        """The corner following position ``p`` in face ``f``."""
        return self.faces[f]["pos"][(self._corner(f, p) + 1) % 3]

    def _before(self, f, p):
        """The corner preceding position ``p`` in face ``f``."""
        return self.faces[f]["pos"][(self._corner(f, p) + 2) % 3]

    def _set_neighbour(self, f, a, b, g):
        """The face across ``f``'s directed edge ``a -> b`` becomes ``g``."""
        k = self._corner(f, a)
        assert self.faces[f]["pos"][(k + 1) % 3] == b, f"face {f} has no edge {a}->{b}"
        self.faces[f]["nbr"][k] = g

    def _replace_neighbour(self, f, old, new):
        nbr = self.faces[f]["nbr"]
        nbr[nbr.index(old)] = new

    def _step_out(self, f, p):
        """The face after ``f`` around ``p``: across p's outgoing edge."""
        return self.faces[f]["nbr"][self._corner(f, p)]

    def _step_in(self, f, p):
        """The face before ``f`` around ``p``: across p's incoming edge."""
        return self.faces[f]["nbr"][(self._corner(f, p) + 2) % 3]

    # -- the view criteria ----------------------------------------------------
    def need_refine(self, x):
        """Whether internal node ``x`` needs detail for the current view.

        Same float64 arithmetic, in the same order, as the compiled kernel:
        frustum (bounding sphere against five planes), back-facing (normal
        cone, when enabled) and screen-space error ``err * kappa / distance``
        against the tolerance in pixels, or the ring bound's error at the
        sphere grown by its reach (``caveclod.kernels.simplify.ring_bound``).
        """
        v = self.view
        cx, cy, cz, r = self.sphere[x - self.e]
        if v["cull"]:
            for nx, ny, nz, d in v["planes"]:
                if nx * cx + ny * cy + nz * cz + d < -r:
                    return False                  # the sphere lies wholly outside a plane
        ex, ey, ez = v["eye"]
        dx, dy, dz = cx - ex, cy - ey, cz - ez
        length = math.sqrt(dx * dx + dy * dy + dz * dz)
        ax, ay, az, spread = self.cone[x - self.e]
        if v["backface"] and length > r and spread < 0.5 * math.pi:
            cosphi = (ax * dx + ay * dy + az * dz) / length
            phi = math.acos(min(1.0, max(-1.0, cosphi)))
            if phi + spread + math.asin(r / length) < 0.5 * math.pi:
                return False                      # every normal faces away from the eye
        if v["tolerance"] <= 0.0:
            return True
        dist = length - r
        if dist <= 0.0:
            return True                           # the eye is inside the sphere
        if self.ring is not None:
            reach, ring_error = self.ring[x - self.e]
            if ring_error > 0.0 and (dist - reach <= 0.0 or ring_error * v["kappa"] > v["tolerance"] * (dist - reach)):
                return True                       # a node beside it may need detail by its own test
        return self.error[x - self.e] * v["kappa"] > v["tolerance"] * dist

    # -- splits ---------------------------------------------------------------
    def split_legal(self, x):
        """Hoppe's vsplit precondition: ``x`` is active and every required face is."""
        return self.node_state(x) == ACTIVE and all(
            f < 0 or self.face_active(f) for f in self.required[x - self.e])

    def budget_allows_split(self):
        return self.ops() < self.max_ops and self.n_faces() + 2 <= self.max_faces

    def force_split(self, x):
        """Split ``x``, first splitting whatever its split requires.

        Hoppe's stack: look at the top node. Already split: pop it. Not yet
        active: push its parent. Some required faces missing: push, in order
        fl_u, fl_t, fr_u, fr_t, the node whose split creates each missing
        face. Otherwise split it and pop. Stops (leaving everything
        consistent) when the budget runs out.
        """
        stack = [x]
        while stack:
            y = stack[-1]
            if self.node_state(y) == SPLIT or self.is_leaf(y):
                stack.pop()
                continue
            if self.node_state(y) == INACTIVE:
                stack.append(self.parent[y])
                continue
            missing = [f for f in self.required[y - self.e] if f >= 0 and not self.face_active(f)]
            if missing:
                stack.extend(self.creator[f] for f in missing)
                continue
            if self.strict:
                blockers = self.split_blockers(y)
                if blockers:
                    stack.extend(blockers)
                    continue
            if not self.budget_allows_split():
                return
            assert self.split_legal(y)
            self.split(y)
            stack.pop()

    # -- the strict bound ---------------------------------------------------------
    def gone_before(self, q, x):
        """Whether position ``q`` had been collapsed away before node ``x`` was made
        (node ids are in the order the build made them)."""
        g = self.parent[self.top[q]]
        return 0 <= g < x

    def active_at(self, q):
        """The active node at position ``q``, or -1."""
        x = q
        while x >= 0:
            if self.node_state(x) == ACTIVE:
                return x
            if x == self.top[q]:
                return -1
            x = self.parent[x]
        return -1

    def split_blockers(self, y):
        """The strict bound's extra dependencies of splitting ``y``: the active
        nodes newer than ``y`` that would stand beside its floating child's
        position, gone before they were made. In order: the corners of the
        wedge moving to u (from fl_u round to fr_u; with fl_u absent, from
        fr_u back to the border), then fl's and fr's third corners."""
        j = y - self.e
        fl, fr = self.new_faces[j]
        fn0, fn1, fn2, fn3 = self.required[j]
        p = self.position(y)
        out = []

        def note(q):
            if self.top[q] > y:
                a = self.active_at(q)
                if a > y and a not in out:
                    out.append(a)

        def corners(f):
            k = self._corner(f, p)
            return [self.faces[f]["pos"][(k + 1) % 3], self.faces[f]["pos"][(k + 2) % 3]]

        if fn0 >= 0:
            f = fn0
            while True:
                for q in corners(f):
                    note(q)
                if f == fn2:
                    break
                f = self._step_out(f, p)
                if f < 0 or f == fr:
                    break
        elif fn2 >= 0:
            f = fn2
            while True:
                for q in corners(f):
                    note(q)
                f = self._step_in(f, p)
                if f < 0 or f == fl:
                    break
        if fl >= 0 and (fn0 >= 0 or fn1 >= 0):
            note(self._before(fn0, p) if fn0 >= 0 else self._after(fn1, p))
        if fr >= 0 and (fn2 >= 0 or fn3 >= 0):
            note(self._after(fn2, p) if fn2 >= 0 else self._before(fn3, p))
        return out

    def fan(self, f0, p):
        """The active faces round position ``p`` from face ``f0``: forward
        (across p's outgoing edges) until back at ``f0`` or at a border, then
        backward from ``f0`` to the border."""
        out = [f0]
        f = self._step_out(f0, p)
        while f >= 0 and f != f0:
            out.append(f)
            f = self._step_out(f, p)
        if f < 0:
            f = self._step_in(f0, p)
            while f >= 0:
                out.append(f)
                f = self._step_in(f, p)
        return out

    def strict_collapse_legal(self, s):
        """Undoing ``s``'s split keeps every position beside it one that was
        still there when ``s`` was made."""
        t, u = self.children[s - self.e]
        fl, fr = self.new_faces[s - self.e]
        f0 = fl if fl >= 0 else fr
        if f0 < 0:
            return True
        pt, pu = self.position(t), self.position(u)
        for p in (pt, pu):
            for f in self.fan(f0, p):
                if f in (fl, fr):
                    continue
                k = self._corner(f, p)
                for q in (self.faces[f]["pos"][(k + 1) % 3], self.faces[f]["pos"][(k + 2) % 3]):
                    if q not in (pt, pu) and self.gone_before(q, s):
                        return False
        return True

    def beside_candidates(self, s):
        """After collapsing ``s`` (strict bound): the parents of the active
        nodes beside it, whose collapse a position just gone may have
        blocked: those newer than ``s`` (u's position was gone before s only
        for them); round s from the first of fl_t, fl_u, fr_t, fr_u present."""
        fn0, fn1, fn2, fn3 = self.required[s - self.e]
        start = [f for f in (fn1, fn0, fn3, fn2) if f >= 0]
        if not start:
            return []
        p = self.position(s)
        out = []
        for f in self.fan(start[0], p):
            k = self._corner(f, p)
            for q in (self.faces[f]["pos"][(k + 1) % 3], self.faces[f]["pos"][(k + 2) % 3]):
                b = self.active_at(q)
                if b >= 0 and self.parent[b] > s:
                    out.append(self.parent[b])
        return out

    def faces_moving_to_u(self, x):
        """The active faces around ``x`` that lie on its floating child's side.

        They form the wedge from fl_u round to fr_u (turning away from fl),
        reached from either end; with fl_u absent, the wedge runs from fr_u
        round the other way to the border (and the reverse).
        """
        fn0, _, fn2, _ = self.required[x - self.e]
        p = self.position(x)
        wedge = []
        for start, step, stop in ((fn0, self._step_out, fn2), (fn2, self._step_in, fn0)):
            f, steps = start, 0
            while f >= 0:
                if f not in wedge:
                    wedge.append(f)
                if f == stop:
                    break
                f = step(f, p)
                steps += 1
                assert steps <= len(self.faces), f"the fan walk round node {x} does not end"
        return wedge

    def split(self, x):
        """Split active node ``x`` into its children (all required faces active)."""
        t, u = self.children[x - self.e]
        fl, fr = self.new_faces[x - self.e]
        fn0, fn1, fn2, fn3 = self.required[x - self.e]
        pt, pu = self.position(x), self.position(u)
        assert self.position(t) == pt
        # 1. The faces on u's side move their corner from s to u.
        for f in self.faces_moving_to_u(x):
            self._move_corner(f, pt, pu)
        # 2. fl = (t, u, vl) and fr = (u, t, vr) appear between the wedges;
        #    the four required faces now border them instead of each other.
        if fl >= 0:
            vl = self._before(fn0, pu) if fn0 >= 0 else self._after(fn1, pt)
            self._add_face(fl, [pt, pu, vl], [fr, fn0, fn1], self.rotation[fl])
            if fn0 >= 0:
                self._set_neighbour(fn0, vl, pu, fl)
            if fn1 >= 0:
                self._set_neighbour(fn1, pt, vl, fl)
        if fr >= 0:
            vr = self._after(fn2, pu) if fn2 >= 0 else self._before(fn3, pt)
            self._add_face(fr, [pu, pt, vr], [fl, fn3, fn2], self.rotation[fr])
            if fn2 >= 0:
                self._set_neighbour(fn2, pu, vr, fr)
            if fn3 >= 0:
                self._set_neighbour(fn3, vr, pt, fr)
        self.state[x] = SPLIT
        self.state[t] = ACTIVE
        self.state[u] = ACTIVE
        self.splits += 1
        for child in (t, u):
            self.append(child)

    # -- collapses ------------------------------------------------------------
    def collapse_legal(self, s):
        """Hoppe's ecol precondition for undoing the split of ``s``.

        Both children are active, fl's neighbours across u -> vl and vl -> t
        are fl_u, fl_t, and fr's across t -> vr and vr -> u are fr_t, fr_u.
        """
        t, u = self.children[s - self.e]
        if self.node_state(t) != ACTIVE or self.node_state(u) != ACTIVE:
            return False
        fl, fr = self.new_faces[s - self.e]
        fn0, fn1, fn2, fn3 = self.required[s - self.e]
        pt, pu = self.position(s), self.position(u)
        if fl >= 0 and [self._across(fl, pu), self._across(fl, self._after(fl, pu))] != [fn0, fn1]:
            return False
        if fr >= 0 and [self._across(fr, pt), self._across(fr, self._after(fr, pt))] != [fn3, fn2]:
            return False
        return not self.strict or self.strict_collapse_legal(s)

    def _across(self, f, p):
        """The neighbour of face ``f`` across its edge from position ``p``."""
        return self.faces[f]["nbr"][self._corner(f, p)]

    def collapse(self, s):
        """Undo the split of ``s`` (legal): u's faces return to s, fl and fr go."""
        t, u = self.children[s - self.e]
        fl, fr = self.new_faces[s - self.e]
        fn0, fn1, fn2, fn3 = self.required[s - self.e]
        pt, pu = self.position(s), self.position(u)
        # Every other active face at u's position is one of u's; it moves to s.
        for f in sorted(self.faces_at.get(pu, set()) - {fl, fr}):
            self._move_corner(f, pu, pt)
        # fl's and fr's outer neighbours border each other again.
        if fl >= 0:
            if fn0 >= 0:
                self._replace_neighbour(fn0, fl, fn1)
            if fn1 >= 0:
                self._replace_neighbour(fn1, fl, fn0)
            self._remove_face(fl)
        if fr >= 0:
            if fn2 >= 0:
                self._replace_neighbour(fn2, fr, fn3)
            if fn3 >= 0:
                self._replace_neighbour(fn3, fr, fn2)
            self._remove_face(fr)
        self.state[s] = ACTIVE
        del self.state[t]
        del self.state[u]
        self.collapses += 1
        self.append(s)

    # -- the active list and one update ----------------------------------------
    def append(self, x):
        """Put ``x`` at the back of the active list unless it is there already."""
        if x not in self.in_list:
            self.in_list.add(x)
            self.active.append(x)

    def adapt(self, splits=True, collapses=True):
        """One pass over the active list (see the module docstring).

        ``splits``/``collapses`` say which operations the pass may make.
        """
        self.active.sort()                       # each pass visits the front in id order
        kept = []
        i = 0
        while i < len(self.active):              # the list grows during the pass
            x = self.active[i]
            i += 1
            if self.node_state(x) != ACTIVE:
                self.in_list.discard(x)           # split or collapsed away meanwhile
                continue
            if self.ops() >= self.max_ops:
                kept.append(x)
                continue
            if splits and not self.is_leaf(x) and self.need_refine(x):
                self.force_split(x)
                if self.node_state(x) == ACTIVE:  # the budget ran out first
                    kept.append(x)
                else:
                    self.in_list.discard(x)
                continue
            s = self.parent[x]
            if collapses and s >= 0 and self.children[s - self.e][0] == x \
                    and not self.need_refine(s) and self.collapse_legal(s):
                self.collapse(s)
                self.in_list.discard(x)
                self.try_candidates(self.candidates_of(s))
                continue
            kept.append(x)
        self.active = kept

    def candidates_of(self, s):
        """Nodes whose collapse the collapse of ``s`` may have made legal, in push order."""
        fn = self.required[s - self.e]
        out = [self.parent[s]] + [self.creator[f] if f >= 0 else -1 for f in fn]
        return out + self.beside_candidates(s) if self.strict else out

    def try_candidates(self, pushed):
        """Collapse candidates, last pushed first; each is pushed once while split."""
        stack, queued = [], set()

        def push(nodes):
            for c in nodes:
                if c >= self.e and self.node_state(c) == SPLIT and c not in queued:
                    queued.add(c)
                    stack.append(c)

        push(pushed)
        while stack:
            c = stack.pop()
            queued.discard(c)
            if self.node_state(c) != SPLIT:
                continue
            t, u = self.children[c - self.e]
            if self.node_state(t) != ACTIVE or self.node_state(u) != ACTIVE or self.need_refine(c) \
                    or not self.collapse_legal(c):
                continue
            if self.ops() >= self.max_ops:
                continue
            self.collapse(c)
            push(self.candidates_of(c))

    # -- parts that vanish --------------------------------------------------------
    def part_drawn(self, k):
        """Whether part ``k`` is to be drawn (rule 6)."""
        v = self.view
        if not v["prune"]:
            return True
        cx, cy, cz, r = self.part_sphere[k]
        if v["cull"]:
            for nx, ny, nz, d in v["planes"]:
                if nx * cx + ny * cy + nz * cz + d < -r:
                    return False                  # wholly outside a plane
        if v["tolerance"] <= 0.0:
            return True
        ex, ey, ez = v["eye"]
        dx, dy, dz = cx - ex, cy - ey, cz - ez
        dist = math.sqrt(dx * dx + dy * dy + dz * dz) - r
        return dist <= 0.0 or 2.0 * r * v["kappa"] > v["tolerance"] * dist

    def show_parts(self):
        for k in sorted(self.hidden):
            if self.part_drawn(k):
                self.hidden.discard(k)
                for i in self.part_faces[k]:
                    f, nodes, nbrs = self.base[i]
                    self._add_face(f, [self.position(x) for x in nodes], list(nbrs))
                for x in self.part_roots[k]:
                    self.state[x] = ACTIVE
                    self.append(x)
                self.parts_shown += 1

    def hide_parts(self):
        for k in range(len(self.part_faces)):
            if k in self.hidden or self.part_drawn(k):
                continue
            self.hidden.add(k)
            for f in [f for f, rec in self.faces.items() if self.node_part[rec["pos"][0]] == k]:
                self._remove_face(f)
            for x in [x for x in self.state if self.node_part[x] == k]:
                del self.state[x]                 # inactive
            for x in self.part_roots[k]:
                self.state[x] = HIDDEN
            # The part's nodes keep their list entries (rule 6): the next
            # walk drops each when it reaches it, unless the node is active
            # again by then (a shown root, a node split into), which the
            # walk then visits there, not at the back.
            self.parts_hidden += 1

    def update(self, view):
        """Refine for ``view`` (a :class:`caveclod.refine.view.View`); returns (splits, collapses)."""
        self.set_view(view)
        self.splits = self.collapses = 0
        self.parts_shown = self.parts_hidden = 0
        self.show_parts()
        if self.max_ops == math.inf and self.max_faces == math.inf:
            self.adapt()
        else:
            # With a budget: refine first, coarsen with what budget is left,
            # so a forced split cut short is not undone by the next update.
            self.adapt(collapses=False)
            if self.ops() < self.max_ops:
                self.adapt(splits=False)
        self.hide_parts()
        return self.splits, self.collapses

    def set_view(self, view):
        """Read the criteria :meth:`need_refine` uses from ``view``'s parameter vector."""
        from .view import P_BACKFACE, P_CULL, P_EYE, P_KAPPA, P_PLANES, P_PRUNE, P_TOL
        vp = [float(v) for v in view.params()]
        self.view = {
            "eye": vp[P_EYE:P_EYE + 3],
            "planes": [vp[P_PLANES + 4 * i:P_PLANES + 4 * i + 4] for i in range(5)],
            "kappa": vp[P_KAPPA],
            "tolerance": vp[P_TOL],
            "cull": vp[P_CULL] != 0.0,
            "backface": vp[P_BACKFACE] != 0.0,
            "prune": vp[P_PRUNE] != 0.0,
        }

    # -- what the camera shows ----------------------------------------------------
    def vertex(self, f, p):
        """Vertex-buffer index of face ``f``'s corner at position ``p`` (D3Dindex)."""
        return self.vertex_of[(self.sgid[f], p)]

    def triangles(self):
        """{material: set of (a, b, c) vertex indices, rotated so the smallest is first}."""
        out = {}
        for f, rec in self.faces.items():
            tri = [self.vertex(f, p) for p in rec["pos"]]
            k = tri.index(min(tri))
            out.setdefault(self.material[f], set()).add(tuple(tri[k:] + tri[:k]))
        return out

    def active_nodes(self):
        """Sorted list of the active nodes (the front)."""
        return sorted(x for x, st in self.state.items() if st == ACTIVE)
