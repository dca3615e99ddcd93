"""The Python samples of README.md and docs/: each page's blocks, in order, are one script
that defines every name it uses, and every page's script runs in the suite: as written, or
on CI-sized problems (the same calls, smaller)."""

import os
import re
import signal
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
PAGES = [
    p
    for p in [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
    if "```python" in p.read_text()
]
AS_WRITTEN = ("README.md", "control.md", "dynamics.md", "locomotion.md", "planner.md")
"""Pages whose samples run as written (each in under a minute in the full suite)."""
CI_SIZED = {
    "learning.md": (
        (
            "TrainConfig()",
            "TrainConfig(actor_critic=_ci.replace(TrainConfig().actor_critic, "
            "episodes_per_iteration=64, max_episode_steps=4, max_iterations=2), "
            "evaluation=_ci.replace(TrainConfig().evaluation, every=2, num_states=128, "
            "num_steps=10), refine=_ci.replace(TrainConfig().refine, iterations=2, batch=64))",
        ),
        (
            "PPOConfig()",
            "PPOConfig(num_timesteps=4096, num_envs=64, batch_size=32, num_minibatches=4, "
            "num_updates_per_batch=1, unroll_length=5, episode_length=10, policy_hidden=(8,), "
            "value_hidden=(8,), num_evals=3, basin_states=64, basin_steps=5)",
        ),
    ),
    "sweep.md": (
        ("directions_deg=(0, 45, 90, 135, 180, 225, 270, 315)", "directions_deg=(180,)"),
        ("phases=(0.1, 0.3, 0.5, 0.7, 0.9)", "phases=(0.5,)"),
        ("replan=(True, False)", "replan=(True,)"),
        ("rounds=4", "rounds=1"),
        ("replicas=5", "replicas=1"),
        ("min_recovered=4", "min_recovered=1, push_step=1, horizon=0.8, steps_after=1"),
        ("directions_deg=(0, 90, 180, 270)", "directions_deg=(0,)"),
        ("magnitudes=(300, 520)", "magnitudes=(520,)"),
        ("horizon=2.5,", "horizon=0.8, push_step=1, steps_after=1,"),
    ),
    "tuning.md": (
        ("horizon=2.5,", "horizon=0.06, segment=60,"),
        ('gradient="forward")', 'gradient="forward", iterations=1)'),
    ),
}
"""Pages that train policies, run searches or tune gains at full size, run with these
replacements (text as written -> a CI-sized value): the same calls on smaller problems.
A replacement that no longer matches the page fails the test, so the sizes follow the
docs."""


def test_every_sample_page_is_run():
    assert sorted(p.name for p in PAGES) == sorted({*AS_WRITTEN, *CI_SIZED})
    assert not set(AS_WRITTEN) & set(CI_SIZED)


def script(page: Path) -> str:
    return "\n".join(re.findall(r"^```python\n(.*?)^```", page.read_text(), re.S | re.M))


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.name)
def test_every_sample_page_defines_what_it_uses(page, tmp_path):
    path = tmp_path / f"{page.stem}.py"
    path.write_text(script(page))
    found = subprocess.run(
        [sys.executable, "-m", "ruff", "check", "--no-cache", "--isolated", "--select",
         "F821,F811", "--output-format", "concise", str(path)],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert found.returncode == 0, found.stdout + found.stderr


def ci_sized(name: str, text: str) -> str:
    """``text`` with the page's :data:`CI_SIZED` replacements, each of which must match."""
    for old, new in CI_SIZED[name]:
        assert old in text, f"{name}: the CI-sized run replaces {old!r}, no longer on the page"
        text = text.replace(old, new)
    return "import dataclasses as _ci\n" + text


@pytest.mark.parametrize("name", [*AS_WRITTEN, *CI_SIZED])
def test_the_samples_run(name, tmp_path):
    """Every page with samples runs: as written, or CI-sized (:data:`CI_SIZED`)."""
    page = ROOT / name if name == "README.md" else ROOT / "docs" / name
    path = tmp_path / f"{page.stem}.py"
    text = script(page)
    path.write_text(ci_sized(name, text) if name in CI_SIZED else text)
    # XLA:CPU has been seen to hang (rarely, under a loaded machine): past the limit the
    # script is aborted with every thread's Python stack in the failure (faulthandler).
    # The run's compile cache (tests/conftest.py): a program a page builds twice (sweep.md's
    # limit search and sweep compile the same tick) is read back the second time.
    env = {**os.environ, "JAX_COMPILATION_CACHE_DIR": os.environ["JAXLOCO_TEST_CACHE_DIR"]}
    proc = subprocess.Popen(
        [sys.executable, "-X", "faulthandler", str(path)],
        cwd=tmp_path,
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        _, err = proc.communicate(timeout=300)
    except subprocess.TimeoutExpired:
        proc.send_signal(signal.SIGABRT)
        _, err = proc.communicate(timeout=60)
        pytest.fail(f"{name}'s samples hung for 300 s; their stacks:\n{err[-6000:]}")
    assert proc.returncode == 0, err[-3000:]
