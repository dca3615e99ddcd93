"""Write ``valkyrie.xml``: a Valkyrie-like 28-joint humanoid, from published figures.

    python assets/valkyrie/build_valkyrie.py          # rewrites valkyrie.xml next to it

The numbers are NASA's published Valkyrie description (val_description), reduced
to 28 joints: wrists and fingers fixed), kept here once and mirrored for the right side.
A test checks that the committed XML is exactly what this script writes.

Modelling choices (not in the figures):
- Geoms are primitive shapes for looks; all of them have contype = conaffinity = 0. The
  only contacts are explicit pairs with the floor: per foot, 4 spheres of radius
  ``SOLE_SPHERE_RADIUS`` whose lowest points are the 4 bottom corners of the sole box
  (MJX is fast with few contacts). Floor friction 0.8, no restitution. Spheres, not the
  box itself: MJX's plane-box collider keeps only corners within 1 mm of the deepest one,
  so a sole tilted by 0.2 deg lost a corner on MJX and kept it on MuJoCo C, and the two
  backends parted after hard pushes (MJX recovered 2 of 40 pushes of 520 N, C 36).
  Sphere-plane contacts are the same
  on both; flat on the floor, the 4 spheres touch where the box's corners did.
- Near-zero inertias (the 0.03 kg ankle-pitch link) are set to 1e-5 kg m^2.
- Each foot carries sites at its centre of pressure and at the 4 contact points used by
  the force QP, 1 cm inside the sole's bottom corners, so the whole sole carries load (the
  authors' points, +-0.10 m, +-0.05 m around the CoP frame, reach 12 mm past this sole's
  heel). The authors' CoP frame sits 9.7 mm above the sole; here the sites lie on the sole
  surface (z = -0.088 below the ankle), so the contact points touch the ground.
- Right-side joint ranges mirror hipYaw, hipRoll, shoulderRoll and elbowPitch (the axes
  are the same on both sides); the others are equal.
- The walking keyframe (hip pitch -0.3, knee 0.6, ankle pitch -0.3, arms lowered) places
  the pelvis so that the soles rest on the floor.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

TINY_INERTIA = 1e-5

# name: (mass, com, diag inertia, joint axis, joint offset from parent)
PELVIS = dict(mass=8.220, com=(-0.0053, -0.0035, -0.0036), inertia=(0.1187, 0.0980, 0.0839))
LEG = [
    (
        "hipYaw",
        2.390,
        (0.0218, -0.0013, 0.0387),
        (0.0173, 0.0149, 0.0112),
        "z",
        (0, 0.1016, -0.1853),
    ),
    ("hipRoll", 3.665, (0.0130, 0.0076, -0.0159), (0.0060, 0.0094, 0.0082), "x", (0, 0, 0)),
    ("hipPitch", 10.200, (0.0167, 0.0914, -0.2079), (0.2408, 0.2569, 0.0233), "y", (0, 0, -0.0609)),
    (
        "knee",
        6.200,
        (-0.0222, 0.0017, -0.1894),
        (0.0869, 0.0916, 0.0140),
        "y",
        (0.0001, 0.0361, -0.4310),
    ),
    ("anklePitch", 0.030, (0, 0, 0), (0, 0, 0), "y", (-0.0102, 0, -0.4063)),
    ("ankleRoll", 2.370, (0.0369, 0.0049, -0.0489), (0.0064, 0.0180, 0.0209), "x", (0, 0, 0)),
]
TORSO = [
    ("torsoYaw", 0.500, (0, 0, -0.01), (0.0006, 0.0006, 0.0011), "z", (0, 0, 0)),
    ("torsoPitch", 0.100, (0, 0, 0.005), (0, 0, 0), "y", (0.0419, 0, 0)),
    (
        "torsoRoll",
        39.470,
        (-0.0955, -0.0033, 0.2431),
        (0.8733, 1.0108, 0.7784),
        "x",
        (0, 0, 0.0203),
    ),
]
NECK = [
    ("lowerNeckPitch", 1.050, (-0.02, 0, 0.04), (0.0015, 0.0019, 0.0008), "y", (0.0204, 0, 0.3385)),
    ("neckYaw", 1.400, (-0.03, -0.01, 0.15), (0.0020, 0.0029, 0.0021), "z", (-0.0519, 0, 0)),
    (
        "upperNeckPitch",
        5.368,
        (0.1027, 0.0042, 0.0404),
        (0.0448, 0.0465, 0.0404),
        "y",
        (-0.06, 0, 0.196),
    ),
]
ARM = [
    (
        "shoulderPitch",
        2.650,
        (-0.012, 0.251, 0),
        (0.0137, 0.0105, 0.0148),
        "y",
        (-0.0316, 0, 0.2984),
    ),
    (
        "shoulderRoll",
        3.970,
        (-0.0085, 0.0207, -0.0011),
        (0.0146, 0.0065, 0.0168),
        "x",
        (0, 0.2499, 0),
    ),
    ("shoulderYaw", 3.085, (-0.0043, 0.2098, 0.0073), (0.0394, 0.0049, 0.0419), "y", (0, 0, 0)),
    (
        "elbowPitch",
        1.830,
        (-0.0203, 0.0147, 0.0223),
        (0.0033, 0.0035, 0.0030),
        "z",
        (0.0254, 0.33, 0),
    ),
    ("forearmYaw", 3.506, (0.0113, 0.1921, 0.0146), (0.0471, 0.0066, 0.0458), "y", (-0.0254, 0, 0)),
]
WRIST = (0, 0.2871, 0)

# Left-side limits: position range, effort.
LIMITS = {
    "hipYaw": ((-0.414, 1.1), 190),
    "hipRoll": ((-0.467, 0.5515), 350),
    "hipPitch": ((-2.42, 1.619), 350),
    "knee": ((-0.083, 2.057), 350),
    "anklePitch": ((-0.93, 0.65), 205),
    "ankleRoll": ((-0.4, 0.4), 205),
    "torsoYaw": ((-1.329, 1.181), 190),
    "torsoPitch": ((-0.13, 0.666), 150),
    "torsoRoll": ((-0.23, 0.255), 150),
    "shoulderPitch": ((-2.85, 2.0), 190),
    "shoulderRoll": ((-1.519, 1.266), 190),
    "shoulderYaw": ((-3.1, 2.18), 65),
    "elbowPitch": ((-2.174, 0.12), 65),
    "forearmYaw": ((-2.019, 3.14), 26),
    "lowerNeckPitch": ((0.0, 1.162), 26),
    "neckYaw": ((-1.047, 1.047), 26),
    "upperNeckPitch": ((-0.872, 0.0), 26),
}
MIRRORED_RANGES = {"hipYaw", "hipRoll", "shoulderRoll", "elbowPitch"}

SOLE_SIZE = (0.27, 0.16, 0.064)
SOLE_CENTRE = (0.066, 0.0, -0.056)
SOLE_Z = -0.088
COP = (0.0189, 0.0)
FORCE_POINT_INSET = 0.01
"""The force QP's 4 contact points per foot sit this far inside the sole's bottom corners
(m). The authors' points (+-0.10, +-0.05 around the CoP frame) reach 12 mm behind this
sole's heel: a QP that loads them asks for a centre of pressure the foot cannot give, and
the foot rolls onto its heel (traced after a 520 N push from 225 deg)."""
SOLE_SPHERE_RADIUS = 0.005
"""Contact spheres at the sole box's bottom corners (m)."""


