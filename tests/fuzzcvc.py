"""Fuzz the ``.cvc`` reader, the structural check, the refinement kernels and ``caveclod serve``
with damaged copies of a small built mesh.

:func:`fuzz_cvc` mutates a copy of a tiny terrain (:func:`make_base`: 2,048
triangles) per case (:func:`mutate`): bit flips, pokes and swaps inside
arrays picked by name through the header's offsets, bit flips in the
stored packed downloads (attachments), bit flips and edits of the header
JSON (wrong counts, offsets, byte counts, dtypes and types, missing keys,
huge materials lists, deep nesting, attachment entries and their
metadata), a damaged prefix, byte pokes and truncations. Each file goes through a :class:`fuzzing.CliWorker`,
which survives crashes and hangs: ``caveclod inspect F``, and when that
accepts it, ``caveclod inspect --verify F`` and :func:`refine_a_little`
(two cameras, one in cache mode, flown near and far over the terrain).
Every ``serve_every``-th case also goes to a real ``caveclod serve`` of the
good mesh and the damaged one (:func:`serve_case`).

The contract of a case: exit 0, or exit 2 with exactly one
``caveclod: error:`` line; never a traceback, a crash, a hang (each call
has :data:`CASE_TIMEOUT` seconds) or a warning. ``serve`` either refuses at
start (exit 2, one line) or answers an Open of the damaged mesh with a
SessionInfo and frames or a clear status (not UNKNOWN or INTERNAL), goes on
serving the good mesh, and exits 0 on SIGTERM; every wait is bounded.

Run it briefly from tests/test_fuzz_cvc.py, for long from the command line::

    .venv/bin/python tests/fuzzcvc.py --seconds 600 --seed 1 --workdir /tmp/fuzzcvc
"""

from __future__ import annotations

import json
import os
import random
import shutil
import signal
import struct
import subprocess
import sys
import time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from fuzzing import ROOT, Budget, CallResult, CliWorker, FuzzReport, cli_contract, finish, fuzzer_arguments, run_reported

CASE_TIMEOUT = 5.0          # seconds one call may take: a case takes about 10 ms
WARMUP_TIMEOUT = 300.0      # a fresh worker's first call imports everything and loads (or compiles) the kernels
SERVE_START_TIMEOUT = 60.0  # seconds until `caveclod serve` listens or exits
STREAM_TIMEOUT = 10.0       # seconds a session may take to answer
STOP_TIMEOUT = 10.0         # seconds `caveclod serve` may take to exit after SIGTERM
SETTLE_SECONDS = 0.2        # after the last stream, before SIGTERM (serve_case says why)
INSPECT_TARGET = "caveclod.cli:main"
REFINE_TARGET = "fuzzcvc:refine_a_little"
BASE_SIZE = 32              # cells a side of the base terrain: 2,048 triangles
MAX_MUTATIONS = 2

MAGIC = b"CAVECLOD"
PREFIX = len(MAGIC) + 8     # magic, version, header length
ALIGN = 64

# Arrays the kernels index with (flipped three times as often as the others).
INDEX_ARRAYS = ("pos_vstart", "vertex_sgid", "vertex_surface", "position_class", "face_material", "face_sgid",
                "face_creator", "face_rotation", "node_parent", "node_links", "node_position", "base_faces",
                "base_face_nodes", "base_face_nbrs")
FLOATS = (float("nan"), float("inf"), float("-inf"), 3.4e38, -3.4e38, 1e-45, 0.0, -1.0, 1e30)


# ------------------------------------------------------------------ the base mesh and its layout


def make_base(directory: str | os.PathLike, size: int = BASE_SIZE) -> Path:
    """Build the default terrain of ``size`` cells a side into ``directory/base.cvc`` (once)."""
    path = Path(directory) / "base.cvc"
    if not path.exists():
        import caveclod
        path.parent.mkdir(parents=True, exist_ok=True)
        caveclod.build("default", size=size).save(path)
    return path


