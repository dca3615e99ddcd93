"""jaxloco: JAX locomotion stack of Kim, Lee and Sentis (RL-PSP planner + WBLC).

Call :func:`jaxloco.runtime.configure` before the first computation to get the XLA:CPU
options jaxloco is measured with; importing jaxloco changes nothing in the process.
"""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("jaxloco")
except PackageNotFoundError:  # a source tree that was never installed
    __version__ = "0.0.0"

# The layers are subpackages, imported by name (``from jaxloco.control import make_wblc``).
__all__ = ["__version__"]