def force_points() -> list[tuple[float, float]]:
    """(x, y) of the force QP's contact points in the foot frame, ``FORCE_POINT_INSET``
    inside the sole's corners, in the order (+x +y), (+x -y), (-x +y), (-x -y)."""
    cx, cy, _ = SOLE_CENTRE
    hx, hy = SOLE_SIZE[0] / 2 - FORCE_POINT_INSET, SOLE_SIZE[1] / 2 - FORCE_POINT_INSET
    return [(cx + sx * hx, cy + sy * hy) for sx in (1, -1) for sy in (1, -1)]


def sole_corner_spheres() -> list[tuple[float, float, float]]:
    """Centres of the 4 contact spheres: each touches the plane of the sole's bottom face
    at one of its corners."""
    cx, cy, _ = SOLE_CENTRE
    hx, hy = SOLE_SIZE[0] / 2, SOLE_SIZE[1] / 2
    z = SOLE_Z + SOLE_SPHERE_RADIUS
    return [(cx + sx * hx, cy + sy * hy, z) for sx in (1, -1) for sy in (1, -1)]


WALK_POSTURE = {
    "hipPitch": -0.3,
    "knee": 0.6,
    "anklePitch": -0.3,
    "shoulderRoll": -1.3,  # left arm down (mirrored on the right)
}

COLORS = {
    "pelvis": "0.35 0.35 0.4 1",
    "limb": "0.85 0.85 0.88 1",
    "foot": "0.25 0.25 0.3 1",
    "torso": "0.7 0.15 0.15 1",
    "head": "0.9 0.9 0.9 1",
}


def fmt(v):
    return " ".join(f"{x:.6g}" for x in v)


def mirror(v, side):
    return (v[0], v[1] if side == "left" else -v[1], v[2])


def joint_range(name, side):
    (lo, hi), effort = LIMITS[name]
    if side == "right" and name in MIRRORED_RANGES:
        lo, hi = -hi, -lo
    return (lo, hi), effort


def inertial(mass, com, inertia, side="left"):
    inertia = tuple(max(i, TINY_INERTIA) for i in inertia)
    return (
        f'<inertial pos="{fmt(mirror(com, side))}" mass="{mass:.6g}" diaginertia="{fmt(inertia)}"/>'
    )


