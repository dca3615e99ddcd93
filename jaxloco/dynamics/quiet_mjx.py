"""MuJoCo's MJX as jaxloco imports it: without the "Failed to import warp" lines MJX prints
when NVIDIA Warp (an optional GPU backend jaxloco does not use) is not installed.

Every library module takes ``mjx`` from here, so whichever of them a process imports first
(a script, a Dask worker re-importing its parent's main module) stays quiet; other output
and errors of the import pass through (:func:`jaxloco.runtime.import_mjx_quietly`).
"""

from jaxloco.runtime import import_mjx_quietly

import_mjx_quietly()

from mujoco import mjx  # noqa: E402  (after the quiet import, which it then finds loaded)

__all__ = ["mjx"]
