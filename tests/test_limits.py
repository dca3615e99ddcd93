"""The limit search: bisection of the largest recovered impulse, its checks, and a real
CI-sized search on MuJoCo C through the CLI (resumed, reported)."""

import json
import subprocess
import sys

import numpy as np
import pytest
from cli_helpers import CI_SEARCH, run_cli

from jaxloco.sweep.bisection import search_limits
from jaxloco.sweep.limit_search import LimitSearch, round_table

SMALL = dict(
    directions_deg=(0.0, 90.0, 180.0),
    phases=(0.3, 0.7),
    durations=(0.1, 0.2),
    replan=(True, False),
    impulse_range=(0.0, 128.0),
    rounds=5,
    replicas=5,
    min_recovered=4,
)


@pytest.mark.parametrize(
    "field, value, message",
    [
        ("directions_deg", (), "a non-empty list"),
        ("phases", (0.0, 0.5), r"values in \(0, 1\)"),
        ("phases", (0.5, 1.0), r"values in \(0, 1\)"),
        ("durations", (0.0,), "values > 0"),
        ("impulse_range", (40.0, 40.0), "0 <= low < high"),
        ("impulse_range", (-10.0, 40.0), "0 <= low < high"),
        ("impulse_range", (10.0,), "0 <= low < high"),
        ("rounds", 0, ">= 1"),
        ("min_recovered", 6, r"\[1, replicas = 5\]"),
        ("qvel_noise", -0.1, ">= 0"),
        ("first_seed", -1, ">= 0"),
    ],
)
def test_a_bad_search_names_the_field_and_the_valid_range(field, value, message):
    with pytest.raises(ValueError, match=rf"LimitSearch\.{field} must be .*{message}"):
        LimitSearch(**{field: value})


def test_a_round_tests_each_cell_with_its_replicas():
    search = LimitSearch(**SMALL)
    impulses = np.arange(len(search.cells()), dtype=float) + 10.0
    table = round_table(search, impulses)
    assert len(table) == len(search.cells()) * 5
    impulse = table["magnitude"] * table["duration"]
    np.testing.assert_allclose(impulse, np.repeat(impulses, 5))
    assert table["seed"].tolist()[:6] == [1, 2, 3, 4, 5, 1]  # one noise draw per replica
    # A repeat on independent draws: the same pushes, other seeds.
    again = round_table(LimitSearch(**SMALL, first_seed=6), impulses)
    assert again["seed"].tolist()[:6] == [6, 7, 8, 9, 10, 6]
    np.testing.assert_array_equal(again["magnitude"], table["magnitude"])


def _robot(search, true_limits, flaky=None, calls=None):
    """A stand-in for the sweep: a push is recovered when its impulse is at most its cell's
    limit; ``flaky`` cells recover only their replicas 1-3 (so 3 of 5)."""
    cell_of = {c: k for k, c in enumerate(search.cells())}

    def run_round(table, round_dir, walks_dir):
        round_dir.mkdir(parents=True, exist_ok=True)
        if calls is not None:
            calls.append((round_dir.name, len(table)))
        cols = (table["direction_deg"], table["phase"], table["duration"], table["replan"])
        keys = zip(*cols, strict=True)
        cells = np.array([cell_of[(float(d), float(p), float(t), bool(r))] for d, p, t, r in keys])
        ok = table["magnitude"] * table["duration"] <= np.asarray(true_limits)[cells]
        if flaky is not None:
            ok &= ~np.asarray(flaky)[cells] | (table["seed"] <= 3)
        return ok

    return run_round