class Writer:
    def __init__(self):
        self.lines = []
        self.depth = 0
        self.joints = []

    def add(self, line):
        self.lines.append("  " * self.depth + line)

    def open(self, line):
        self.add(line)
        self.depth += 1

    def close(self, tag):
        self.depth -= 1
        self.add(f"</{tag}>")

    def joint(self, name, axis, side_name, side):
        (lo, hi), effort = joint_range(name, side)
        self.joints.append((side_name, effort))
        axis_v = {"x": (1, 0, 0), "y": (0, 1, 0), "z": (0, 0, 1)}[axis]
        self.add(
            f'<joint name="{side_name}" type="hinge" axis="{fmt(axis_v)}" '
            f'range="{lo:.6g} {hi:.6g}"/>'
        )


def leg(w: Writer, side: str):
    prefix = side
    for name, mass, com, inertia, axis, offset in LEG:
        w.open(f'<body name="{prefix}_{name}_link" pos="{fmt(mirror(offset, side))}">')
        w.add(inertial(mass, com, inertia, side))
        w.joint(name, axis, f"{prefix}_{name}", side)
        if name == "hipPitch":  # thigh
            w.add(
                f'<geom type="capsule" size="0.06" fromto="0 0 0 {fmt(mirror(LEG[3][5], side))}" '
                f'rgba="{COLORS["limb"]}" class="visual"/>'
            )
        elif name == "knee":  # shin
            w.add(
                f'<geom type="capsule" size="0.05" fromto="0 0 0 {fmt(mirror(LEG[4][5], side))}" '
                f'rgba="{COLORS["limb"]}" class="visual"/>'
            )
        elif name == "ankleRoll":  # foot
            w.add(
                f'<geom name="{prefix}_sole" type="box" size="{fmt(np.array(SOLE_SIZE) / 2)}" '
                f'pos="{fmt(SOLE_CENTRE)}" rgba="{COLORS["foot"]}" class="visual"/>'
            )
            for k, corner in enumerate(sole_corner_spheres()):
                w.add(
                    f'<geom name="{prefix}_sole{k}" type="sphere" size="{SOLE_SPHERE_RADIUS}" '
                    f'pos="{fmt(corner)}" class="sole"/>'
                )
            w.add(f'<site name="{prefix}_foot_cop" pos="{fmt((*COP, SOLE_Z))}" size="0.01"/>')
            for k, (x, y) in enumerate(force_points()):
                pos = (x, y, SOLE_Z)
                w.add(f'<site name="{prefix}_foot_contact{k}" pos="{fmt(pos)}" size="0.008"/>')
        elif name == "hipYaw":
            w.add(f'<geom type="sphere" size="0.07" rgba="{COLORS["limb"]}" class="visual"/>')
    for _ in LEG:
        w.close("body")


def arm(w: Writer, side: str):
    for name, mass, com, inertia, axis, offset in ARM:
        w.open(f'<body name="{side}_{name}_link" pos="{fmt(mirror(offset, side))}">')
        w.add(inertial(mass, com, inertia, side))
        w.joint(name, axis, f"{side}_{name}", side)
        if name == "shoulderYaw":  # upper arm, to the elbow
            w.add(
                f'<geom type="capsule" size="0.045" fromto="0 0 0 {fmt(mirror(ARM[3][5], side))}" '
                f'rgba="{COLORS["limb"]}" class="visual"/>'
            )
        elif name == "forearmYaw":  # forearm and hand, to the wrist
            w.add(
                f'<geom type="capsule" size="0.04" fromto="0 0 0 {fmt(mirror(WRIST, side))}" '
                f'rgba="{COLORS["limb"]}" class="visual"/>'
            )
            w.add(f'<site name="{side}_hand" pos="{fmt(mirror(WRIST, side))}" size="0.01"/>')
    for _ in ARM:
        w.close("body")


def build() -> tuple[str, list[tuple[str, float]]]:
    w = Writer()
    w.open('<body name="pelvis" pos="0 0 1.171" childclass="valkyrie">')
    w.add('<freejoint name="floating_base"/>')
    w.add(inertial(**PELVIS))
    w.add(f'<geom type="box" size="0.1 0.15 0.08" rgba="{COLORS["pelvis"]}" class="visual"/>')
    w.add('<site name="pelvis" size="0.01"/>')
    leg(w, "left")
    leg(w, "right")
    for name, mass, com, inertia, axis, offset in TORSO:
        w.open(f'<body name="{name}_link" pos="{fmt(offset)}">')
        w.add(inertial(mass, com, inertia))
        w.joint(name, axis, name, "left")
    w.add(
        f'<geom type="box" size="0.14 0.18 0.2" pos="-0.08 0 0.25" rgba="{COLORS["torso"]}" '
        'class="visual"/>'
    )
    w.add('<site name="torso" pos="0 0 0.25" size="0.01"/>')
    arm(w, "left")
    for name, mass, com, inertia, axis, offset in NECK:
        w.open(f'<body name="{name}_link" pos="{fmt(offset)}">')
        w.add(inertial(mass, com, inertia))
        w.joint(name, axis, name, "left")
    w.add(
        f'<geom type="sphere" size="0.11" pos="0.06 0 0.05" rgba="{COLORS["head"]}" '
        'class="visual"/>'
    )
    for _ in NECK:
        w.close("body")
    arm(w, "right")
    for _ in TORSO:
        w.close("body")
    w.close("body")
    return "\n".join("      " + line for line in w.lines), w.joints


