"""The three fuzzers for long: protocol, .cvc files and sources, side by side.

    python benchmarks/fuzz.py [--minutes 10] [--seed 1] [--only protocol,cvc,sources]
    python benchmarks/fuzz.py --minutes 1                  # a short run, to try it

Runs, at the same time and each for ``--minutes``, in its own process:

* **protocol** (tests/fuzzprotocol.py): mutated, random and wrong-order
  ClientMessages on Session streams against one ``caveclod serve``
  (127.0.0.1, port 0) serving three small meshes built here: the smooth
  default terrain, the rough terrain with no-data holes and the range scan
  with its open borders (``--size`` cells a side);
* **cvc** (tests/fuzzcvc.py): damaged copies of a built mesh through
  ``load``, ``inspect --verify``, a few refinements, and now and then
  ``caveclod serve`` with a session;
* **sources** (tests/fuzzsources.py): mutated OBJ, PLY, glTF/GLB, STL, OFF,
  npy, PNG and TIFF inputs (and option sets) through ``caveclod build``.

Each case is held to the contract of tests/fuzzing.py: a clear gRPC status
(not UNKNOWN or INTERNAL) or a one-line ``caveclod: error:`` with exit 2;
never a traceback, a crash, a hang or a leaked session. Pass: no finding, and
at least the issue's counts scaled to the run's length (for 10 minutes:
200,000 protocol messages, 5,000 .cvc files, 2,000 source files).

Writes ``benchmarks/results/fuzz.json`` (each fuzzer's report: cases, units,
outcomes, findings with the first examples) and ``fuzz.png``. A finding's
input is kept under ``--workdir`` (``findings/``); a case is reproduced by
its seed and number (see each fuzzer's ``--help``). Every process started is
stopped by its pid, whatever happens.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
RESULTS = ROOT / "benchmarks" / "results"
TESTS = ROOT / "tests"

# The counts for a 10-minute run; a run of other length is held to them pro rata.
TARGETS = {"protocol": ("messages", 200_000), "cvc": ("files", 5_000), "sources": ("files", 2_000)}
MESHES = ("default", "rough", "scan")
GRACE_S = 240.0         # beyond --minutes: start-up (kernels compile), the leak check, writing the report


def build_meshes(directory: Path, size: int) -> list[Path]:
    """The protocol fuzzer's meshes: each built-in at ``size`` cells a side, in ``directory``."""
    import caveclod
    paths = []
    for name in MESHES:
        path = directory / f"{name}.cvc"
        caveclod.build(name, size=size).save(path)
        paths.append(path)
    return paths


def commands(which: list[str], seconds: float, seed: int, workdir: Path, meshes: list[Path]) -> dict:
    """Each fuzzer's command line, writing its report to ``workdir/NAME.json``."""
    common = ["--seconds", str(seconds), "--seed", str(seed)]
    out = {}
    for name in which:
        report = ["--out", str(workdir / f"{name}.json")]
        if name == "protocol":
            out[name] = [sys.executable, str(TESTS / "fuzzprotocol.py"), *common, *report, *map(str, meshes)]
        elif name == "cvc":
            out[name] = [sys.executable, str(TESTS / "fuzzcvc.py"), *common, *report,
                         "--workdir", str(workdir / "cvc")]
        else:
            out[name] = [sys.executable, str(TESTS / "fuzzsources.py"), *common, *report,
                         "--workdir", str(workdir / "sources")]
    return out


