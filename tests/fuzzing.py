"""What every fuzzer in this repository reports, and the contract it holds each case to.

The fuzzers (``fuzzprotocol``, ``fuzzcvc``, ``fuzzsources``) run briefly in
``make test`` with fixed seeds and for long from ``benchmarks/fuzz.py``.
A case passes when the system under test answers with a clear status (a gRPC
status other than UNKNOWN/INTERNAL) or a one-line ``caveclod: error: ...``
with exit status 2. It fails (a :class:`Finding`) on a traceback, a crash (a
negative exit: a signal), a hang (no answer within the case's time limit), a
leaked session, or a wrong answer.

Cases that could crash or hang the interpreter run in a :class:`CliWorker`: a
child process that runs ``caveclod.cli.main`` (or any function named by module
and attribute) in-process, one case at a time, and is restarted when a case
kills or stalls it, so one process start serves thousands of cases.
"""

from __future__ import annotations

import io
import json
import os
import selectors
import signal
import subprocess
import sys
import time
import traceback
from contextlib import redirect_stderr, redirect_stdout
from dataclasses import dataclass, field

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
KINDS = ("status", "traceback", "crash", "hang", "leak", "wrong")


@dataclass
class Finding:
    """One case that broke the contract."""

    kind: str       # one of KINDS
    case: str       # what was fed: seed and mutation, enough to reproduce it
    detail: str     # what came back (shortened)

    def __post_init__(self):
        if self.kind not in KINDS:
            raise ValueError(f"finding kind {self.kind!r} is not one of {KINDS}")
        self.detail = self.detail if len(self.detail) <= 600 else self.detail[:300] + " ... " + self.detail[-280:]


@dataclass
class FuzzReport:
    """Counts of one fuzzer's run: ``cases`` fed, ``units`` (messages, files, ...),
    ``outcomes`` (how the cases were answered: status names, exit codes) and findings."""

    name: str
    cases: int = 0
    units: dict = field(default_factory=dict)
    outcomes: dict = field(default_factory=dict)
    findings: list = field(default_factory=list)
    seconds: float = 0.0
    fuzzer_error: str = ""     # the fuzzer's own bug that ended its run early (a traceback's last lines)

    def count(self, unit: str, n: int = 1) -> None:
        self.units[unit] = self.units.get(unit, 0) + n

    def outcome(self, label: str) -> None:
        self.outcomes[label] = self.outcomes.get(label, 0) + 1

    def add(self, kind: str, case: str, detail: str) -> None:
        self.findings.append(Finding(kind, case, detail))

    def finding_counts(self) -> dict:
        counts = {k: 0 for k in KINDS}
        for f in self.findings:
            counts[f.kind] += 1
        return counts

    def as_json(self) -> dict:
        return {"name": self.name, "cases": self.cases, "units": self.units, "outcomes": self.outcomes,
                "seconds": round(self.seconds, 2), "findings": self.finding_counts(), "fuzzer_error": self.fuzzer_error,
                "examples": [vars(f) for f in self.findings[:20]]}

    def assert_clean(self) -> None:
        """Raise AssertionError naming the first findings, if there are any."""
        if self.findings:
            lines = [f"{self.name}: {len(self.findings)} of {self.cases} cases broke the contract "
                     f"{self.finding_counts()}:"]
            lines += [f"  [{f.kind}] {f.case}: {f.detail}" for f in self.findings[:10]]
            raise AssertionError("\n".join(lines))


class Budget:
    """Bounded in both count and time: ``more()`` is False once ``cases`` cases
    were taken or ``seconds`` have passed (either may be None, not both)."""

    def __init__(self, cases: int | None = None, seconds: float | None = None):
        if cases is None and seconds is None:
            raise ValueError("a budget needs a case count, a time, or both")
        self.cases, self.seconds = cases, seconds
        self.start, self.taken = time.monotonic(), 0

    def more(self) -> bool:
        if self.cases is not None and self.taken >= self.cases:
            return False
        if self.seconds is not None and time.monotonic() - self.start >= self.seconds:
            return False
        self.taken += 1
        return True

    def elapsed(self) -> float:
        return time.monotonic() - self.start