def test_bisection_brackets_every_cells_limit_at_the_final_resolution(tmp_path):
    search = LimitSearch(**SMALL)
    n = len(search.cells())
    rng = np.random.default_rng(0)
    true = rng.uniform(8.0, 120.0, n)
    true[0], true[1] = 500.0, 1.0  # past the range; under the first impulse tried
    flaky = np.zeros(n, bool)
    flaky[2], true[2] = True, 500.0  # always 3 of 5: never recovered
    calls = []
    res = search_limits(search, tmp_path, _robot(search, true, flaky, calls), progress=False)
    lo, hi = res.brackets.lo, res.brackets.hi
    assert np.allclose(hi - lo, search.resolution()) and search.resolution() == 4.0
    ok = ~flaky
    assert np.all((lo[ok] <= true[ok]) & (true[ok] < hi[ok]) | res.censored_above[ok])
    # 3 of 5 is below min_recovered: the flaky cell never counts as recovered.
    assert res.limit[2] == 0.0 and res.censored_below[2]
    assert res.censored_above[0] and res.limit[0] == 124.0
    assert res.censored_below[1] and res.limit[1] == 0.0
    assert not (res.censored_above[3:] | res.censored_below[3:]).any()
    # Every smaller impulse tested in a cell was recovered (the bisection only tests above lo).
    for k in range(n):
        below = res.tested[:, k] <= res.limit[k]
        assert np.all(res.recovered[below, k] >= 4)
    # Each round runs 4 replicas of every cell, then the 5th only of the cells left open
    # (3 of 4 recovered): the flaky cell in every round, no cell whose replicas agree.
    assert [name for name, _ in calls[:2]] == ["round_00", "round_00_last"]
    assert [size for name, size in calls if name.endswith("_last")] == [1] * 5
    assert res.runs[:, 2].tolist() == [5] * 5 and (res.runs[:, 3:] == 4).all()
    s = res.summary()
    assert s["pushes_run"] == 5 * (4 * n + 1) and len(s["cells"]) == n
    assert set(s["variants"]) == {"replan, 0.1 s", "replan, 0.2 s", "no_replan, 0.1 s",
                                  "no_replan, 0.2 s"}  # fmt: skip
    json.dumps(s)  # every number JSON-ready
    # Both references counted per variant, and the cells whose limit may lie past the range.
    assert s["paper_impulse_Ns"] == 52.0 and s["learned_impulse_Ns"] == 108.0
    variants = s["variants"].values()
    assert sum(v["cells_at_least_learned"] for v in variants) == int(np.sum(res.limit >= 108.0))
    assert sum(v["cells_at_least_paper"] for v in variants) == int(np.sum(res.limit >= 52.0))
    assert sum(v["cells_censored_above"] for v in variants) == int(res.censored_above.sum()) == 1
    # On a lighter robot both references are the same velocity changes as on the paper's.
    light = res.summary(mass=35.0)
    assert light["paper_impulse_Ns"] == round(52.0 * 35.0 / 135.9, 2)
    assert light["learned_impulse_Ns"] == round(108.0 * 35.0 / 135.9, 2)


def test_a_run_directory_holds_one_search(tmp_path):
    search = LimitSearch(**SMALL)
    n = len(search.cells())
    robot = _robot(search, np.full(n, 50.0))
    search_limits(search, tmp_path, robot, progress=False)
    search_limits(search, tmp_path, robot, progress=False)  # the same search: resumes
    with pytest.raises(ValueError, match="another limit search.*rounds"):
        search_limits(LimitSearch(**dict(SMALL, rounds=3)), tmp_path, robot)
    (tmp_path / "other" / "round_00").mkdir(parents=True)
    with pytest.raises(ValueError, match="unknown search"):
        search_limits(search, tmp_path / "other", robot)
    # A search written before a field existed holds that field's default.
    written = json.loads((tmp_path / "search.json").read_text())
    del written["first_seed"]
    (tmp_path / "search.json").write_text(json.dumps(written))
    search_limits(search, tmp_path, robot, progress=False)
    with pytest.raises(ValueError, match="another limit search.*first_seed"):
        search_limits(LimitSearch(**SMALL, first_seed=6), tmp_path, robot)


def test_the_main_job_finds_a_limit_on_mujoco_c_and_resumes(tmp_path, installed_jaxloco):
    """`jaxloco push-sweep` with a CI-sized search, from the installed wheel away from the
    checkout: 2 rounds of up to 2 replicas, 1 needed (20 N s is recovered, as in the CI
    sweep, by the first replica, so the second is not run and the second round tests
    30 N s); the report has every number and both plots; the same command again runs
    nothing and reports the same."""
    proc = run_cli(["push-sweep", *CI_SEARCH], tmp_path, timeout=900, installed=installed_jaxloco)
    assert proc.returncode == 0, proc.stderr[-3000:]
    run = tmp_path / "run"
    summary = json.loads((run / "summary.json").read_text())
    cell = summary["cells"][0]
    assert cell["tested_Ns"] == [20.0, 30.0]
    assert cell["recovered_replicas"][0] == 1 and cell["replicas_run"][0] == 1
    assert not (run / "round_00_last").exists()
    assert cell["limit_Ns"] in (20.0, 30.0) and cell["bracket_Ns"][1] - cell["bracket_Ns"][0] == 10
    for name in ("limits_polar.png", "limits_heatmap.png", "summary.md"):
        assert (run / name).stat().st_size > 0
    report = (run / "summary.md").read_text()
    assert "| cells >= 52 N s | cells >= 108 N s | cells past the range |" in report
    # The report states the torque bound the search ran at: Valkyrie's default, the paper's.
    assert summary["torque_limit"] == 500.0
    assert "bounded at +-500 N m at every joint (the paper's authors' setting)" in report
    manifest = json.loads((run / "round_00" / "manifest.json").read_text())
    assert len(manifest["runs"]) == 1 and manifest["limit_search"]["rounds"] == 2
    assert sorted(p.name for p in (run / "walks").iterdir()) == ["1.0_0.0_1.npz"]
    again = run_cli(["push-sweep", *CI_SEARCH], tmp_path, timeout=900, installed=installed_jaxloco)
    assert again.returncode == 0, again.stderr[-3000:]
    manifest = json.loads((run / "round_01" / "manifest.json").read_text())
    assert len(manifest["runs"]) == 1  # nothing ran twice
    assert json.loads((run / "summary.json").read_text())["cells"] == summary["cells"]


