"""Alignment angles from the four wheels' centres and outward spin axes.

Formulas and signs: docs/conventions.md ("Car frame", "Alignment angles"). Inputs are in the
station frame; wheels in the order of ``calibration.station_frame.WHEELS``.
"""

from __future__ import annotations

import numpy as np

from calibration.station_frame import SIDE, WHEELS
from station.result import ANGLE_NAMES


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v)


def paper_car_frame(centers: dict[str, np.ndarray]) -> np.ndarray:
    """The paper's car frame: x' wheel 3 -> 4 (RL -> RR), y' wheel 3 -> 2 (RL -> FL), z' = x' x y'.

    Returns R_station_car (3,3) with columns x_hat, y_hat, z_hat (orthonormalised).
    """
    x = _unit(centers["RR"] - centers["RL"])
    z = _unit(np.cross(x, centers["FL"] - centers["RL"]))
    y = np.cross(z, x)
    return np.stack([x, y, z], axis=1)


RUNWAY_UP = np.array([0.0, 0.0, 1.0])  # the station frame's z: normal to the runways the wheels stand on


def alignment_frames(C: np.ndarray) -> np.ndarray:
    """Frames of the signed angles for K sets of wheel centres C (K,4,3) (WHEELS order): z the
    runways' normal (the station frame's z, as the calibration box on its fixtures defines it),
    y along the geometric centreline laid on the runways. Returns R_station_align (K,3,3),
    columns x_a (right), y_a (forward), z_a (up).

    Camber is read against the plane the wheels stand on. The paper's z' (normal to the plane
    of the wheel centres) moves with each centre's height: a lip centred 0.5 mm off its hub, or
    one tyre a few millimetres lower, rolls that plane and shifts the left and right cambers
    apart (bench/camber_reference.py)."""
    line = (C[:, 0] + C[:, 1]) / 2 - (C[:, 2] + C[:, 3]) / 2          # the geometric centreline (K,3)
    y = line - np.outer(line @ RUNWAY_UP, RUNWAY_UP)                   # laid on the runways
    y /= np.linalg.norm(y, axis=-1, keepdims=True)
    return np.stack([np.cross(y, RUNWAY_UP), y, np.broadcast_to(RUNWAY_UP, y.shape)], axis=2)


def alignment_frame(centers: dict[str, np.ndarray]) -> np.ndarray:
    """:func:`alignment_frames` of one set of centres {W: (3,)}: (3,3)."""
    return alignment_frames(np.stack([np.asarray(centers[w], float) for w in WHEELS])[None])[0]


