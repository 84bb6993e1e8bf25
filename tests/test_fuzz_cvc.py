"""The .cvc fuzzer (tests/fuzzcvc.py): a short clean run, with `caveclod serve` cases, and proof
that it reports what a reader without the structural check does with damaged files.

The long run is ``.venv/bin/python benchmarks/fuzz.py --minutes 10`` (with the other two).
"""

from __future__ import annotations

import pytest
from fuzzcvc import fuzz_cvc, make_base
from fuzzing import Budget, FuzzReport

SEED = 20240611
CASES = 150           # about 2 s of files, plus 3 serve cases of about 3 s each


@pytest.fixture(scope="module")
def base(tmp_path_factory):
    return make_base(tmp_path_factory.mktemp("fuzzcvc"))


def test_a_short_run_keeps_the_contract(base, tmp_path):
    report = fuzz_cvc(base, Budget(cases=CASES, seconds=120), SEED, FuzzReport("cvc"), tmp_path, serve_every=50)
    report.assert_clean()
    assert report.units["files"] == CASES and report.units["serves"] == 3, report.as_json()
    for outcome in ("inspect exit 0", "inspect exit 2", "refine exit 0"):
        assert report.outcomes.get(outcome, 0) > 0, report.as_json()
    assert any(k.startswith("serve ") for k in report.outcomes), report.as_json()


def skip_the_check() -> None:
    """Load every file as the reader did before issue 17: no structural check."""
    import caveclod.meshcheck
    caveclod.meshcheck.check_mesh = lambda mesh: None


def inspect_unchecked(argv: list) -> int:
    """A worker target: ``caveclod inspect`` without the structural check."""
    from caveclod.cli import main
    skip_the_check()
    return main(argv)


def refine_unchecked(path: str) -> int:
    """A worker target: :func:`fuzzcvc.refine_a_little` without the structural check."""
    from fuzzcvc import refine_a_little
    skip_the_check()
    return refine_a_little(path)


def test_without_the_structural_check_the_fuzzer_reports_findings(base, tmp_path):
    """Damaged index arrays then reach the kernels and numpy: crashes, hangs and tracebacks."""
    report = fuzz_cvc(base, Budget(cases=120, seconds=120), SEED, FuzzReport("unchecked"), tmp_path, serve_every=0,
                      targets={"inspect": "test_fuzz_cvc:inspect_unchecked", "refine": "test_fuzz_cvc:refine_unchecked"})
    counts = report.finding_counts()
    assert counts["crash"] + counts["hang"] + counts["traceback"] > 0, report.as_json()
    with pytest.raises(AssertionError, match="broke the contract"):
        report.assert_clean()


def test_the_mutators_themselves_never_raise(base):
    """Two truncations in one case (the first to nothing) raised in the fuzzer itself and ended a
    long run with no report; then 5,000 cases of stacked mutations."""
    import random

    from fuzzcvc import Layout, mutate, poke_bytes, truncate
    data = base.read_bytes()
    layout, rng = Layout.of(data), random.Random(11)
    for _ in range(20):
        truncate(b"", layout, rng)
        poke_bytes(b"", layout, rng)
    for _ in range(5_000):
        mutate(data, layout, rng)


def test_the_command_line_writes_its_report(tmp_path):
    import json

    from fuzzcvc import main
    out = tmp_path / "cvc.json"
    assert main(["--cases", "20", "--seconds", "60", "--serve-every", "0", "--workdir", str(tmp_path / "w"),
                 "--out", str(out)]) == 0
    report = json.loads(out.read_text())
    assert report["cases"] == 20 and report["units"]["files"] == 20 and report["fuzzer_error"] == ""


def test_a_fuzzer_s_own_bug_keeps_its_report(tmp_path, monkeypatch):
    """A mutator that raises ends the run with exit 3; the counts so far and the error are reported."""
    import json

    import fuzzcvc
    calls = []

    def mutate_then_fail(base, layout, rng):
        calls.append(1)
        if len(calls) > 5:
            raise ValueError("a mutator's bug")
        return base, ["none"]

    monkeypatch.setattr(fuzzcvc, "mutate", mutate_then_fail)
    out = tmp_path / "cvc.json"
    assert fuzzcvc.main(["--cases", "50", "--serve-every", "0", "--workdir", str(tmp_path / "w"),
                         "--out", str(out)]) == 3
    report = json.loads(out.read_text())
    assert report["cases"] == 5 and "a mutator's bug" in report["fuzzer_error"]
