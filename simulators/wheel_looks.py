"""A wheel's looks beyond its geometry (simulators.scene.Appearance): brake dust and dirt on
the lip, a protector rib on the tyre, the arch's shadow over the wheel.

Points are in the wheel frame (docs/conventions.md): ``theta`` (N,) rad from the u axis about
w, ``r`` (N,) m from the axis, ``pu``, ``pv`` (N,) m. Everything is a function of the point and
the Appearance's numbers: deterministic, vectorised.
"""

from __future__ import annotations

import numpy as np

from simulators.scene import Appearance


def dust_weight(theta: np.ndarray, look: Appearance) -> np.ndarray:
    """(N,) float32 0..look.dust: how much of the lip's colour the brake dust replaces, a
    raised cosine over ``dust_span_rad`` centred on ``dust_center_rad`` (0 outside it)."""
    off = np.abs(np.mod(theta - look.dust_center_rad + np.pi, 2 * np.pi) - np.pi)
    x = np.clip(off / (0.5 * look.dust_span_rad), 0.0, 1.0)
    return (look.dust * 0.5 * (1.0 + np.cos(np.pi * x))).astype(np.float32)


def dirt_blotches(theta: np.ndarray, r: np.ndarray, look: Appearance) -> np.ndarray:
    """(N,) float32 0..1: blotches of dirt on the lip, 1 inside a blotch, about 15-50 mm across
    along the lip; a sum of six waves of random integer order round the wheel (seamless at
    theta = +-pi) and random radial frequency, from ``dirt_seed``, through a soft threshold."""
    rng = np.random.default_rng([look.dirt_seed, 4242])
    order = rng.integers(12, 45, 6)
    radial = rng.uniform(-150.0, 150.0, 6)          # rad per m across the lip
    phase = rng.uniform(0, 2 * np.pi, 6)
    noise = np.zeros(np.shape(theta), np.float64)
    for k in range(6):
        noise += np.sin(order[k] * theta + radial[k] * r + phase[k])
    noise /= np.sqrt(3.0)                           # unit variance
    return np.clip((noise - 0.3) / 0.6, 0.0, 1.0).astype(np.float32)


def ridge_points(profile_outer: np.ndarray, look: Appearance) -> tuple[np.ndarray, list[int]]:
    """The tyre's outer profile (P,2) of (r, w) points with a protector rib inserted: a
    trapezoid standing ``ridge_height_m`` off the sidewall (in +w), its feet ``ridge_offset_m``
    and ``ridge_offset_m + ridge_width_m`` beyond the flange edge, its top 40 % of its width.
    Returns the new outline and the indices of its segments that are the rib's."""
    rr = profile_outer[0, 0]
    r_feet = rr + look.ridge_offset_m + np.array([0.0, 0.3, 0.7, 1.0]) * look.ridge_width_m
    k = int(np.searchsorted(profile_outer[:, 0], r_feet[0]))      # the rib sits on segment k-1 -> k
    if not (1 <= k < len(profile_outer) and r_feet[-1] < profile_outer[k, 0]):
        raise ValueError("the protector rib must sit on one segment of the tyre's sidewall")
    w_side = np.interp(r_feet, profile_outer[:, 0], profile_outer[:, 1])
    rib = np.stack([r_feet, w_side + np.array([0.0, 1.0, 1.0, 0.0]) * look.ridge_height_m], axis=1)
    out = np.vstack([profile_outer[:k], rib, profile_outer[k:]])
    return out, [k, k + 1, k + 2]


def arch_shadow(pu: np.ndarray, pv: np.ndarray, up_uv: np.ndarray, rim_radius_m: float,
                look: Appearance) -> np.ndarray:
    """(N,) float32 share of the key light reaching each point under the arch's shadow: 0 above
    the boundary (the line ``shadow_height`` x rim radius above the centre, across the wheel's
    up direction ``up_uv`` (2,) turned by ``shadow_tilt_rad``), 1 below, linear over
    ``shadow_soft_m``."""
    a = np.arctan2(up_uv[1], up_uv[0]) + look.shadow_tilt_rad
    s = pu * np.cos(a) + pv * np.sin(a) - look.shadow_height * rim_radius_m
    return np.clip(0.5 - s / look.shadow_soft_m, 0.0, 1.0).astype(np.float32)