@dataclass(frozen=True)
class Layout:
    """Where things are in a ``.cvc`` file: its header (parsed), where the arrays start,
    and each array's (file offset, nbytes, dtype, shape)."""

    header: dict
    data_start: int
    arrays: dict
    attachments: dict       # name -> (file offset, nbytes) of the stored packed downloads

    @classmethod
    def of(cls, data: bytes) -> Layout:
        (hlen,) = struct.unpack("<I", data[len(MAGIC) + 4:PREFIX])
        header = json.loads(data[PREFIX:PREFIX + hlen])
        start = _aligned(PREFIX + hlen)
        arrays = {name: (start + t["offset"], t["nbytes"], np.dtype(t["dtype"]), tuple(t["shape"]))
                  for name, t in header["arrays"].items()}
        attachments = {name: (start + t["offset"], t["nbytes"]) for name, t in header.get("attachments", {}).items()}
        return cls(header, start, arrays, attachments)

    def moved(self, data_start: int) -> Layout:
        """The same arrays behind a header of another length."""
        shift = data_start - self.data_start
        return replace(self, data_start=data_start,
                       arrays={k: (a + shift, b, c, d) for k, (a, b, c, d) in self.arrays.items()},
                       attachments={k: (a + shift, b) for k, (a, b) in self.attachments.items()})


def _aligned(n: int) -> int:
    return (n + ALIGN - 1) // ALIGN * ALIGN


def with_header(data: bytes, layout: Layout, blob: bytes) -> tuple[bytes, Layout]:
    """``data`` with its header JSON replaced by ``blob``; the arrays move with the header's end."""
    head = MAGIC + struct.pack("<II", 2, len(blob)) + blob
    start = _aligned(len(head))
    return head + b"\0" * (start - len(head)) + data[layout.data_start:], layout.moved(start)


# ------------------------------------------------------------------ mutations
# Each takes (data, layout, rng) and returns (data, layout, description).


def _pick_array(layout: Layout, rng: random.Random, names=None) -> str:
    names = [n for n in (names or layout.arrays) if layout.arrays[n][1] > 0]
    weights = [3 if n in INDEX_ARRAYS else 1 for n in names]
    return rng.choices(names, weights)[0]


def flip_array_bit(data, layout, rng):
    """One bit flipped inside an array (the fuzzer's finds: segfaults and hangs in the kernels)."""
    name = _pick_array(layout, rng)
    start, nbytes, _, _ = layout.arrays[name]
    at, bit = rng.randrange(nbytes), rng.randrange(8)
    out = bytearray(data)
    out[start + at] ^= 1 << bit
    return bytes(out), layout, f"bit {bit} at byte {at} of {name}"


def poke_array(data, layout, rng):
    """One element of an array set to a value near a limit or another array's count."""
    name = _pick_array(layout, rng)
    start, nbytes, dtype, _ = layout.arrays[name]
    count = nbytes // dtype.itemsize
    i = rng.randrange(count)
    if dtype.kind == "f":
        value = rng.choice(FLOATS)
    else:
        old = int(np.frombuffer(data, dtype, 1, start + i * dtype.itemsize)[0])
        counts = [v[3][0] for v in layout.arrays.values()]
        info = np.iinfo(dtype)
        value = rng.choice([-1, -2, 0, 1, old + 1, old - 1, info.max, info.min, *counts, *(c - 1 for c in counts)])
        value = int(np.clip(value, info.min, info.max))
    out = bytearray(data)
    out[start + i * dtype.itemsize:start + (i + 1) * dtype.itemsize] = np.array([value], dtype).tobytes()
    return bytes(out), layout, f"{name}[{i}] (flat) = {value!r}"


