"""The Python samples of README.md and docs/: each page's blocks, in order, are one script
that defines every name it uses; the quick ones run as written."""

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
QUICK = ("README.md", "control.md", "planner.md")
"""Pages whose samples run in seconds."""
SLOW = ("dynamics.md", "locomotion.md")
"""Pages whose samples run in a minute or so (``make test-all``). The others train
policies, tune gains or run searches at full size."""


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


@pytest.mark.parametrize(
    "name", [*QUICK, *(pytest.param(name, marks=pytest.mark.slow) for name in SLOW)]
)
def test_the_samples_run_as_written(name, tmp_path):
    page = ROOT / name if name == "README.md" else ROOT / "docs" / name
    path = tmp_path / f"{page.stem}.py"
    path.write_text(script(page))
    # XLA:CPU has been seen to hang (rarely, under a loaded machine): past the limit the
    # script is aborted with every thread's Python stack in the failure (faulthandler).
    proc = subprocess.Popen(
        [sys.executable, "-X", "faulthandler", str(path)],
        cwd=tmp_path,
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
