"""Push sweeps: the spec, the store (resume, chunking), the report, and small real sweeps."""

import dataclasses
import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxloco.learning.checkpoint import SHIPPED_POLICIES, assets_dir
from jaxloco.sweep import SweepSpec, SweepStore, expand, summarize
from jaxloco.sweep.outcome import FIELDS
from jaxloco.sweep.store import table_digest

# The sweep machinery is tested on Algorithm 1's policy alone: the default's look-ahead
# makes the compile longer, and the walking tests cover it.
ALG1 = str(assets_dir() / SHIPPED_POLICIES["algorithm1"])


def test_spec_rejects_bad_values_naming_the_field():
    with pytest.raises(ValueError, match="SweepSpec.phases"):
        SweepSpec(phases=(1.5,))
    with pytest.raises(ValueError, match="SweepSpec.magnitudes"):
        SweepSpec(magnitudes=())
    with pytest.raises(ValueError, match="SweepSpec.mode"):
        SweepSpec(mode="sobol")


def test_grid_expands_every_combination_in_a_fixed_order():
    spec = SweepSpec(
        directions_deg=(0.0, 90.0, 180.0),
        magnitudes=(100.0, 200.0),
        phases=(0.5,),
        replan=(True, False),
    )
    table = expand(spec)
    assert len(table) == 12
    assert table["direction_deg"][:4].tolist() == [0.0] * 4
    assert table["replan"][:2].tolist() == [True, False]
    assert np.all(expand(spec)["magnitude"] == table["magnitude"])


def test_random_mode_is_reproducible_and_inside_the_ranges():
    spec = SweepSpec(mode="random", num_random=50, magnitudes=(100.0, 600.0), phases=(0.1, 0.9))
    a, b = expand(spec), expand(spec)
    assert np.array_equal(a["magnitude"], b["magnitude"])
    assert a["magnitude"].min() >= 100 and a["magnitude"].max() <= 600
    assert a["phase"].min() >= 0.1 and a["phase"].max() <= 0.9
    other = expand(SweepSpec(mode="random", num_random=50, magnitudes=(100.0, 600.0), seeds=(1,)))
    assert not np.array_equal(a["magnitude"], other["magnitude"])


def _fake_outcome(n, recovered):
    out = {k: np.zeros(n, int) for k in FIELDS}
    out["recovered"] = np.asarray(recovered, bool)
    out["fell"] = ~out["recovered"]
    for k in ("fall_time", "max_com_error", "max_com_offset", "peak_torque_norm"):
        out[k] = np.zeros(n)
    return out


def _manifest(table, **settings):
    return {
        "table_digest": table_digest(table),
        "num_pushes": len(table),
        "settings": {"backend": "c", "chunk_size": 1, **settings},
        "runs": [],
    }


def test_store_resumes_and_refuses_another_sweep(tmp_path):
    spec = SweepSpec(directions_deg=(0.0, 90.0), magnitudes=(520.0,), phases=(0.5,), replan=(True,))
    table = expand(spec)
    store = SweepStore(tmp_path)
    manifest = _manifest(table)
    store.open(manifest, table)
    store.write_chunk(1, np.array([1]), _fake_outcome(1, [True]))
    assert not store.done(0) and store.done(1)
    assert store.open(dict(manifest), table) == manifest  # same sweep: resumes
    other_table = expand(dataclasses.replace(spec, magnitudes=(400.0,)))
    with pytest.raises(ValueError, match="different sweep.*table_digest"):
        store.open(_manifest(other_table), other_table)
    # Physics, gait and backend decide outcomes too: a run with others is refused, while
    # the same settings resume (tuples compare equal to the lists JSON stored).
    other = tmp_path / "settings"
    settings = _manifest(table, physics={"torque_limit": 500.0}, gait={"step": (0.1, 0.2)})
    SweepStore(other).open(settings, table)
    SweepStore(other).open(dict(settings), table)
    with pytest.raises(ValueError, match="settings"):
        SweepStore(other).open(_manifest(table, physics={"torque_limit": None}), table)
    _, out, have = store.load_results()
    assert have.tolist() == [False, True] and out["recovered"][1]
    assert not list(tmp_path.glob("chunks/*.tmp*"))


