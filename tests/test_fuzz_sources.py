"""The source fuzzer (tests/fuzzsources.py): a short clean run, and proof that it
reports a build that breaks the contract.

The long run is ``.venv/bin/python benchmarks/fuzz.py --minutes 10`` (with the other two).
"""

from __future__ import annotations

import numpy as np
import pytest

from fuzzing import Budget, CallResult, FuzzReport
from fuzzsources import build_case, fuzz_sources, judge, make_seeds

SEED = 20240517
CASES = 100       # about 2 s: tiny seeds build in about 10 ms each


def test_a_short_run_keeps_the_contract(tmp_path):
    report = fuzz_sources(Budget(cases=CASES, seconds=120), SEED, FuzzReport("sources"), tmp_path)
    report.assert_clean()
    assert report.cases == CASES and report.units["files"] == CASES
    kinds = {label.split()[0] for label in report.outcomes}
    assert len(kinds) >= 12, f"every kind of seed is built: {sorted(kinds)}"
    assert any(label.endswith("exit 0") for label in report.outcomes), report.outcomes
    assert any(label.endswith("exit 2") for label in report.outcomes), report.outcomes


def test_every_seed_builds(tmp_path, capsys):
    """The unmutated seeds are valid inputs: each builds, inspects and stores finite floats."""
    for seed in make_seeds(np.random.default_rng(SEED)):
        case = tmp_path / seed.kind
        case.mkdir()
        for name, content in {**seed.companions, seed.name: seed.data}.items():
            (case / name).write_bytes(content)
        value = build_case(str(case / seed.name), str(case / "out.cvc"), [])
        err = capsys.readouterr().err
        assert judge(CallResult(exit=0, stderr=err, value=value)) == (None, "", "exit 0"), (seed.kind, err)


def raise_plain_exception(input_path: str, output_path: str, options: list) -> dict:
    """A worker target whose build leaks a traceback (a ValueError no one caught)."""
    raise ValueError(f"cannot parse {input_path}")


def build_without_range_checks(input_path: str, output_path: str, options: list) -> dict:
    """A worker target with the refusal of far and non-finite coordinates switched off."""
    from caveclod.builder import meshfile, source, terrain
    meshfile._refuse_nonfinite_positions = meshfile._refuse_far_positions = lambda soup, label: None
    terrain._refuse_far_heights = lambda h, z_scale: None
    source.out_of_range_rows = lambda values, limit=None: np.zeros(len(values), bool)
    source.SourceMesh.validate = lambda self: None
    return build_case(input_path, output_path, options)


def test_a_traceback_is_a_finding(tmp_path):
    report = fuzz_sources(Budget(cases=5), SEED, FuzzReport("sources"), tmp_path,
                          target="test_fuzz_sources:raise_plain_exception")
    assert report.finding_counts()["traceback"] == 5
    with pytest.raises(AssertionError, match="ValueError: cannot parse"):
        report.assert_clean()


def test_far_coordinates_let_through_are_findings(tmp_path):
    """With the range checks off, mutated files overflow float32: the build
    warns on stderr or stores infinities, and the fuzzer reports it."""
    report = fuzz_sources(Budget(cases=120), SEED, FuzzReport("sources"), tmp_path,
                          target="test_fuzz_sources:build_without_range_checks",
                          kinds=("npy-f32", "npy-f64", "stl-binary"))
    assert report.findings, report.outcomes
    assert {f.kind for f in report.findings} <= {"wrong", "traceback"}
    assert any("Warning" in f.detail or "infinite" in f.detail for f in report.findings)


def test_the_mutators_themselves_never_raise(tmp_path):
    """Mutations stack (a second one meets what the first left), so each mutator must take any
    bytes: a mutator that raises ends a long run with no report (benchmarks/fuzz.py's first
    10-minute run lost its source and .cvc reports so). The two found, then 5,000 cases."""
    import random

    from fuzzsources import make_case, png_header, replace_index
    seeds = {s.kind: s for s in make_seeds(np.random.default_rng(SEED))}
    rng = random.Random(5)
    replace_index(b"v 0 0 0\nf a/b c\n", rng)              # a face line with no number left
    png = seeds["png16"].data
    huge = bytearray(png)
    huge[16:24] = (2 ** 32 - 1).to_bytes(4, "big") * 2     # IHDR width and height at their maximum
    for _ in range(50):
        png_header(bytes(huge), rng)                       # grown by one, or tripled: clamped
    all_seeds = list(seeds.values())
    for n in range(5_000):
        make_case(all_seeds[n % len(all_seeds)], rng, tmp_path)


def test_the_command_line_writes_its_report(tmp_path):
    import json

    from fuzzsources import main
    out = tmp_path / "sources.json"
    assert main(["--cases", "12", "--seconds", "60", "--workdir", str(tmp_path / "w"), "--out", str(out)]) == 0
    report = json.loads(out.read_text())
    assert report["cases"] == 12 and report["units"]["files"] == 12 and report["fuzzer_error"] == ""