def swap_rows(data, layout, rng):
    """Two rows of an index array swapped: every value stays in range, the structure breaks."""
    name = _pick_array(layout, rng, INDEX_ARRAYS)
    start, nbytes, _, shape = layout.arrays[name]
    row = nbytes // shape[0]
    i, j = rng.randrange(shape[0]), rng.randrange(shape[0])
    out = bytearray(data)
    a, b = bytes(out[start + i * row:start + (i + 1) * row]), bytes(out[start + j * row:start + (j + 1) * row])
    out[start + i * row:start + (i + 1) * row], out[start + j * row:start + (j + 1) * row] = b, a
    return bytes(out), layout, f"{name} rows {i} and {j} swapped"


def flip_attachment_bit(data, layout, rng):
    """One bit flipped in a stored packed download (a server must refuse it and pack afresh)."""
    names = [n for n, (_, nbytes) in layout.attachments.items() if nbytes]
    if not names:
        return flip_array_bit(data, layout, rng)
    name = rng.choice(names)
    start, nbytes = layout.attachments[name]
    at, bit = rng.randrange(nbytes), rng.randrange(8)
    out = bytearray(data)
    out[start + at] ^= 1 << bit
    return bytes(out), layout, f"bit {bit} at byte {at} of attachment {name}"


def flip_header_bit(data, layout, rng):
    """One bit flipped in the header JSON (``nbytes`` -> ``njytes``, a digit, a quote)."""
    hlen = struct.unpack("<I", data[len(MAGIC) + 4:PREFIX])[0]
    at, bit = PREFIX + rng.randrange(max(hlen, 1)), rng.randrange(8)
    out = bytearray(data)
    if at < len(out):
        out[at] ^= 1 << bit
    return bytes(out), layout, f"header bit {bit} at byte {at}"


def damage_prefix(data, layout, rng):
    """The magic, the version or the header length changed."""
    out = bytearray(data)
    what = rng.choice(("magic", "version", "hlen"))
    if what == "magic":
        out[rng.randrange(len(MAGIC))] ^= 1 << rng.randrange(8)
        return bytes(out), layout, "magic"
    if what == "version":
        value = rng.choice((0, 1, 3, 2 ** 32 - 1))
        out[len(MAGIC):len(MAGIC) + 4] = struct.pack("<I", value)
        return bytes(out), layout, f"version {value}"
    hlen = struct.unpack("<I", data[len(MAGIC) + 4:PREFIX])[0]
    value = rng.choice((0, 1, hlen - 1, hlen + 1, hlen + 64, 2 ** 31, 2 ** 32 - 1))
    out[len(MAGIC) + 4:PREFIX] = struct.pack("<I", value % 2 ** 32)
    return bytes(out), layout, f"header length {value}"


def poke_bytes(data, layout, rng):
    """A run of 1 to 8 bytes anywhere set to one value."""
    out = bytearray(data)
    at, run, value = rng.randrange(max(len(out), 1)), rng.randint(1, 8), rng.choice((0, 0xFF, 0x7F, 0x80, rng.randrange(256)))
    out[at:at + run] = bytes([value]) * len(out[at:at + run])
    return bytes(out), layout, f"{run} bytes at {at} = {value:#x}"


def truncate(data, layout, rng):
    """The file cut short: in the prefix, the header, an array, or by a few bytes."""
    cut = rng.choice((rng.randrange(PREFIX), rng.randrange(layout.data_start), rng.randrange(max(len(data), 1)),
                      len(data) - rng.randint(1, 200)))
    return data[:max(cut, 0)], layout, f"truncated to {max(cut, 0)} bytes"


def append_junk(data, layout, rng):
    """Bytes after the last array (harmless: nothing points there)."""
    return data + bytes(rng.randrange(256) for _ in range(rng.randint(1, 100))), layout, "junk appended"


def edit_header(data, layout, rng):
    """One edit of the parsed header, written back (the arrays move with its end)."""
    header = json.loads(json.dumps(layout.header))
    what = _header_edit(header, layout, rng)
    blob = json.dumps(header).encode()
    data, layout = with_header(data, layout, blob)
    return data, layout, what


