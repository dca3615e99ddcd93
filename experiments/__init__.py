"""The experiments: one hydra app per file, run as ``jaxloco NAME`` (``jaxloco`` lists
them). Installed as the package ``jaxloco.experiments``, so the command works from a
wheel as from a checkout."""