def test_the_settings_of_a_job_decide_whether_a_run_directory_is_the_same_sweep(tmp_path):
    import shutil
    from pathlib import Path

    from jaxloco.learning.checkpoint import SHIPPED_POLICIES, assets_dir
    from jaxloco.locomotion import GaitParams
    from jaxloco.sim.mjx_loop import PhysicsParams
    from jaxloco.sweep import SweepJob

    job = SweepJob.of(SweepSpec(), tmp_path)
    # Where it runs and with how many threads does not change outcomes; the rest does.
    same = job.replace(run_dir="elsewhere", nthread=1, cache_dir="/tmp/c", walks_dir="w")
    assert same.settings_digest() == job.settings_digest()
    for changed in (
        job.replace(physics=PhysicsParams(torque_limit=None)),
        job.replace(gait=GaitParams(replan_gamma=0.3)),
        job.replace(backend="mjx"),
        job.replace(chunk_size=3),
        job.replace(qvel_noise=0.01),
        job.replace(x64=True),
        job.replace(planner=str(assets_dir() / SHIPPED_POLICIES["refined"])),
    ):
        assert changed.settings_digest() != job.settings_digest()
    # The policy counts by its contents: the shipped default (a fallback planner naming its
    # two neighbours) copied elsewhere with them is the same.
    copy = tmp_path / "policies"
    shutil.copytree(assets_dir() / "policies", copy)
    default = copy / Path(SHIPPED_POLICIES["default"]).name
    assert job.replace(planner=str(default)).settings_digest() == job.settings_digest()
    with pytest.raises(FileNotFoundError, match="no planner checkpoint"):
        job.replace(planner=str(tmp_path / "none")).settings_digest()
    with pytest.raises(ValueError, match="SweepJob.backend"):
        job.replace(backend="gpu")
    with pytest.raises(ValueError, match="SweepJob.chunk_size"):
        job.replace(chunk_size=0)


def test_a_damaged_chunk_file_is_detected_moved_aside_and_not_used(tmp_path):
    spec = SweepSpec(directions_deg=(0.0, 90.0), magnitudes=(520.0,), phases=(0.5,), replan=(True,))
    table = expand(spec)
    store = SweepStore(tmp_path)
    store.open(_manifest(table), table)
    for i in (0, 1):
        store.write_chunk(i, np.array([i]), _fake_outcome(1, [True]))
    assert store.done(0, np.array([0])) and store.done(1, np.array([1]))
    assert not store.done(1, np.array([0]))  # a file holding other rows is not this chunk
    store.write_chunk(1, np.array([1]), _fake_outcome(1, [True]))
    # Truncated (a write cut short by hand or by a full disk).
    path0 = store.chunk_path(0)
    path0.write_bytes(path0.read_bytes()[:100])
    # Whole as a zip file, but the content no longer matches its digest.
    path1 = store.chunk_path(1)
    with np.load(path1) as f:
        data = {k: f[k] for k in f.files}
    data["recovered"] = ~data["recovered"]
    np.savez(path1, **data)
    _, out, have = store.load_results()
    assert have.tolist() == [False, False]
    assert not store.done(0) and not store.done(1)
    assert sorted(p.name for p in store.chunks_dir.iterdir()) == [
        "00000.corrupt.npz",
        "00001.corrupt.npz",
    ]


def test_a_run_directory_with_chunks_but_no_manifest_is_refused(tmp_path):
    spec = SweepSpec(directions_deg=(0.0,), magnitudes=(520.0,), phases=(0.5,), replan=(True,))
    table = expand(spec)
    (tmp_path / "chunks").mkdir()
    np.savez(tmp_path / "chunks" / "00000.npz", rows=np.array([0]))
    with pytest.raises(ValueError, match="no manifest"):
        SweepStore(tmp_path).open(_manifest(table), table)


