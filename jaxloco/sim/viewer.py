"""Watching a run as it happens: MuJoCo's passive viewer, paced to the simulation's clock.

:func:`open_viewer` opens the viewer on a model and its data (or says clearly that this
machine has no display); the :class:`RealTimeViewer` it returns is called after every
physics step (``run_closed_loop(..., on_step=viewer)``): it redraws the scene at most
``fps`` times a second and waits so the run goes no faster than real time (it goes slower
when the controller and physics take longer than the timestep). Closing the window does not
stop the run; the recorded video (:mod:`.render`) is the headless alternative.
"""

from __future__ import annotations

import os
import sys
import threading
import time
from collections.abc import Callable
from typing import Protocol

import mujoco


class ViewerHandle(Protocol):
    """What :class:`RealTimeViewer` uses of ``mujoco.viewer.Handle``."""

    def sync(self) -> None: ...

    def is_running(self) -> bool: ...

    def close(self) -> None: ...


def display_available(environ: dict[str, str] | None = None) -> bool:
    """Whether a window can open: on Linux a ``DISPLAY`` or ``WAYLAND_DISPLAY`` is set;
    macOS and Windows always have one."""
    environ = os.environ if environ is None else environ
    if not sys.platform.startswith("linux"):
        return True
    return bool(environ.get("DISPLAY") or environ.get("WAYLAND_DISPLAY"))


class NoDisplayError(RuntimeError):
    """The viewer was asked for on a machine with no display."""


class RealTimeViewer:
    """Called after each physics step with the data: redraws at most ``fps`` times per
    simulated second and keeps the simulation from running ahead of the wall clock."""

    def __init__(
        self,
        handle: ViewerHandle,
        fps: float = 60.0,
        clock: Callable[[], float] = time.perf_counter,
        sleep: Callable[[float], None] = time.sleep,
    ):
        if not fps > 0:
            raise ValueError(f"fps must be > 0 frames per second; got {fps}")
        self.handle = handle
        self.period = 1.0 / fps
        self.clock, self.sleep = clock, sleep
        self.start_wall: float | None = None
        self.start_sim = 0.0
        self.last_frame = -float("inf")
        self.frames = 0
        self.threads: list[threading.Thread] = []
        """The viewer's drawing threads, joined by :meth:`close`."""

    def __call__(self, data: mujoco.MjData) -> None:
        if self.start_wall is None:
            self.start_wall, self.start_sim = self.clock(), float(data.time)
        if data.time - self.last_frame < self.period or not self.handle.is_running():
            return
        ahead = (data.time - self.start_sim) - (self.clock() - self.start_wall)
        if ahead > 0:
            self.sleep(ahead)
        self.handle.sync()
        self.last_frame = float(data.time)
        self.frames += 1

    def close(self, wait_s: float = 5.0) -> None:
        """Close the window and wait (up to ``wait_s``) for the viewer's threads to end:
        MuJoCo draws on a daemon thread, and a process that exits while it still draws can
        crash in the GL driver (seen under Xvfb)."""
        self.handle.close()
        for thread in self.threads:
            thread.join(wait_s)


def require_display() -> None:
    """Raise :class:`NoDisplayError`, saying what to do instead, where no window can open."""
    if not display_available():
        raise NoDisplayError(
            "viewer=true needs a display, and this machine has none (DISPLAY and "
            "WAYLAND_DISPLAY are unset); run where a screen is attached, forward X (ssh -X), "
            "or keep viewer=false and watch the recorded video (video=true)"
        )


def open_viewer(model: mujoco.MjModel, data: mujoco.MjData, fps: float = 60.0) -> RealTimeViewer:
    """MuJoCo's passive viewer on ``model``/``data``, paced to real time.

    Raises :class:`NoDisplayError` where no window can open (no ``DISPLAY`` or
    ``WAYLAND_DISPLAY`` on Linux, e.g. over SSH or in CI)."""
    require_display()
    import mujoco.viewer  # noqa: PLC0415 (GLFW: only where a window opens)

    before = set(threading.enumerate())
    viewer = RealTimeViewer(mujoco.viewer.launch_passive(model, data), fps=fps)
    viewer.threads = [t for t in threading.enumerate() if t not in before]
    return viewer