def test_limit_searches_compare_per_direction(tmp_path):
    """Two searches of the same cells (e.g. two torque bounds) side by side: per direction
    the worst phase's limit and the median, from their summaries, through the CLI too."""
    from jaxloco.sweep.limits_report import compare_limit_summaries

    search = LimitSearch(**SMALL)
    n = len(search.cells())
    strong = np.full(n, 120.0)
    weak = np.linspace(10.0, 90.0, n)
    summaries = {}
    for label, true in (("bound", strong), ("model", weak)):
        res = search_limits(search, tmp_path / label, _robot(search, true), progress=False)
        summaries[label] = res.summary()
        (tmp_path / label / "summary.json").write_text(json.dumps(summaries[label]))
    cmp = compare_limit_summaries(summaries)
    assert cmp["labels"] == ["bound", "model"]
    row = cmp["variants"]["replan, 0.1 s"]["per_direction"]["90"]
    cells = [k for k, c in enumerate(search.cells()) if c[0] == 90.0 and c[2] == 0.1 and c[3]]
    model_limits = [summaries["model"]["cells"][k]["limit_Ns"] for k in cells]
    assert row["model"]["worst_phase_Ns"] == min(model_limits)
    assert row["model"]["median_Ns"] == float(np.median(model_limits))
    assert row["bound"]["worst_phase_Ns"] > row["model"]["worst_phase_Ns"]
    # The learned policy's 108 N s: every cell of the strong search reaches it, no other.
    variant = cmp["variants"]["replan, 0.1 s"]
    assert variant["cells_at_least_learned"] == {"bound": variant["cells"], "model": 0}
    assert cmp["learned_impulse_Ns"] == 108.0
    older = json.loads(json.dumps(summaries["model"]))  # written before the count existed
    for v in older["variants"].values():
        del v["cells_at_least_learned"]
    mixed = compare_limit_summaries({"bound": summaries["bound"], "older": older})
    assert mixed["variants"]["replan, 0.1 s"]["cells_at_least_learned"]["older"] is None
    other = json.loads(json.dumps(summaries["model"]))
    other["search"]["phases"] = [0.5]
    with pytest.raises(ValueError, match="search.phases"):
        compare_limit_summaries({"bound": summaries["bound"], "other": other})

    def compare_cli(*args):
        command = [sys.executable, "-m", "jaxloco.cli", "limits-compare", *args]
        return subprocess.run(command, capture_output=True, text=True, timeout=300)

    runs = f"runs=[{tmp_path / 'bound'},{tmp_path / 'model'}]"
    proc = compare_cli(runs, 'labels=["500 N m",model]', f"hydra.run.dir={tmp_path / 'cmp'}")
    assert proc.returncode == 0, proc.stderr[-3000:]
    table = (tmp_path / "cmp" / "comparison.md").read_text()
    assert "| direction | 500 N m | model |" in table and "| 90 deg |" in table
    assert "| cells >= 108 N s (learned policy) | 6/6 | 0/6 |" in table
    assert (tmp_path / "cmp" / "comparison_polar.png").stat().st_size > 0
    bad = compare_cli(f"runs=[{tmp_path / 'bound'}]", f"hydra.run.dir={tmp_path / 'x'}")
    assert bad.returncode != 0 and "runs: needs at least two" in bad.stderr, bad.stderr[-2000:]
