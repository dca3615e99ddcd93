"""Files jaxloco loads at run time, installed as the package data of ``jaxloco.assets``:
the MJCF models, the shipped step policies and tuned gains (see ``README.md`` here)."""
