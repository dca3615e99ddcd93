"""Loading the robot models shipped in ``assets/``.

The Valkyrie-like humanoid (``assets/valkyrie/valkyrie.xml``, written by
``assets/valkyrie/build_valkyrie.py`` from published figures): floating base + 28 joints in
the paper's order, nq = 35, nv = 34, 135.9 kg; torque motors with the effort limits as
control ranges; contacts only between each sole box and the floor; sites at each foot's
centre of pressure and 4 contact corners. Keyframes ``zero`` (T-pose) and ``walk``. Its
names (joints, feet, frames) are in :mod:`jaxloco.robots.valkyrie`.
"""

from __future__ import annotations

import copy
from pathlib import Path

import mujoco
import numpy as np

from jaxloco.runtime import assets_dir  # noqa: F401 (re-exported)


def load_model(name_or_path: str) -> mujoco.MjModel:
    """An MjModel from a path, or a name in assets/: ``valkyrie`` or ``planar3dof``."""
    named = {
        "valkyrie": assets_dir() / "valkyrie" / "valkyrie.xml",
        "planar3dof": assets_dir() / "planar3dof.xml",
    }
    path = named.get(name_or_path, Path(name_or_path))
    if not path.exists():
        raise FileNotFoundError(
            f"no model {name_or_path!r}: expected one of {sorted(named)} or an MJCF path"
        )
    return mujoco.MjModel.from_xml_path(str(path))


def load_valkyrie() -> mujoco.MjModel:
    return load_model("valkyrie")


def without_colliders(model: mujoco.MjModel) -> mujoco.MjModel:
    """A copy of ``model`` whose geoms collide with nothing: the controller's dynamics (mass
    matrix, bias forces, Jacobians) need no collision geometry, and ``mjx.put_model``
    refuses colliders MJX cannot pair (e.g. the G1's cylinders against meshes)."""
    model = copy.deepcopy(model)
    model.geom_contype[:] = 0
    model.geom_conaffinity[:] = 0
    return model


def keyframe_qpos(model: mujoco.MjModel, name: str) -> np.ndarray:
    """The ``qpos`` of a named keyframe."""
    key = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_KEY, name)
    if key < 0:
        names = [model.key(i).name for i in range(model.nkey)]
        raise KeyError(f"no keyframe {name!r}; the model has {names}")
    return model.key_qpos[key].copy()


def joint_dof(model: mujoco.MjModel, names) -> np.ndarray:
    """Velocity indices of the named (hinge) joints."""
    return np.array([model.jnt_dofadr[model.joint(n).id] for n in names])


def site_id(model: mujoco.MjModel, name: str) -> int:
    return model.site(name).id


def body_id(model: mujoco.MjModel, name: str) -> int:
    return model.body(name).id