def test_largest_recovered_impulse_stops_at_the_first_failure():
    spec = SweepSpec(
        directions_deg=(0.0,), magnitudes=(100.0, 200.0, 300.0), phases=(0.5,), replan=(True,)
    )
    table = expand(spec)
    s = summarize(table, _fake_outcome(3, [True, False, True]), np.ones(3, bool))
    d = s["variants"]["replan"]["directions"]["0"]
    assert d["largest_recovered_impulse_Ns"] == pytest.approx(10.0)
    assert d["recovered"] == 2


DISCRETE = ("recovered", "fell", "steps_after", "replans", "failed_plans")

CI_SPEC = dict(
    directions_deg=(0.0, 90.0),
    magnitudes=(200.0,),
    phases=(0.5,),
    replan=(True,),
    push_step=1,
    horizon=0.8,
    steps_after=1,
)


def test_paired_comparison_is_mcnemars_exact_test():
    from scipy.stats import binomtest

    from jaxloco.sweep import paired_comparison

    rng = np.random.default_rng(3)
    for _ in range(20):
        a, b = rng.random(48) < 0.4, rng.random(48) < 0.5
        got = paired_comparison(a, b)
        only_a, only_b = int(np.sum(a & ~b)), int(np.sum(b & ~a))
        assert (got["only_a"], got["only_b"]) == (only_a, only_b)
        assert got["recovered_a"] == a.sum() and got["recovered_b"] == b.sum()
        want = binomtest(only_a, only_a + only_b, 0.5).pvalue if only_a + only_b else 1.0
        assert got["p_value"] == pytest.approx(want, rel=1e-9)
    # A held-out sweep: 10 pushes only the tuned gamma recovered, 6 only the
    # hand-set one: not beyond chance.
    tuned = np.r_[np.ones(10, bool), np.zeros(6, bool), np.ones(10, bool)]
    hand = np.r_[np.zeros(10, bool), np.ones(6, bool), np.ones(10, bool)]
    assert paired_comparison(tuned, hand)["p_value"] == pytest.approx(0.4545, abs=1e-4)
    with pytest.raises(ValueError, match="paired_comparison"):
        paired_comparison(np.ones(3, bool), np.ones(4, bool))


@pytest.fixture(scope="module")
def chunks_of_one(tmp_path_factory):
    """The CI sweep in this process in chunks of 1, stopped after one chunk and resumed:
    ``(stopped, resumed, walks)``, ``walks`` the walks it simulated. Shared by the tests
    that compare other chunkings and executors with it (one sweep fewer to run)."""
    import jaxloco.sweep.chunks as sweep_chunks
    from jaxloco.sweep import run_sweep

    run_dir = tmp_path_factory.mktemp("chunks_of_one")
    walks = []
    snapshot_walk = sweep_chunks.snapshot_walk
    spec = SweepSpec(**CI_SPEC)
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(
            sweep_chunks,
            "snapshot_walk",
            lambda *a, **k: walks.append(a[3:6]) or snapshot_walk(*a, **k),
        )
        kw = dict(backend="c", chunk_size=1, progress=False, planner=ALG1)
        stopped = run_sweep(spec, run_dir, max_chunks=1, **kw)
        stopped_walks = len(list((run_dir / "walks").glob("*.npz")))
        resumed = run_sweep(spec, run_dir, **kw)
    return stopped, stopped_walks, resumed, walks


