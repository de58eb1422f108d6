"""The ellipse of the paper's eqs 1-3 and its conversions.

An ellipse is ``(u0, v0, a, b, theta)``: centre, semi-major ``a`` >= semi-minor ``b`` (px) and
the rotation angle ``theta`` (rad). A pixel ``(u, v)`` lies on it when (eqs 1-3)

    u_e =  (u - u0) cos(theta) + (v - v0) sin(theta)
    v_e = -(u - u0) sin(theta) + (v - v0) cos(theta)
    u_e^2 / a^2 + v_e^2 / b^2 = 1

so the major axis points along ``(cos theta, sin theta)`` in pixel coordinates (v down), and the
point at parameter ``t`` is ``c + a cos t (cos theta, sin theta) + b sin t (-sin theta, cos theta)``.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property, lru_cache
from typing import NamedTuple

import numpy as np

from station.rim import fit_loops
from station.rim.npfast import row_norms


def _wrap_angle(theta: float) -> float:
    """Ellipse angles are defined modulo pi: map to [-pi/2, pi/2)."""
    return float((theta + np.pi / 2) % np.pi - np.pi / 2)


@lru_cache(maxsize=64)
def _circle(n: int) -> tuple[np.ndarray, np.ndarray]:
    """cos t, sin t (n,) (read-only) at t = 2 pi k / n: :meth:`Ellipse.points` samples every
    candidate ellipse of a size with the same n."""
    t = np.arange(n) * (2 * np.pi / n)
    ct, st = np.cos(t), np.sin(t)
    ct.flags.writeable = st.flags.writeable = False
    return ct, st


class Feet(NamedTuple):
    """Foot points of N points on an ellipse (:meth:`Ellipse.feet`): d (N,) signed distance
    (positive outside); t (N,) foot parameter; ct, st (N,) its cos and sin; nx, ny (N,) the
    unit outward normal at the foot in the ellipse's own frame."""

    d: np.ndarray
    t: np.ndarray
    ct: np.ndarray
    st: np.ndarray
    nx: np.ndarray
    ny: np.ndarray