def _header_edit(header: dict, layout: Layout, rng: random.Random) -> str:
    """Change ``header`` in place; returns what was done."""
    kind = rng.choice(("shape", "shape", "offset", "nbytes", "dtype", "field type", "field missing",
                       "array missing", "materials", "materials", "info", "hash", "top", "attachment",
                       "attachment"))
    name = rng.choice(list(layout.arrays))
    entry = header["arrays"][name]
    weird = rng.choice((None, "12", 1.5, True, [], {}, -1, 2 ** 62, 2 ** 31))
    if kind == "shape":
        shape = entry["shape"]
        k = rng.randrange(len(shape))
        shape[k] = rng.choice((0, 1, shape[k] + 1, shape[k] - 1, 2 * shape[k], 2 ** 31, 2 ** 62, -1))
        if rng.random() < 0.5:     # keep nbytes consistent: only the file's size can refuse it
            entry["nbytes"] = int(np.prod(shape)) * np.dtype(entry["dtype"]).itemsize
        return f"{name} shape {shape}, nbytes {entry['nbytes']}"
    if kind == "offset":
        other = rng.choice(list(header["arrays"].values()))["offset"]
        entry["offset"] = rng.choice((entry["offset"] + 64, entry["offset"] - 64, entry["offset"] + 1, other,
                                      2 ** 40, -64))
        return f"{name} offset {entry['offset']}"
    if kind == "nbytes":
        entry["nbytes"] = rng.choice((0, entry["nbytes"] + 1, entry["nbytes"] - 1, 2 * entry["nbytes"], 2 ** 40))
        return f"{name} nbytes {entry['nbytes']}"
    if kind == "dtype":
        entry["dtype"] = rng.choice(("<f8", ">i4", "<i8", "u1", "x", "<u2", "<f4", "object"))
        return f"{name} dtype {entry['dtype']}"
    if kind == "field type":
        field = rng.choice(("shape", "offset", "nbytes", "dtype"))
        entry[field] = weird
        return f"{name} {field} = {weird!r}"
    if kind == "field missing":
        field = rng.choice(("shape", "offset", "nbytes", "dtype"))
        entry[field.replace("b", "j", 1) if field == "nbytes" else field + "_"] = entry.pop(field)
        return f"{name} {field} renamed"
    if kind == "array missing":
        header["arrays"].pop(name)
        return f"{name} missing"
    if kind == "materials":
        n = len(header["materials"])
        choice = rng.choice(("100k", "65537", "long", "empty", "fewer", "not str", "not list", "65536"))
        header["materials"] = {
            "100k": [f"m{i}" for i in range(100_000)], "65537": [f"m{i}" for i in range(65537)],
            "65536": [f"m{i}" for i in range(65536)], "long": ["x" * 5000] * max(n, 1), "empty": [],
            "fewer": header["materials"][:max(n - 1, 0)], "not str": [1] * n, "not list": "water",
        }[choice]
        return f"materials {choice}"
    if kind == "info":
        deep: object = 0
        for _ in range(rng.choice((40, 500, 900))):
            deep = [deep]
        header["info"] = rng.choice(({"deep": deep}, [], "info", None, {"notes": ["x" * 100] * 1000}))
        return "info edited"
    if kind == "attachment" and header.get("attachments"):
        table = header["attachments"]
        name = rng.choice(sorted(table))
        entry = table[name]
        what = rng.choice(("offset", "nbytes", "meta", "meta", "table"))
        if what == "offset":
            entry["offset"] = rng.choice((entry["offset"] + 64, 0, header["arrays"]["node_links"]["offset"], 2 ** 40,
                                          entry["offset"] + 1, weird))
        elif what == "nbytes":
            entry["nbytes"] = rng.choice((0, entry["nbytes"] - 1, entry["nbytes"] + 64, 2 ** 40, weird))
        elif what == "meta":
            key = rng.choice(sorted(entry["meta"]))
            entry["meta"][key] = rng.choice((weird, 0, -1.0, float("nan"), "0" * 32, 2 ** 33))
            return f"attachment {name} meta {key} = {entry['meta'][key]!r}"
        else:
            header["attachments"] = weird
            return f"attachments = {weird!r}"
        return f"attachment {name} {what} = {entry[what]!r}"
    if kind == "hash":
        key = rng.choice(("content_hash", "vertex_buffer_hash"))
        header[key] = rng.choice(("", "0" * 32, "zz", 5, None))
        return f"{key} = {header[key]!r}"
    key = rng.choice(("arrays", "format", "version"))
    header[key] = weird
    return f"header {key} = {weird!r}"


