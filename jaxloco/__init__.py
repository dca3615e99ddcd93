"""jaxloco: JAX locomotion stack of Kim, Lee and Sentis (RL-PSP planner + WBLC)."""

import os as _os

# XLA:CPU's concurrency-optimised scheduler has deadlocked here (0% CPU, stuck in
# block_until_ready) on vmapped programs with several independent LAPACK calls, e.g. the
# force QP's polish at batch >= 64. Turning it off fixed every such hang we reproduced.
# Set before JAX creates its CPU backend; a user's own XLA_FLAGS setting wins.
_FLAG = "--xla_cpu_enable_concurrency_optimized_scheduler"
if _FLAG not in _os.environ.get("XLA_FLAGS", ""):
    _os.environ["XLA_FLAGS"] = (_os.environ.get("XLA_FLAGS", "") + f" {_FLAG}=false").strip()