def toe_camber_rad(R_a: np.ndarray, A: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(toe (K,4), camber (K,4)) in radians of the wheels' outward axes A (K,4,3) (WHEELS order,
    any length) in the alignment frames R_a (K,3,3)."""
    a = A / np.linalg.norm(A, axis=-1, keepdims=True)
    wx, wy, wz = np.moveaxis(np.einsum("kwi,kij->kwj", a, R_a), 2, 0)  # (K,4) each, alignment frame
    side = np.array([SIDE[w] for w in WHEELS])
    return np.arctan2(wy, side * wx), np.arctan2(-wz, side * wx)


def compute_angles(centers: dict[str, np.ndarray], axes: dict[str, np.ndarray]) -> dict:
    """All signed angles (degrees) and distances (m) from centres (3,) and outward axes (3,).

    Returns a dict with ``wheels[W] = {toe_deg, camber_deg, [toe_thrust_deg]}``, ``axles``,
    ``thrust_deg``, ``wheelbase_m``, ``centreline_deg`` (geometric centreline vs the paper's
    y_hat) and the frames used.
    """
    centers = {w: np.asarray(centers[w], float) for w in WHEELS}
    R_a = alignment_frame(centers)
    t, c = toe_camber_rad(R_a[None], np.stack([np.asarray(axes[w], float) for w in WHEELS])[None])
    toe = {w: float(t[0, i]) for i, w in enumerate(WHEELS)}
    camber = {w: float(c[0, i]) for i, w in enumerate(WHEELS)}
    thrust = (toe["RL"] - toe["RR"]) / 2
    local = {w: R_a.T @ (centers[w] - centers["RL"]) for w in WHEELS}
    wheels = {}
    for w in WHEELS:
        wheels[w] = {"toe_deg": np.degrees(toe[w]), "camber_deg": np.degrees(camber[w])}
        if w.startswith("F"):
            wheels[w]["toe_thrust_deg"] = np.degrees(toe[w] + SIDE[w] * thrust)
    axles = {}
    for axle, (left, right) in (("front", ("FL", "FR")), ("rear", ("RL", "RR"))):
        d = local[right] - local[left]
        axles[axle] = {"total_toe_deg": np.degrees(toe[left] + toe[right]),
                       "setback_m": float(d[1]), "setback_deg": float(np.degrees(np.arctan2(d[1], d[0]))),
                       "track_m": float(d[0])}
    y_paper = paper_car_frame(centers)[:, 1]
    return {
        "wheels": wheels,
        "axles": axles,
        "thrust_deg": float(np.degrees(thrust)),
        "wheelbase_m": {"left": float(local["FL"][1] - local["RL"][1]),
                        "right": float(local["FR"][1] - local["RR"][1])},
        "centreline_deg": float(np.degrees(np.arctan2(y_paper @ R_a[:, 0], y_paper @ R_a[:, 1]))),
        "R_station_align": R_a,
    }


def angle_vector(angles: dict) -> np.ndarray:
    """The angles of ANGLE_NAMES (degrees) as a (11,) vector."""
    out = []
    for name in ANGLE_NAMES:
        head, kind = name.split(".") if "." in name else (name, "")
        if head in WHEELS:
            out.append(angles["wheels"][head][f"{kind}_deg"])
        elif head in ("front", "rear"):
            out.append(angles["axles"][head]["total_toe_deg"])
        else:
            out.append(angles["thrust_deg"])
    return np.array(out, float)


def angle_vectors(C: np.ndarray, A: np.ndarray) -> np.ndarray:
    """``angle_vector(compute_angles(...))`` of K configurations at once: centres C (K,4,3) and
    outward axes A (K,4,3), wheels in WHEELS order. Returns (K,11) degrees."""
    toe, camber = toe_camber_rad(alignment_frames(C), A)
    out = np.stack([toe[:, 0], camber[:, 0], toe[:, 1], camber[:, 1], toe[:, 2], camber[:, 2],
                    toe[:, 3], camber[:, 3], toe[:, 0] + toe[:, 1], toe[:, 2] + toe[:, 3],
                    (toe[:, 2] - toe[:, 3]) / 2], axis=1)
    return np.degrees(out)


def angle_covariance(centers: dict, axes: dict, cov_center: dict, cov_axis: dict,
                     step: float = 1e-7) -> np.ndarray:
    """Covariance (11,11) in deg^2 of ``angle_vector`` by first-order propagation.

    cov_center[W], cov_axis[W]: (3,3) covariances of each wheel's centre (m^2) and axis.
    The Jacobian is taken numerically (central differences, all 48 perturbed configurations in
    one :func:`angle_vectors` call); inputs are independent per wheel.
    """
    c0 = np.stack([np.asarray(centers[w], float) for w in WHEELS])
    a0 = np.stack([_unit(np.asarray(axes[w], float)) for w in WHEELS])
    d = step * np.eye(3)
    C, A = [], []
    for i in range(4):
        for which in (0, 1):                   # the centre, then the axis, of wheel i
            for sign in (1.0, -1.0):
                dc = np.zeros((3, 4, 3))
                dc[:, i, :] = sign * d
                C.append(c0 + dc * (which == 0))           # (3,4,3): the three coordinates
                A.append(a0 + dc * (which == 1))
    V = angle_vectors(np.concatenate(C), np.concatenate(A)).reshape(4, 2, 2, 3, -1)  # wheel, which, sign, k
    J = (V[:, :, 0] - V[:, :, 1]) / (2 * step)                                        # (4,2,3,11)
    cov = np.zeros((len(ANGLE_NAMES),) * 2)
    for i, w in enumerate(WHEELS):
        for which, S in ((0, cov_center[w]), (1, cov_axis[w])):
            Jw = J[i, which].T                                                           # (11,3)
            cov += Jw @ np.asarray(S, float) @ Jw.T
    return cov


def paper_front_angles(centers: dict[str, np.ndarray], axes: dict[str, np.ndarray]) -> dict:
    """The paper's unsigned camber and toe of the front wheels, eqs 39-42 (degrees).

    Wheels 1 = FR, 2 = FL, 3 = RL, 4 = RR. The paper's w vectors are the spin axes; the
    formulas compare the projection of w_1 (w_2) with w_4 (w_3), all taken here as the outward
    axes made to point along +x_hat so that the angles are the small deviations, as in Fig. 11.
    """
    R = paper_car_frame({w: np.asarray(centers[w], float) for w in WHEELS})
    x_hat, y_hat, z_hat = R[:, 0], R[:, 1], R[:, 2]

    def along_x(w):  # the paper's Fig. 11 draws every w along +x_hat
        v = _unit(np.asarray(axes[w], float))
        return v if v @ x_hat >= 0 else -v

    w1, w2, w3, w4 = along_x("FR"), along_x("FL"), along_x("RL"), along_x("RR")

    def angle(a, b):
        return float(np.degrees(np.arccos(np.clip(a @ b / (np.linalg.norm(a) * np.linalg.norm(b)), -1, 1))))

    def proj(v, n):  # projection onto the plane with normal n
        return v - n * (v @ n)

    return {
        "camber_1_deg": angle(proj(w1, y_hat), w4),   # eq 39: w_1xz vs w_4
        "camber_2_deg": angle(proj(w2, y_hat), w3),   # eq 40: w_2xz vs w_3
        "toe_1_deg": angle(proj(w1, z_hat), w4),      # eq 41: w_1xy vs w_4
        "toe_2_deg": angle(proj(w2, z_hat), w3),      # eq 42: w_2xy vs w_3
    }