@dataclass(frozen=True)
class Ellipse:
    """center_px: (2,) (u0, v0); axes_px: (2,) (a, b) with a >= b > 0; angle_rad: theta."""

    center_px: np.ndarray
    axes_px: np.ndarray
    angle_rad: float

    def __post_init__(self):
        c = np.array(self.center_px, dtype=float).reshape(2)
        ax = np.array(self.axes_px, dtype=float).reshape(2)
        th = float(self.angle_rad)
        if ax[1] > ax[0]:  # keep a >= b: swap axes and turn by 90 degrees
            ax = ax[::-1].copy()
            th += np.pi / 2
        c.flags.writeable = False
        ax.flags.writeable = False
        object.__setattr__(self, "center_px", c)
        object.__setattr__(self, "axes_px", ax)
        object.__setattr__(self, "angle_rad", _wrap_angle(th))

    # --- construction / conversion ----------------------------------------------------------
    @classmethod
    def from_params(cls, p) -> "Ellipse":
        """From a (5,) array (cx, cy, a, b, theta)."""
        p = np.asarray(p, float)
        return cls(p[:2], np.abs(p[2:4]), p[4])

    @property
    def params(self) -> np.ndarray:
        """(5,) (cx, cy, a, b, theta), the order of ``RimDetection.ellipse_cov``."""
        return np.array([*self.center_px, *self.axes_px, self.angle_rad])

    def scaled(self, s: float) -> "Ellipse":
        """The same ellipse in an image scaled by ``s`` (pixel-centre convention kept)."""
        c = (self.center_px + 0.5) * s - 0.5
        return Ellipse(c, self.axes_px * s, self.angle_rad)

    def to_conic(self) -> np.ndarray:
        """(6,) (A, B, C, D, E, F) with A u^2 + B u v + C v^2 + D u + E v + F = 0, unit norm, A > 0."""
        (u0, v0), (a, b) = self.center_px, self.axes_px
        c, s = self.cos_sin
        A = c * c / a**2 + s * s / b**2
        C = s * s / a**2 + c * c / b**2
        B = 2 * c * s * (1 / a**2 - 1 / b**2)
        D = -2 * A * u0 - B * v0
        E = -B * u0 - 2 * C * v0
        F = A * u0**2 + B * u0 * v0 + C * v0**2 - 1
        q = np.array([A, B, C, D, E, F])
        return q / np.linalg.norm(q)

    def conic_matrix(self) -> np.ndarray:
        """(3,3) the symmetric conic C of :meth:`to_conic`: x^T C x = 0 for homogeneous points
        x = (u, v, 1) on the ellipse."""
        A, B, C, D, E, F = self.to_conic()
        return np.array([[A, B / 2, D / 2], [B / 2, C, E / 2], [D / 2, E / 2, F]])

    @classmethod
    def from_conic_matrix(cls, Q) -> "Ellipse":
        """Inverse of :meth:`conic_matrix` (any scale); ValueError if ``Q`` is not a real ellipse."""
        Q = np.asarray(Q, float)
        return cls.from_conic([Q[0, 0], 2 * Q[0, 1], Q[1, 1], 2 * Q[0, 2], 2 * Q[1, 2], Q[2, 2]])

    @classmethod
    def from_conic(cls, q) -> "Ellipse":
        """Inverse of :meth:`to_conic`; raises ValueError if ``q`` is not a real ellipse."""
        A, B, C, D, E, F = np.asarray(q, float)
        M = np.array([[A, B / 2], [B / 2, C]])
        det = np.linalg.det(M)
        if det <= 0:
            raise ValueError("conic is not an ellipse")
        center = np.linalg.solve(2 * M, [-D, -E])
        k = -(F + 0.5 * (D * center[0] + E * center[1]))  # value x^T M x = k on the curve
        w, V = np.linalg.eigh(M / k)
        if np.any(w <= 0):
            raise ValueError("conic is an imaginary ellipse")
        a, b = 1 / np.sqrt(w[0]), 1 / np.sqrt(w[1])  # smallest eigenvalue -> major axis
        return cls(center, (a, b), np.arctan2(V[1, 0], V[0, 0]))

    # --- sampling ---------------------------------------------------------------------------
    def point_at(self, t: np.ndarray) -> np.ndarray:
        """(N,) parameters -> (N,2) points."""
        t = np.asarray(t, float)
        return self.point_from_cos_sin(np.cos(t), np.sin(t))

    def point_from_cos_sin(self, ct: np.ndarray, st: np.ndarray) -> np.ndarray:
        """:meth:`point_at` from cos t and sin t (N,) (tables kept for a fixed set of t)."""
        a, b = self.axes_px
        c, s = self.cos_sin
        x, y = a * ct, b * st
        return np.stack([self.center_px[0] + c * x - s * y, self.center_px[1] + s * x + c * y], axis=1)

    def normal_at(self, t: np.ndarray) -> np.ndarray:
        """(N,) parameters -> (N,2) outward unit normals."""
        t = np.asarray(t, float)
        a, b = self.axes_px
        c, s = self.cos_sin
        nx, ny = b * np.cos(t), a * np.sin(t)  # ∝ (cos t / a, sin t / b)
        n = np.stack([c * nx - s * ny, s * nx + c * ny], axis=1)
        return n / row_norms(n)[:, None]

    def scaled_points(self, factors, t: np.ndarray) -> np.ndarray:
        """(F*N,2) the points at parameters t (N,) of the concentric similar ellipses with axes
        scaled by each of ``factors`` (F,) > 0, ellipse after ellipse: the points of
        ``Ellipse(c, axes * f, angle).point_at(t)`` for each f, by the same arithmetic, with
        one cos and sin of t for all of them."""
        same = Ellipse(self.center_px, self.axes_px, self.angle_rad)  # the scaled ones' angle
        axes = self.axes_px * np.asarray(factors, float)[:, None]       # (F,2)
        t = np.asarray(t, float)
        x, y = axes[:, :1] * np.cos(t), axes[:, 1:] * np.sin(t)          # (F,N)
        c, s = same.cos_sin
        return np.stack([(self.center_px[0] + c * x - s * y).ravel(),
                         (self.center_px[1] + s * x + c * y).ravel()], axis=1)

    def points(self, n: int) -> np.ndarray:
        """(n,2) points at equal parameter steps, t = 2 pi k / n."""
        return self.point_from_cos_sin(*_circle(n))

    def perimeter(self) -> float:
        """Ramanujan's approximation (relative error < 1e-9 for a/b < 1.5)."""
        a, b = self.axes_px
        h = ((a - b) / (a + b)) ** 2
        return float(np.pi * (a + b) * (1 + 3 * h / (10 + np.sqrt(4 - 3 * h))))

    # --- geometry ---------------------------------------------------------------------------
    def to_local(self, pts: np.ndarray) -> np.ndarray:
        """(N,2) pixels -> (N,2) (u_e, v_e) of eqs 2-3."""
        return np.stack(self.local_xy(pts), axis=1)

    def local_xy(self, pts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(N,2) pixels -> u_e (N,), v_e (N,) of eqs 2-3: :meth:`to_local`'s columns, without
        the (N,2) stack for callers that use them apart."""
        pts = np.asarray(pts, float)
        c, s = self.cos_sin
        # column by column: contiguous temporaries, 2x faster than from the (N,2) difference
        du, dv = pts[:, 0] - self.center_px[0], pts[:, 1] - self.center_px[1]
        return du * c + dv * s, -du * s + dv * c

    @cached_property
    def cos_sin(self) -> tuple[float, float]:
        """cos and sin of the angle, once per ellipse (many callers transform points)."""
        return np.cos(self.angle_rad), np.sin(self.angle_rad)

    def radius_ratio(self, pts: np.ndarray) -> np.ndarray:
        """(N,) sqrt(u_e^2/a^2 + v_e^2/b^2): 1 on the curve, the scale of the similar concentric ellipse."""
        le = self.to_local(pts)
        a, b = self.axes_px
        return np.sqrt((le[:, 0] / a) ** 2 + (le[:, 1] / b) ** 2)

    def distance(self, pts: np.ndarray, iterations: int = 4, t0: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Signed orthogonal distance (positive outside) and foot parameter t, both (N,).

        Newton's method on the foot-point parameter from the angle of the point (or from
        ``t0`` (N,), e.g. the feet on a nearby ellipse); exact to 1e-10 px for points within a
        few px of an ellipse with a/b < 2.
        """
        feet = self.feet(pts, iterations, t0)
        return feet.d, feet.t

    def feet(self, pts: np.ndarray, iterations: int = 4, t0: np.ndarray | None = None) -> "Feet":
        """:meth:`distance` with what it computed at the feet on the way (:class:`Feet`), for a
        fit's Jacobian at the same feet (no second cos / sin of t)."""
        pts = np.asarray(pts, float)
        d, t, ct, st, nx, ny = (np.empty(len(pts)) for _ in range(6))
        t0 = t if t0 is None else np.ascontiguousarray(t0, dtype=float)  # (unread without a start)
        fit_loops.feet(np.ascontiguousarray(pts[:, 0]), np.ascontiguousarray(pts[:, 1]), self.params, t0,
                       iterations, t0 is not t, d, t, ct, st, nx, ny)
        return Feet(d, t, ct, st, nx, ny)

    def to_dict(self) -> dict:
        return {"center_px": [float(x) for x in self.center_px],
                "axes_px": [float(x) for x in self.axes_px],
                "angle_deg": float(np.degrees(self.angle_rad))}