def raw_header(data, layout, rng):
    """The header replaced by something that is not the header (deep JSON: RecursionError)."""
    blob = rng.choice((b"[" * 100_000 + b"]" * 100_000, b"{" * 50_000, b"[]", b"null", b"\xff\xfe{}", b"",
                       b'{"arrays": {}}', b"1e999"))
    data, layout = with_header(data, layout, blob)
    return data, layout, f"header = {blob[:12]!r}... ({len(blob)} bytes)"


# (mutator, weight); at most one header rewrite per case, done first.
HEADER_MUTATORS = ((edit_header, 20), (raw_header, 3))
BYTE_MUTATORS = ((flip_array_bit, 40), (poke_array, 15), (swap_rows, 6), (flip_header_bit, 8), (damage_prefix, 2),
                 (poke_bytes, 4), (truncate, 5), (append_junk, 1), (flip_attachment_bit, 4))


def mutate(base: bytes, layout: Layout, rng: random.Random) -> tuple[bytes, list[str]]:
    """A damaged copy of ``base`` and the mutations made (one or two; one case in 30 is unmutated)."""
    if rng.random() < 1 / 30:
        return base, ["none"]
    data, done = base, []
    mutators = [m for m, _ in HEADER_MUTATORS + BYTE_MUTATORS]
    weights = [w for _, w in HEADER_MUTATORS + BYTE_MUTATORS]
    chosen = rng.choices(mutators, weights, k=rng.randint(1, MAX_MUTATIONS))
    chosen.sort(key=lambda m: (m not in dict(HEADER_MUTATORS), m is truncate))   # header first, truncation last
    rewritten = False
    for mutator in chosen:
        if mutator in dict(HEADER_MUTATORS):
            if rewritten:
                continue
            rewritten = True
        data, layout, what = mutator(data, layout, rng)
        done.append(what)
    return data, done


# ------------------------------------------------------------------ the worker's side


def refine_a_little(path: str) -> int:
    """Load the ``.cvc`` at ``path`` and fly two cameras over it: one with a resident vertex
    buffer, one in cache mode, near the surface, then far, then near again, with a keyframe.
    Returns 0, or 2 after one ``caveclod: error:`` line (a CaveclodError), as the CLI does."""
    import caveclod
    from caveclod.errors import CaveclodError
    from caveclod.paths import flyover
    from caveclod.refine.activevertices import ActiveVertices
    from caveclod.refine.cachedcamera import CachedCamera
    from caveclod.staticmesh import load
    try:
        mesh = load(path)
        lo, hi = mesh.bounds()
        plain = mesh.new_camera()
        base = ActiveVertices(mesh.n_vertices, plain.triangles()).count
        cached = CachedCamera(mesh.new_camera(), max(2 * base, 8))
        for t, tolerance in ((0.0, 0.5), (15.0, 0.5), (15.0, 50.0), (40.0, 0.2)):
            for camera, cam in enumerate((plain, cached)):
                cam.update(caveclod.View.from_pose(flyover(lo, hi, camera, t), width=640, height=360,
                                                   tolerance_px=tolerance))
        plain.keyframe()
        cached.keyframe()
    except CaveclodError as exc:
        print(f"caveclod: error: {exc}", file=sys.stderr)
        return 2
    return 0


# ------------------------------------------------------------------ judging