def walking_qpos(joint_names):
    """Joint angles of the walking posture, in joint order (pelvis height solved later)."""
    q = []
    for name in joint_names:
        side, _, base = name.partition("_")
        if not base:
            base = side
        value = WALK_POSTURE.get(base, 0.0)
        if base == "shoulderRoll" and side == "right":
            value = -value
        q.append(value)
    return q


def xml_text(walk_pelvis_z: float | None = None, joints=None) -> str:
    body, joints_found = build()
    joints = joints or joints_found
    names = [n for n, _ in joints]
    actuators = "\n".join(
        f'    <motor name="{n}" joint="{n}" ctrlrange="{-e:.6g} {e:.6g}"/>' for n, e in joints
    )
    zero = " ".join(["0 0 1.171 1 0 0 0"] + ["0"] * len(names))
    walk = walking_qpos(names)
    walk_z = 1.171 if walk_pelvis_z is None else walk_pelvis_z
    walk_q = " ".join([f"0 0 {walk_z:.6g} 1 0 0 0"] + [f"{v:.6g}" for v in walk])
    pairs = "\n".join(
        f'    <pair geom1="{side}_sole{k}" geom2="floor" friction="0.8 0.8 0.005 0.0001 0.0001"/>'
        for side in ("left", "right")
        for k in range(len(sole_corner_spheres()))
    )
    return f"""<!-- Generated by build_valkyrie.py from published Valkyrie figures; do not edit by hand. -->
<mujoco model="valkyrie">
  <compiler angle="radian" autolimits="true"/>
  <option timestep="0.001" integrator="Euler"/>
  <default>
    <default class="valkyrie">
      <joint damping="0" armature="0" limited="true"/>
      <default class="visual">
        <geom contype="0" conaffinity="0" group="1" density="0"/>
      </default>
      <default class="sole">
        <geom contype="0" conaffinity="0" group="2" density="0" friction="0.8 0.005 0.0001"/>
      </default>
    </default>
    <motor ctrllimited="true"/>
  </default>
  <visual>
    <global offwidth="1280" offheight="720"/>
  </visual>
  <asset>
    <texture name="grid" type="2d" builtin="checker" rgb1="0.2 0.3 0.4" rgb2="0.3 0.4 0.5"
             width="512" height="512"/>
    <material name="grid" texture="grid" texrepeat="8 8" reflectance="0.1"/>
  </asset>
  <worldbody>
    <light pos="0 0 4" dir="0 0 -1" directional="true"/>
    <geom name="floor" type="plane" size="0 0 0.05" material="grid" friction="0.8 0.005 0.0001"
          contype="0" conaffinity="0"/>
{body}
  </worldbody>
  <contact>
{pairs}
  </contact>
  <actuator>
{actuators}
  </actuator>
  <keyframe>
    <key name="zero" qpos="{zero}"/>
    <key name="walk" qpos="{walk_q}"/>
  </keyframe>
</mujoco>
"""


def solve_walk_height(xml: str) -> float:
    """Pelvis height that puts the lowest sole corner of the walking posture on the floor."""
    import mujoco

    model = mujoco.MjModel.from_xml_string(xml)
    data = mujoco.MjData(model)
    key = model.key("walk").id
    mujoco.mj_resetDataKeyframe(model, data, key)
    mujoco.mj_kinematics(model, data)
    lowest = np.inf
    for side in ("left", "right"):
        for k in range(len(sole_corner_spheres())):
            g = model.geom(f"{side}_sole{k}").id
            lowest = min(lowest, data.geom_xpos[g][2] - model.geom_size[g][0])
    return float(data.qpos[2] - lowest)


def main(path: Path | None = None) -> Path:
    path = path or Path(__file__).with_name("valkyrie.xml")
    draft = xml_text()
    xml = xml_text(walk_pelvis_z=round(solve_walk_height(draft), 6))
    path.write_text(xml)
    return path


if __name__ == "__main__":
    print(main(Path(sys.argv[1]) if len(sys.argv) > 1 else None))
