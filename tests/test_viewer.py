"""Watching a run: the viewer is paced to the simulation's clock, and where there is no
display the command says so instead of failing inside GLFW."""

import os
import subprocess
import sys
from types import SimpleNamespace

import pytest

from jaxloco.sim.viewer import NoDisplayError, RealTimeViewer, display_available, open_viewer


class FakeHandle:
    def __init__(self, running=True):
        self.syncs, self.running, self.closed = 0, running, False

    def sync(self):
        self.syncs += 1

    def is_running(self):
        return self.running

    def close(self):
        self.closed = True


class FakeClock:
    """Wall time that moves only when stepped or slept."""

    def __init__(self):
        self.now, self.slept = 0.0, 0.0

    def __call__(self):
        return self.now

    def sleep(self, seconds):
        self.now += seconds
        self.slept += seconds


def run_steps(viewer, clock, steps, dt, wall_per_step):
    data = SimpleNamespace(time=0.0)
    for _ in range(steps):
        data.time += dt
        clock.now += wall_per_step
        viewer(data)
    return data


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="display rules are Linux's")
def test_a_display_is_x_or_wayland_on_linux():
    assert not display_available({})
    assert not display_available({"DISPLAY": ""})
    assert display_available({"DISPLAY": ":0"})
    assert display_available({"WAYLAND_DISPLAY": "wayland-0"})


def test_a_fast_run_is_slowed_to_real_time_at_the_viewers_frame_rate():
    clock, handle = FakeClock(), FakeHandle()
    viewer = RealTimeViewer(handle, fps=50.0, clock=clock, sleep=clock.sleep)
    # 2 s simulated at 1 kHz, computed at 4x real time: the viewer waits out the rest.
    run_steps(viewer, clock, 2000, 1e-3, 0.25e-3)
    assert 95 <= handle.syncs <= 101  # 50 frames per simulated second
    assert clock.now == pytest.approx(2.0, abs=0.03)  # wall clock kept with the simulation
    assert clock.slept == pytest.approx(1.5, abs=0.03)


def test_a_slow_run_is_not_delayed_and_a_closed_window_is_not_drawn():
    clock, handle = FakeClock(), FakeHandle()
    viewer = RealTimeViewer(handle, fps=50.0, clock=clock, sleep=clock.sleep)
    run_steps(viewer, clock, 1000, 1e-3, 2e-3)  # half real time: never sleeps
    assert clock.slept == 0.0 and handle.syncs > 0
    closed = FakeHandle(running=False)
    viewer = RealTimeViewer(closed, clock=clock, sleep=clock.sleep)
    run_steps(viewer, clock, 100, 1e-3, 0.0)
    assert closed.syncs == 0
    viewer.close()
    assert closed.closed
    with pytest.raises(ValueError, match="fps must be > 0"):
        RealTimeViewer(FakeHandle(), fps=0.0)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="display rules are Linux's")
def test_without_a_display_the_viewer_and_the_command_say_so(tmp_path, monkeypatch):
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    with pytest.raises(NoDisplayError, match="needs a display"):
        open_viewer(None, None)
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    out = subprocess.run(
        [sys.executable, "-m", "jaxloco.cli", "walk-steer", "viewer=true",
         f"hydra.run.dir={tmp_path / 'run'}"],
        cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert out.returncode != 0
    assert "viewer=true needs a display" in out.stdout + out.stderr