def run_all(cmds: dict, seconds: float, workdir: Path) -> dict:
    """Start every command at once (each in its own process group, its output in
    ``workdir/NAME.log``), wait for them all (bounded), stop any left by its pid;
    returns ``{name: (exit status, report or None)}``."""
    procs, logs = {}, {}
    try:
        for name, cmd in cmds.items():
            logs[name] = open(workdir / f"{name}.log", "w")
            procs[name] = subprocess.Popen(cmd, stdout=logs[name], stderr=subprocess.STDOUT, cwd=ROOT,
                                           start_new_session=True)
        deadline = time.monotonic() + seconds + GRACE_S
        for proc in procs.values():
            try:
                proc.wait(timeout=max(1.0, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                pass
    finally:
        for proc in procs.values():
            if proc.poll() is None:
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait(timeout=30)
        for f in logs.values():
            f.close()
    results = {}
    for name, proc in procs.items():
        path = workdir / f"{name}.json"
        report = json.loads(path.read_text()) if path.exists() else None
        results[name] = (proc.returncode, report)
    return results


def summarize(results: dict, minutes: float, workdir: Path) -> dict:
    """The run's verdict: each fuzzer's report with its target and pass/fail."""
    out = {"minutes": minutes, "fuzzers": {}, "pass": True}
    for name, (code, report) in results.items():
        unit, per_ten = TARGETS[name]
        target = int(per_ten * minutes / 10.0)
        if report is None:
            log = (workdir / f"{name}.log").read_text()[-2000:]
            entry = {"exit": code, "report": None, "target": {unit: target}, "pass": False,
                     "why": f"no report (exit {code}); the end of its log: {log}"}
        else:
            done = report["units"].get(unit, 0)
            findings = sum(report["findings"].values())
            why = [] if findings == 0 else [f"{findings} findings"]
            if done < target:
                why.append(f"{done:,} {unit} of {target:,} wanted")
            if report.get("fuzzer_error"):
                why.append(f"the fuzzer failed: {report['fuzzer_error']}")
            entry = {"exit": code, "report": report, "target": {unit: target}, "pass": not why and code == 0,
                     "why": "; ".join(why)}
        out["fuzzers"][name] = entry
        out["pass"] = out["pass"] and entry["pass"]
    return out


def plot(out: dict, path: Path) -> None:
    """Per fuzzer: units done against the target, and how the cases were answered."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import matplotlib.ticker
    names = list(out["fuzzers"])
    fig, axes = plt.subplots(1, 1 + len(names), figsize=(4.2 * (1 + len(names)), 4.2))
    ax = axes[0]
    done, labels = [], []
    for name in names:
        entry = out["fuzzers"][name]
        unit, target = next(iter(entry["target"].items()))
        units = (entry["report"] or {}).get("units", {})
        done.append(units.get(unit, 0) / max(target, 1))
        findings = sum((entry["report"] or {}).get("findings", {}).values()) if entry["report"] else "?"
        labels.append(f"{name}\n{units.get(unit, 0):,} {unit}\n{findings} findings")
    ax.tick_params(axis="x", labelsize=8)
    ax.bar(labels, done, color=["tab:green" if out["fuzzers"][n]["pass"] else "tab:red" for n in names])
    ax.axhline(1.0, color="k", lw=1, ls="--", label="target")
    ax.set_ylabel("done / target")
    ax.set_title(f"{out['minutes']:g} min, all at once")
    ax.legend()
    for ax, name in zip(axes[1:], names):
        outcomes = (out["fuzzers"][name]["report"] or {}).get("outcomes", {})
        if name == "sources":              # "{input kind} exit N": summed over the kinds
            summed: dict = {}
            for label, n in outcomes.items():
                ending = label.split(" ", 1)[-1]
                summed[ending] = summed.get(ending, 0) + n
            outcomes = summed
        top = sorted(outcomes.items(), key=lambda kv: -kv[1])[:12]
        ax.barh([k for k, _ in top][::-1], [v for _, v in top][::-1], color="tab:blue")
        ax.set_xscale("log")
        ax.xaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())
        ax.set_title(f"{name}: how cases ended")
        ax.tick_params(axis="y", labelsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--minutes", type=float, default=10.0, help="how long each fuzzer runs (default 10)")
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--only", default="protocol,cvc,sources", help="comma-separated fuzzers to run")
    p.add_argument("--size", type=int, default=48, help="cells a side of the protocol fuzzer's meshes")
    p.add_argument("--workdir", help="scratch directory, kept (default: a temporary one, removed after a pass)")
    p.add_argument("--out", type=Path, default=RESULTS, help="where fuzz.json and fuzz.png go")
    args = p.parse_args(argv)
    which = [w for w in args.only.split(",") if w]
    unknown = set(which) - set(TARGETS)
    if unknown or not which or not args.minutes > 0:
        p.error(f"--only takes some of {','.join(TARGETS)} and --minutes must be > 0")
    workdir = Path(args.workdir or tempfile.mkdtemp(prefix="caveclod-fuzz-"))
    workdir.mkdir(parents=True, exist_ok=True)
    meshes = build_meshes(workdir, args.size) if "protocol" in which else []
    seconds = args.minutes * 60.0
    print(f"fuzzing {', '.join(which)} for {args.minutes:g} min each, at once (seed {args.seed}) ...", flush=True)
    results = run_all(commands(which, seconds, args.seed, workdir, meshes), seconds, workdir)
    out = summarize(results, args.minutes, workdir)
    if out["pass"] and not args.workdir:
        shutil.rmtree(workdir, ignore_errors=True)
    else:                                  # the findings' inputs and the fuzzers' logs, to reproduce them
        print(f"kept {workdir} (findings/ under each fuzzer's directory, NAME.log)")
    out["seed"], out["cores"] = args.seed, os.cpu_count()
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "fuzz.json").write_text(json.dumps(out, indent=1) + "\n")
    plot(out, args.out / "fuzz.png")
    for name, entry in out["fuzzers"].items():
        report = entry["report"] or {}
        units = ", ".join(f"{v:,} {k}" for k, v in report.get("units", {}).items())
        print(f"{name:9s} {'PASS' if entry['pass'] else 'FAIL'}  {report.get('cases', 0):,} cases: {units}; "
              f"findings {report.get('findings')} {entry['why']}")
    print(f"{'PASS' if out['pass'] else 'FAIL'}; wrote {args.out / 'fuzz.json'} and fuzz.png")
    return 0 if out["pass"] else 1


if __name__ == "__main__":
    sys.exit(main())