def judge(result: CallResult) -> tuple[str | None, str]:
    """(finding kind or None, detail) of one worker call, by the contract of the module doc."""
    stderr = result.stderr.strip()
    if result.exit is None:
        return "hang", f"no answer within {CASE_TIMEOUT:g} s"
    if result.died:
        return "crash", f"the worker died with status {result.exit}"
    kind = cli_contract(result.exit, result.stderr)
    if kind:
        return kind, stderr or f"exit {result.exit} with nothing on stderr"
    if result.exit == 2:
        lines = stderr.splitlines()
        if len(lines) != 1 or not lines[0].startswith("caveclod: error:"):
            return "wrong", "exit 2 without exactly one 'caveclod: error:' line: " + stderr
    elif stderr:
        return "wrong", "exit 0 with output on stderr: " + stderr
    return None, ""


def run_file(worker: CliWorker, path: Path, report: FuzzReport, case: str, targets: dict) -> int:
    """The calls of one file in ``worker``; adds findings and outcomes; returns inspect's exit status
    (None when it hung or crashed)."""
    calls = [("inspect", targets["inspect"], [["inspect", str(path)]])]
    first = None
    while calls:
        label, target, args = calls.pop(0)
        result = worker.call(target, args, timeout=CASE_TIMEOUT)
        report.count("calls")
        kind, detail = judge(result)
        report.outcome(f"{label} " + ("hang" if result.exit is None else f"exit {result.exit}"))
        if kind:
            report.add(kind, f"{case}: {label}", detail)
        if label == "inspect":
            first = result.exit
            if result.exit == 0:     # a file load refuses is refused the same way by the calls below
                calls += [("inspect --verify", targets["inspect"], [["inspect", "--verify", str(path)]]),
                          ("refine", targets["refine"], [str(path)])]
    return first


# ------------------------------------------------------------------ caveclod serve


def serve_case(base_path: Path, case_path: Path, log_path: Path, report: FuzzReport, case: str) -> None:
    """``caveclod serve BASE CASE``: refused at start with exit 2 and one line, or it answers an
    Open of the damaged mesh (SessionInfo and frames, or a clear status), still serves the good
    one, and exits 0 on SIGTERM. Started and stopped by its pid; every wait is bounded."""
    from service import readline_within, stop_process
    report.count("serves")
    cmd = [sys.executable, "-m", "caveclod.cli", "serve", "--host", "127.0.0.1", "--port", "0",
           "--drain-seconds", "0", str(base_path), str(case_path)]
    with open(log_path, "w") as log:
        proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=log, text=True, cwd=ROOT)
    try:
        line = readline_within(proc.stdout, SERVE_START_TIMEOUT)
        if not line.startswith("listening on "):
            _judge_refusal(proc, log_path, report, case)
            return
        port = int(line.rsplit(":", 1)[1])
        lo, hi = _bounds(base_path)
        ok = _session_kept_contract(port, case_path.stem, lo, hi, report, case, damaged=True)
        if ok:
            _session_kept_contract(port, base_path.stem, lo, hi, report, case, damaged=False)
        if proc.poll() is not None:
            report.add("crash", f"{case}: serve", f"exited with {proc.returncode} while serving; "
                                                  f"log: {log_path.read_text()[-400:]}")
            return
        # Let the server finish the RPCs we cancelled first: a SIGTERM at that very moment can leave a
        # grpc.aio task pending when the server closes its event loop, which then logs "Task was
        # destroyed but it is pending!" with a GeneratorExit traceback (once in 250 serves; a race in
        # the server's stop, not in reading meshes, which this fuzzer is about).
        time.sleep(SETTLE_SECONDS)
        os.kill(proc.pid, signal.SIGTERM)
        try:
            code = proc.wait(STOP_TIMEOUT)
        except subprocess.TimeoutExpired:
            report.add("hang", f"{case}: serve", f"did not exit within {STOP_TIMEOUT:g} s of SIGTERM")
            return
        report.outcome(f"serve stopped {code}")
        if code != 0:
            report.add("crash" if code < 0 else "wrong", f"{case}: serve", f"exited {code} on SIGTERM")
        _judge_log(log_path, report, case)
    finally:
        stop_process(proc)
        proc.stdout.close()