@pytest.mark.slow  # ~75 s beyond the shared sweep; CI keeps the main job's resume and Dask's
def test_ci_sweep_on_mujoco_c_resumes_and_does_not_depend_on_chunking(tmp_path, chunks_of_one):
    """A real sweep (C backend): two pushes in one chunk of 2, and in chunks of 1 (stopped
    after one chunk, then resumed from the walk kept on disk) give the same outcomes."""
    from jaxloco.sweep import run_sweep, write_report

    spec = SweepSpec(**CI_SPEC)
    b = run_sweep(spec, tmp_path / "b", backend="c", chunk_size=2, progress=False, planner=ALG1)
    summary = write_report(tmp_path / "b")
    assert summary["variants"]["replan"]["recovered"] == 2
    assert (tmp_path / "b" / "success_polar.png").stat().st_size > 0
    assert json.loads((tmp_path / "b" / "summary.json").read_text())["pushes"] == 2
    # One chunk: its time includes the compile, so no steady rate is claimed.
    assert b.manifest["runs"][0]["env_steps_per_s"] is None
    assert "no compile-free rate" in (tmp_path / "b" / "summary.md").read_text()

    stopped, stopped_walks, a, walks = chunks_of_one
    assert stopped.complete.tolist() == [True, False]
    assert stopped_walks == 1
    assert a.complete.all()
    assert len(a.manifest["runs"]) == 2 and a.manifest["runs"][1]["chunks"] == [1]
    assert len(walks) == 1  # the resume loaded its walk from disk
    assert a.outcomes["recovered"].dtype == bool
    # 200 N x 0.1 s is well inside what the walking controller recovers.
    assert a.outcomes["recovered"].all(), a.outcomes
    assert np.all(a.outcomes["steps_after"] >= 1)
    for k in FIELDS:
        np.testing.assert_allclose(a.outcomes[k], b.outcomes[k], rtol=1e-5, err_msg=k)


def _kill_a_worker_once_chunks_start(run_dir, killed):
    """Kill one of this process's Dask worker processes (SIGKILL) once the sweep in
    ``run_dir`` has its walks, i.e. while the workers run chunks."""
    import os
    import signal
    import time

    import psutil

    deadline = time.time() + 600
    while time.time() < deadline and not list((run_dir / "walks").glob("*.npz")):
        time.sleep(0.2)
    time.sleep(1.0)
    workers = [
        p
        for p in psutil.Process().children(recursive=True)
        if "spawn_main" in " ".join(p.cmdline())
    ]
    if workers:
        os.kill(workers[0].pid, signal.SIGKILL)
        killed.append(workers[0].pid)


def test_a_local_dask_cluster_gives_the_in_process_outcomes_bit_for_bit(
    tmp_path, chunks_of_one, capfd
):
    """Two Dask worker processes (one chunk each) give the outcomes of this process running
    the same chunks, bit for bit, even with one worker killed while chunks run (its task
    runs again); the run is recorded in the manifest; a damaged chunk file is run again,
    and a second call with nothing left to do starts no cluster. The workers print nothing
    about MJX's GPU backends (their preload imports MJX quietly)."""
    import threading

    from jaxloco.sweep import run_sweep

    spec = SweepSpec(**CI_SPEC)
    one = chunks_of_one[2]  # the same chunks, run in this process
    killed = []
    killer = threading.Thread(
        target=_kill_a_worker_once_chunks_start, args=(tmp_path / "two", killed), daemon=True
    )
    killer.start()
    two = run_sweep(
        spec, tmp_path / "two", backend="c", chunk_size=1, progress=False, workers=2, planner=ALG1
    )
    killer.join(timeout=5)
    assert killed, "no worker process was found to kill"
    printed = capfd.readouterr()
    assert "Failed to import" not in printed.out + printed.err
    assert two.complete.all()
    for k in FIELDS:
        np.testing.assert_array_equal(two.outcomes[k], one.outcomes[k], err_msg=k)
    run = two.manifest["runs"][0]
    assert run["executor"] == "dask" and run["workers"] == 2 and run["chunks"] == [0, 1]
    assert run["overall_env_steps_per_s"] > 0
    again = run_sweep(
        spec, tmp_path / "two", backend="c", chunk_size=1, progress=False, workers=2, planner=ALG1
    )
    assert len(again.manifest["runs"]) == 1
    # A damaged chunk is run again (here in this process), to the same outcomes.
    path = SweepStore(tmp_path / "two").chunk_path(1)
    path.write_bytes(b"not a chunk")
    fixed = run_sweep(
        spec, tmp_path / "two", backend="c", chunk_size=1, progress=False, planner=ALG1
    )
    assert fixed.manifest["runs"][-1]["chunks"] == [1]
    for k in FIELDS:
        np.testing.assert_array_equal(fixed.outcomes[k], one.outcomes[k], err_msg=k)


