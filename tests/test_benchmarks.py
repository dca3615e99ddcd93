"""The benchmark plumbing: JSON with machine, date, commit, tables and targets, and
RESULTS.md rendered from it (no benchmark is timed here)."""

import json
import sys
from pathlib import Path

import pytest

BENCH = Path(__file__).resolve().parent.parent / "benchmarks"
sys.path.insert(0, str(BENCH))

import _common  # noqa: E402
import render_results  # noqa: E402


def test_targets_say_whether_they_are_met():
    assert _common.target("tick", 90.0, 100.0, "us")["met"]
    assert not _common.target("tick", 110.0, 100.0, "us")["met"]
    reach = _common.target("rate", 9_000.0, 1e4, "env-steps/s", at_most=False)
    assert not reach["met"] and reach["target"] == ">= 10000 env-steps/s"


def test_results_render_from_the_json_benchmarks_write(tmp_path, capsys):
    table = _common.print_table(
        "Ticks",
        [{"case": "a", "us": 1.25}, {"case": "b", "us": None}],
        [("case", "case", "s"), ("us", "us", ".1f")],
    )
    assert table == {
        "title": "Ticks",
        "headers": ["case", "us"],
        "rows": [["a", "1.2"], ["b", "-"]],
    }
    out = tmp_path / "results"
    _common.write_json(
        out / "bench_demo.json",
        "bench_demo",
        {"quick": True, "rows": [{"case": "a", "us": 1.25}]},
        tables=[table],
        targets=[_common.target("tick", 120.0, 100.0, "us")],
    )
    payload = json.loads((out / "bench_demo.json").read_text())
    for key in ("machine", "date", "commit", "tables", "targets"):
        assert key in payload
    # An older JSON without recorded tables is rendered from its rows.
    (out / "bench_old.json").write_text(json.dumps({"benchmark": "old", "rows": [{"x": 1}]}))
    text = render_results.render(out)
    assert "## bench_demo" in text and "## old" in text
    assert "| tick | 120 | <= 100 us | **no** |" in text
    assert "| a | 1.2 |" in text and "| 1 |" in text
    assert "date not recorded" in text


def test_render_without_results_says_so(tmp_path):
    with pytest.raises(SystemExit, match="no bench_"):
        render_results.render(tmp_path)


def test_interleaved_calls_each_callable_once_per_round():
    calls = []

    def make(name):
        return lambda: calls.append(name)

    out = _common.interleaved({"a": (make("a"), 64), "b": (make("b"), 50)}, rounds=4)
    assert calls == ["a", "a", "b", "b"] * 4
    assert set(out) == {"a", "b", "a/b"}
    assert all(v > 0 for v in out.values())