def _judge_refusal(proc, log_path: Path, report: FuzzReport, case: str) -> None:
    """serve did not listen: it must have exited 2 with one line."""
    try:
        code = proc.wait(STOP_TIMEOUT)
    except subprocess.TimeoutExpired:
        report.add("hang", f"{case}: serve", "neither listened nor exited")
        return
    log = log_path.read_text()
    report.outcome(f"serve refused {code}")
    kind = cli_contract(code, log)
    lines = log.strip().splitlines()
    if kind is None and code == 2 and (len(lines) != 1 or not lines[0].startswith("caveclod: error:")):
        kind = "wrong"
    if kind is None and code != 2:
        kind = "wrong"
    if kind:
        report.add(kind, f"{case}: serve at start", f"exit {code}: {log[-600:]}")


def _judge_log(log_path: Path, report: FuzzReport, case: str) -> None:
    log = log_path.read_text()
    if "Traceback (most recent call last)" in log:
        report.add("traceback", f"{case}: serve's log", log[-600:])


def _session_kept_contract(port: int, mesh: str, lo, hi, report: FuzzReport, case: str, damaged: bool) -> bool:
    """Open ``mesh`` with two cameras and poses; a good mesh must send SessionInfo and frames, a
    damaged one may end with a clear status instead. Returns whether the server answered at all."""
    import grpc
    from service import open_message, pose_message

    from caveclod.paths import flyover
    poses = [pose_message(c, c + 1, *flyover(lo, hi, c, 10.0 * c)[:2]) for c in range(2)]
    code, details, kinds = _session(port, [open_message(mesh, cameras=2, tolerance_px=0.5), *poses])
    label = "damaged" if damaged else "good"
    report.outcome(f"serve {label} {code.name if code else 'served'}")
    answered = kinds.count("frame") >= 1 and "session_info" in kinds
    if code is None and answered:
        return True
    if code is not None and damaged and code not in (grpc.StatusCode.UNKNOWN, grpc.StatusCode.INTERNAL,
                                                     grpc.StatusCode.DEADLINE_EXCEEDED):
        return True
    kind = "hang" if code == grpc.StatusCode.DEADLINE_EXCEEDED else "status" if code is not None else "wrong"
    report.add(kind, f"{case}: serve, the {label} mesh {mesh!r}", f"{code}: {details}; got {kinds}")
    return False


def _session(port: int, messages: list, frames: int = 2) -> tuple:
    """Send ``messages`` on a Session stream and read until ``frames`` frames came (then cancel:
    code None) or the stream ended (its code) or STREAM_TIMEOUT passed (DEADLINE_EXCEEDED).
    Returns (code or None, details, kinds of the messages received)."""
    import threading

    import grpc

    from caveclod.v1 import caveclod_pb2 as pb
    channel = grpc.insecure_channel(f"127.0.0.1:{port}")
    done = threading.Event()

    def requests():
        yield from (m.SerializeToString() for m in messages)
        done.wait(STREAM_TIMEOUT)            # keep our side open: a half-close would be a Close

    call = channel.stream_stream("/caveclod.v1.Lod/Session", request_serializer=lambda b: b,
                                 response_deserializer=pb.ServerMessage.FromString)(requests(), timeout=STREAM_TIMEOUT)
    kinds = []
    try:
        for r in call:
            kinds.append(r.WhichOneof("kind"))
            if kinds.count("frame") >= frames:
                call.cancel()
                return None, "", kinds
        return grpc.StatusCode.OK, "", kinds
    except grpc.RpcError as exc:
        if exc.code() == grpc.StatusCode.CANCELLED and kinds.count("frame") >= frames:
            return None, "", kinds
        return exc.code(), exc.details(), kinds
    finally:
        done.set()
        channel.close()