def test_the_steady_rate_leaves_out_each_workers_first_chunk():
    from jaxloco.sweep.chunks import ChunkReport
    from jaxloco.sweep.executors import run_record

    def report(i, worker, seconds):
        return ChunkReport(i, 16, 16, seconds, 40_000, worker)

    # Finish order: both workers' first chunks (start-up and compile), then two steady ones.
    done = [report(0, "a", 30.0), report(1, "b", 25.0), report(2, "a", 8.0), report(3, "b", 10.0)]
    run = run_record([0, 1, 2, 3], done, 5.0, 60.0, {"executor": "dask"})
    assert run["first_chunk_s"] == 30.0 and run["steady_chunk_s"] == 9.0
    assert run["env_steps_per_s"] == pytest.approx(2 * 40_000 / 9.0)  # side by side
    assert run["overall_env_steps_per_s"] == pytest.approx(160_000 / 60.0)
    alone = run_record([0], done[:1], 5.0, 30.0, {})
    assert alone["env_steps_per_s"] is None  # no compile-free chunk


def test_workers_are_validated(tmp_path):
    from jaxloco.sweep import run_sweep

    spec = SweepSpec(**CI_SPEC)
    with pytest.raises(ValueError, match="workers must be >= 0"):
        run_sweep(spec, tmp_path / "a", workers=-1, progress=False)
    with pytest.raises(ValueError, match="backend='mjx'"):
        run_sweep(spec, tmp_path / "b", backend="mjx", workers=2, progress=False)


def test_automatic_workers_need_enough_work_to_pay_for_their_start(monkeypatch):
    import jaxloco.sweep.run as sweep_run

    monkeypatch.setattr(sweep_run, "available_cores", lambda: [0, 1, 2, 3])
    assert sweep_run._auto_workers("c", 8.0) == 1  # bench_sweep's 8 pushes x 1 s
    assert sweep_run._auto_workers("c", 100.0) == 2
    assert sweep_run._auto_workers("c", 1e4) == 4  # never more than the cores
    assert sweep_run._auto_workers("mjx", 1e4) == 1


def test_walk_snapshots_round_trip_through_disk(tmp_path):
    from jaxloco.sweep.starts import WalkSnapshots, load_snapshots, save_snapshots

    template = {"gait": (np.zeros(3), np.int32(0)), "plan": np.zeros((2, 2))}
    stacked = {"gait": (np.arange(6.0).reshape(2, 3), np.array([4, 5], np.int32)),
               "plan": np.ones((2, 2, 2))}  # fmt: skip
    snap = WalkSnapshots(np.array([0.3, 0.7]), np.array([1.1, 1.3]), np.ones((2, 5)), stacked,
                         0.9, 0.6)  # fmt: skip
    path = tmp_path / "walks" / "w.npz"
    save_snapshots(path, snap)
    got = load_snapshots(path, template)
    assert sorted(p.name for p in path.parent.iterdir()) == ["w.npz"]  # no temporary left
    np.testing.assert_array_equal(got.phases, snap.phases)
    np.testing.assert_array_equal(got.physics, snap.physics)
    assert (got.step_start, got.step_duration) == (0.9, 0.6)
    for x, y in zip(jax.tree.leaves(got.controller), jax.tree.leaves(stacked), strict=True):
        np.testing.assert_array_equal(x, y)
        assert x.dtype == y.dtype


@pytest.mark.slow
def test_mjx_backend_gives_the_c_backends_push_outcomes(tmp_path):
    """Same pushes from the same snapshots on both physics backends (float32 controller)."""
    from jaxloco.sweep import run_sweep

    spec = SweepSpec(**CI_SPEC)
    c = run_sweep(spec, tmp_path / "c", backend="c", chunk_size=2, progress=False)
    m = run_sweep(spec, tmp_path / "m", backend="mjx", chunk_size=2, progress=False)
    print({k: (c.outcomes[k], m.outcomes[k]) for k in FIELDS})
    assert np.array_equal(c.outcomes["recovered"], m.outcomes["recovered"])
    assert np.array_equal(c.outcomes["steps_after"], m.outcomes["steps_after"])
    np.testing.assert_allclose(c.outcomes["max_com_error"], m.outcomes["max_com_error"], atol=0.02)