# -- one-line errors ---------------------------------------------------------------

def damage(data: bytes, rng, how: int) -> bytes:
    """``data`` damaged one of four ways (``how`` % 4): a bit flipped, cut short at a random
    place, a random byte inserted, a byte deleted. ``rng``: a numpy Generator."""
    out = bytearray(data)
    at = int(rng.integers(len(out))) if out else 0
    how %= 4
    if how == 0 and out:
        out[at] ^= 1 << int(rng.integers(8))
    elif how == 1:
        out = out[:at]
    elif how == 2:
        out.insert(at, int(rng.integers(256)))
    elif out:
        del out[at]
    return bytes(out)


def cli_contract(exit_code: int, stderr: str) -> str | None:
    """None when ``exit_code``/``stderr`` keep the CLI's contract (0, or 2 with one
    ``caveclod: error:`` line and no traceback); else the kind of finding."""
    if "Traceback (most recent call last)" in stderr:
        return "traceback"
    if exit_code < 0:
        return "crash"
    if exit_code == 0:
        return None
    if exit_code == 2:
        lines = [ln for ln in stderr.splitlines() if ln.strip() and not ln.startswith("usage:")]
        errors = [ln for ln in lines if ln.startswith("caveclod: error:") or ln.startswith("caveclod: ")]
        return None if errors else "wrong"
    return "wrong"


# -- a worker process for cases that may crash or hang -------------------------------

@dataclass
class CallResult:
    """What one call in a :class:`CliWorker` did: its exit status (the return value
    of the function, or SystemExit's code; negative: killed by that signal; None:
    it hung and was killed), its captured stdout and stderr, and ``value`` (what
    a non-CLI function returned, if JSON can carry it)."""

    exit: int | None
    stdout: str = ""
    stderr: str = ""
    value: object = None
    seconds: float = 0.0
    died: bool = False          # the worker process ended during the call (exit: its status)


