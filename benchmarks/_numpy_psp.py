"""A vectorised NumPy implementation of the same PSP step, as the benchmark's baseline.

Same algorithm as ``jaxloco.planner.psp.plan_step`` (Eq. 44, Eq. 38 via growth factors,
Eq. 35, Eq. 45, Eq. 3-4 and the stride bounds) and the same outputs, written the way one
would in NumPy: whole-array operations, masks instead of branches. The benchmark checks
that it agrees with the JAX planner before timing it.
"""

from __future__ import annotations

import numpy as np


def plan_step_numpy(state: np.ndarray, action: np.ndarray, p) -> dict[str, np.ndarray]:
    dt = state.dtype
    y0, xd0, yd0 = state[:, 0], state[:, 1], state[:, 2]
    px, v2, ydn = action[:, 0], action[:, 1], action[:, 2]
    w = dt.type(np.sqrt(p.g / p.h))
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        has_switch = np.abs(px) > 1e-6
        ps = np.where(has_switch, px, 1)
        x_sw = 0.5 * ps + (v2 * v2 - xd0 * xd0) / (2 * w * w * ps)
        sign = np.where(xd0 >= 0, 1, -1).astype(dt)
        xd_sw = sign * np.sqrt(w * w * (x_sw - ps) ** 2 + v2 * v2)
        num1, den1 = w * x_sw + xd_sw, xd0
        sw_ok = has_switch & (num1 > 1e-12) & (den1 > 1e-12)
        g_sw = np.where(sw_ok, num1 / den1, 1)
        num2, den2 = v2, w * (x_sw - ps) + xd_sw
        ap_ok = has_switch & (num2 > 1e-12) & (den2 > 1e-12)
        g_ap = np.where(ap_ok, num2 / den2, 1)
        t_sw = np.log(g_sw) / w
        t_ap = np.log(g_ap) / w
        c1, s1 = 0.5 * (g_sw + 1 / g_sw), 0.5 * (g_sw - 1 / g_sw)
        y_sw = y0 * c1 + yd0 / w * s1
        yd_sw = y0 * w * s1 + yd0 * c1
        c2, s2 = 0.5 * (g_ap + 1 / g_ap), 0.5 * (g_ap - 1 / g_ap)
        lat_ok = ap_ok & (np.abs(s2) > 1e-9)
        p_y = y_sw + (yd_sw * c2 - ydn) / (w * np.where(lat_ok, s2, 1))
        r0 = y_sw - p_y
        y_ap = p_y + r0 * c2 + yd_sw / w * s2
        yd_ap = r0 * w * s2 + yd_sw * c2
        ok = sw_ok & lat_ok
        p_y = np.where(ok, p_y, 0)
        next_state = np.where(ok[:, None], np.stack([-(y_ap - p_y), v2, -yd_ap], -1), 0)
        stride = np.sqrt(px * px + p_y * p_y)
        terminal = (
            ~ok
            | (t_sw <= p.t_switch_min)
            | (t_ap <= p.t_apex_min)
            | (p_y <= p.p_y_min)
            | (p_y >= p.p_y_max)
            | (stride < p.stride_min)
            | (stride > p.stride_max)
        )
        reward = -(
            p.reward_weight_xd * (p.xd_apex_nominal - v2) ** 2
            + p.reward_weight_p_y * (p.p_y_nominal - p_y) ** 2
            + p.reward_weight_yd * ydn**2
        )
        reward = np.where(terminal, p.terminal_reward, reward).astype(dt)
    return {
        "x_switch": x_sw,
        "xd_switch": xd_sw,
        "y_switch": y_sw,
        "yd_switch": yd_sw,
        "t_switch": np.where(sw_ok, t_sw, 0),
        "t_apex": np.where(ap_ok, t_ap, 0),
        "p_y": p_y,
        "next_state": next_state,
        "reward": reward,
        "terminal": terminal,
    }