SHARDED = """
import json, sys
import numpy as np
from jaxloco.sweep import SweepSpec, run_sweep
import jax
import jax.numpy as jnp
spec = SweepSpec(**json.loads(sys.argv[1]))
r = run_sweep(spec, sys.argv[2], backend="mjx", chunk_size=2, progress=False)
print(json.dumps({"devices": jax.device_count(),
                  **{k: np.asarray(v).tolist() for k, v in r.outcomes.items()}}))
"""


@pytest.mark.slow
def test_sharded_over_two_host_devices_matches_one_device(tmp_path):
    """The MJX backend sharded over two virtual CPU devices gives one device's results."""
    import os
    import subprocess
    import sys

    spec = dict(CI_SPEC, horizon=0.5, steps_after=0)
    results = {}
    for n in (1, 2):
        env = dict(os.environ)
        env["XLA_FLAGS"] = (
            env.get("XLA_FLAGS", "") + f" --xla_force_host_platform_device_count={n}"
        ).strip()
        out = subprocess.run(
            [sys.executable, "-c", SHARDED, json.dumps(spec), str(tmp_path / f"d{n}")],
            env=env, capture_output=True, text=True, timeout=900,
        )  # fmt: skip
        assert out.returncode == 0, out.stderr[-3000:]
        results[n] = json.loads(out.stdout.strip().splitlines()[-1])
    assert results[1]["devices"] == 1 and results[2]["devices"] == 2
    # Discrete outcomes are identical; continuous ones agree to float32 rounding (the two
    # programs are compiled for different per-device batch sizes).
    for k in FIELDS:
        if k in DISCRETE:
            assert results[1][k] == results[2][k], k
        else:
            np.testing.assert_allclose(results[1][k], results[2][k], rtol=1e-3, err_msg=k)


def test_tree_layout_packs_one_array_per_dtype_and_back():
    from jaxloco.sim.packing import TreeLayout

    tree = {
        "f": jnp.arange(6.0, dtype=jnp.float32).reshape(2, 3),
        "i": jnp.asarray([3, -4], jnp.int32),
        "b": jnp.asarray(True),
        "g": (jnp.float32(2.5), jnp.zeros((0,), jnp.float32)),
    }
    layout = TreeLayout.of(tree)
    packed = layout.pack(tree)
    assert sorted(packed) == ["bool", "float32", "int32"]
    assert packed["float32"].shape == (7,) and packed["int32"].dtype == jnp.int32
    back = layout.unpack(packed)
    assert jax.tree.structure(back) == jax.tree.structure(tree)
    for a, b in zip(jax.tree.leaves(back), jax.tree.leaves(tree), strict=True):
        assert a.dtype == b.dtype and a.shape == b.shape
        np.testing.assert_array_equal(a, b)
    # Batched the way the C backend uses it: a leading robot axis on every leaf.
    stacked = jax.tree.map(lambda x: jnp.stack([x, x]), tree)
    round_trip = jax.vmap(layout.unpack)(jax.vmap(layout.pack)(stacked))
    np.testing.assert_array_equal(round_trip["i"], stacked["i"])
    assert hash(layout) == hash(TreeLayout.of(tree))  # keys the compile cache


def test_host_gather_packs_live_arrays_into_alternating_buffers():
    from jaxloco.sim.packing import HostGather

    rng = np.random.default_rng(0)
    time = np.array([0.5, 1.25])
    matrix = rng.normal(size=(2, 6, 6))[:, ::2, :]  # a strided view, as MuJoCo's bound fields
    host = HostGather((time, matrix))
    first = host.gather()
    assert first.shape == (2, 1 + 18)
    t, m = jax.vmap(host.unpack)(jnp.asarray(first))
    np.testing.assert_array_equal(t, time)
    np.testing.assert_array_equal(m, matrix)
    # The next gather reads the arrays' new values into the other buffer: the one a tick may
    # still be reading is left as it was.
    kept = first.copy()
    time += 0.001
    second = host.gather()
    assert second is not first
    np.testing.assert_array_equal(first, kept)
    np.testing.assert_array_equal(second[:, 0], time)