class CliWorker:
    """A child Python process that runs calls one at a time, restarted after a
    crash or a hang. ``call("caveclod.cli:main", [argv])`` runs the CLI in-process.

    Use as a context manager; the child is stopped by its pid on exit.
    """

    def __init__(self, env: dict | None = None):
        self.env = {**os.environ, "PYTHONPATH": os.pathsep.join([ROOT, os.path.join(ROOT, "tests")]),
                    **(env or {})}
        self.proc: subprocess.Popen | None = None
        self.starts = 0

    def __enter__(self) -> "CliWorker":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def _start(self) -> None:
        self.proc = subprocess.Popen([sys.executable, "-c", "import fuzzing; fuzzing._worker_loop()"],
                                     stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL,
                                     cwd=ROOT, env=self.env, start_new_session=True)
        self.starts += 1

    def call(self, target: str, args: list, timeout: float = 30.0) -> CallResult:
        """Run ``module:function(*args)`` in the child; JSON carries ``args`` there."""
        if self.proc is None or self.proc.poll() is not None:
            self._start()
        t0 = time.monotonic()
        try:
            self.proc.stdin.write((json.dumps({"target": target, "args": args}) + "\n").encode())
            self.proc.stdin.flush()
        except BrokenPipeError:
            return self._died(t0)
        line = self._readline(timeout)
        if line is None:                                # no answer in time: a hang
            self.close()
            return CallResult(exit=None, seconds=time.monotonic() - t0)
        if not line:
            return self._died(t0)
        out = json.loads(line)
        return CallResult(exit=out["exit"], stdout=out["stdout"], stderr=out["stderr"], value=out.get("value"),
                          seconds=time.monotonic() - t0)

    def _died(self, t0: float) -> CallResult:
        code = self.proc.wait(10)
        self.close()
        return CallResult(exit=code, seconds=time.monotonic() - t0, died=True)

    def _readline(self, timeout: float) -> bytes | None:
        # A selector, as tests/service.py's readline_within: select.select() refuses descriptors above
        # 1023, which a test process running many files reaches (four fuzzer tests failed so when two
        # test processes shared the files).
        fd, buf, deadline = self.proc.stdout.fileno(), b"", time.monotonic() + timeout
        with selectors.DefaultSelector() as sel:
            sel.register(fd, selectors.EVENT_READ)
            while not buf.endswith(b"\n"):
                left = deadline - time.monotonic()
                if left <= 0:
                    return None
                if sel.select(left):
                    chunk = os.read(fd, 1 << 20)
                    if not chunk:
                        return b""
                    buf += chunk
        return buf

    def close(self) -> None:
        if self.proc is not None:
            try:
                os.killpg(self.proc.pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
            self.proc.wait(10)
            for f in (self.proc.stdin, self.proc.stdout):
                try:
                    f.close()
                except OSError:
                    pass
            self.proc = None


def _worker_loop() -> None:
    """The child's side of :class:`CliWorker`: one JSON call per line in, one out."""
    import importlib
    out = sys.stdout
    for line in sys.stdin:
        req = json.loads(line)
        module, _, name = req["target"].partition(":")
        fn = getattr(importlib.import_module(module), name)
        so, se, value = io.StringIO(), io.StringIO(), None
        with redirect_stdout(so), redirect_stderr(se):
            try:
                ret = fn(*req["args"])
                code = ret if isinstance(ret, int) else 0
                value = ret if isinstance(ret, (dict, list, str, float)) else None
            except SystemExit as exc:
                code = exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 1)
            except BaseException:            # noqa: BLE001 - the finding is the traceback
                traceback.print_exc(file=se)
                code = 1
        out.write(json.dumps({"exit": code, "stdout": so.getvalue()[-4000:], "stderr": se.getvalue()[-4000:],
                              "value": value}) + "\n")
        out.flush()


# -- the fuzzers' command lines ------------------------------------------------------

def fuzzer_arguments(description: str):
    """An argparse parser with what every fuzzer's command line takes:
    ``--seconds``, ``--cases``, ``--seed`` and ``--out`` (a JSON file)."""
    import argparse
    parser = argparse.ArgumentParser(description=description)
    parser.add_argument("--seconds", type=float, default=60.0, help="how long to fuzz (default 60)")
    parser.add_argument("--cases", type=int, help="stop after this many cases (default: no limit)")
    parser.add_argument("--seed", type=int, default=1, help="seed of the cases (a case is reproduced by "
                                                             "its seed and number)")
    parser.add_argument("--out", help="also write the report as JSON to this file")
    return parser


def run_reported(into: FuzzReport, fuzz, *args, **kwargs) -> None:
    """``fuzz(*args, **kwargs)``, which adds to the report ``into``; a bug of the fuzzer's
    own (an exception) ends the run but not its report: the counts so far, and the
    error in ``into.fuzzer_error``."""
    t0 = time.monotonic()
    try:
        fuzz(*args, **kwargs)
    except Exception:
        into.fuzzer_error = " | ".join(traceback.format_exc().strip().splitlines()[-6:])
        into.seconds = into.seconds or time.monotonic() - t0
        traceback.print_exc()


def finish(report: FuzzReport, unit: str, out: str | None) -> int:
    """Print ``report`` as JSON (with ``{unit}_per_second``), write it to ``out`` too,
    and return the exit status: 3 when the fuzzer itself failed, 1 with findings, else 0."""
    doc = report.as_json()
    doc[f"{unit}_per_second"] = round(report.units.get(unit, 0) / max(report.seconds, 1e-9), 2)
    text = json.dumps(doc, indent=1)
    print(text)
    if out:
        with open(out, "w") as f:
            f.write(text + "\n")
    return 3 if report.fuzzer_error else 1 if report.findings else 0