def _bounds(path: Path):
    from caveclod.staticmesh import load
    return load(path, check=False).bounds()


# ------------------------------------------------------------------ the loop


def fuzz_cvc(base_path: str | os.PathLike, budget: Budget, seed: int, report: FuzzReport,
             workdir: str | os.PathLike, serve_every: int = 50, targets: dict | None = None) -> FuzzReport:
    """Feed damaged copies of ``base_path`` to the worker until ``budget`` runs out.

    Args:
        base_path: a good ``.cvc`` (:func:`make_base`).
        budget: cases and/or seconds.
        seed: makes the mutations (a case is reproduced by the seed and its number).
        report: ``cases``; units ``files``, ``calls``, ``serves``; outcomes
            ``"{call} exit {code}"`` and ``"serve ..."``; findings (their files
            are kept under ``workdir/findings``).
        workdir: scratch directory (created).
        serve_every: every this many cases (from the first) a case also goes
            through ``caveclod serve`` (0: never): alternately that case, and
            the next one that ``inspect`` accepts.
        targets: the worker functions, ``{"inspect": "module:function" taking
            argv, "refine": one taking a path}``; tests point them at broken ones.
    """
    targets = {"inspect": INSPECT_TARGET, "refine": REFINE_TARGET, **(targets or {})}
    workdir, base_path = Path(workdir), Path(base_path)
    casedir, keep = workdir / "case", workdir / "findings"
    casedir.mkdir(parents=True, exist_ok=True)
    base = base_path.read_bytes()
    layout = Layout.of(base)
    rng = random.Random(seed)
    with CliWorker() as worker:
        number = dues = 0
        due = False
        while budget.more():
            data, mutations = mutate(base, layout, rng)
            case = f"seed {seed} case {number}: {' + '.join(mutations)}"
            path = casedir / "case.cvc"
            path.write_bytes(data)
            _warm_up(worker, targets, base_path)
            findings = len(report.findings)
            accepted = run_file(worker, path, report, case, targets) == 0
            if serve_every and number % serve_every == 0:
                due, dues = True, dues + 1
            # Every other serve takes the case whatever it is (serve refuses most at start); the
            # others wait for a file that load accepts, whose damage only refinement can meet.
            if due and (accepted or dues % 2 == 1):
                due = False
                serve_case(base_path, path, workdir / "serve.log", report, case)
            report.cases += 1
            report.count("files")
            if len(report.findings) > findings:
                kept = keep / f"case-{number}.cvc"
                kept.parent.mkdir(parents=True, exist_ok=True)
                shutil.copyfile(path, kept)
                for f in report.findings[findings:]:
                    f.case += f" (kept as {kept})"
            number += 1
    report.seconds = budget.elapsed()
    return report


def _warm_up(worker: CliWorker, targets: dict, base_path: Path) -> None:
    """Start a fresh worker with one call on the good mesh (imports and loading the kernels
    take far longer than a case may); a no-op while the worker runs."""
    if worker.proc is not None and worker.proc.poll() is None:
        return
    worker.call(targets["refine"], [str(base_path)], timeout=WARMUP_TIMEOUT)


def main(argv: list[str] | None = None) -> int:
    """Run the fuzzer from the command line; prints the report as JSON."""
    p = fuzzer_arguments("fuzz caveclod's .cvc reader, kernels and server with damaged files")
    p.add_argument("--serve-every", type=int, default=50)
    p.add_argument("--workdir", default="/tmp/caveclod-fuzzcvc")
    args = p.parse_args(argv)
    report = FuzzReport("cvc")
    base = make_base(args.workdir)
    run_reported(report, fuzz_cvc, base, Budget(cases=args.cases, seconds=args.seconds), args.seed, report,
                 args.workdir, serve_every=args.serve_every)
    return finish(report, "files", args.out)


if __name__ == "__main__":
    sys.exit(main())
