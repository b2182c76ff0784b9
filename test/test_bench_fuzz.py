"""Smoke test of ``hand-suite bench fuzz``: it runs, prints its tables and finds no failure."""

from __future__ import annotations

from hand_capture.bench import json_line
from hand_control.bench import fuzz
from hand_control.cli import available_benches


def test_bench_fuzz_smoke(capsys) -> None:
    assert available_benches()["fuzz"] == "hand_control.bench.fuzz"
    figures = fuzz.run(quick=True, scale=0.05)
    out = capsys.readouterr().out
    assert "Input validation of every node" in out and "Core paths" in out
    for key in ("cases", "failures", "msgs_per_s"):
        assert key in figures
    assert figures["failures"] == 0
    assert figures["cases"] >= 2 * 100 * len(fuzz.TYPES)
    assert figures["msgs_per_s"] > 0
    assert json_line(figures).startswith("{")
