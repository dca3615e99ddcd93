"""jaxloco: JAX locomotion stack of Kim, Lee and Sentis (RL-PSP planner + WBLC).

Call :func:`jaxloco.runtime.configure` before the first computation to get the XLA:CPU
options jaxloco is measured with; importing jaxloco changes nothing in the process.
"""
