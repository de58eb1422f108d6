"""Ray casting of one wheel: rim flange, barrel, spokes, hub, brake, tyre, all exact.

The wheel is a stack of surfaces of revolution about its spin axis plus non-symmetric masks
(spokes, lug holes, caliper). Geometry in the wheel frame (docs/conventions.md): origin at the
rim-flange circle centre, w = outward spin axis, r = distance from the axis.

- flange: the plane w = 0 for r in [rim_radius - flange_width, rim_radius]. Its outer edge, the
  circle r = rim_radius, w = 0, is the measured feature; it is intersected exactly.
- barrel: the cylinder r = rim_radius - flange_width between the flange and the spoke face.
- spoke face: the plane w = -rim_face_depth, spokes by angle, with gaps through which the
  brake disc, the caliper and the dark wheel cavity behind show.
- hub: a disc standing a little proud of the spoke face, with lug-nut holes.
- tyre: a closed profile of cone frusta (outer sidewall bulging ``sidewall_bulge_m`` beyond
  the flange plane, so oblique views lose part of the flange behind it, tread, inner sidewall)
  and the dark inner face. Normals are interpolated along the profile (smooth shading); a
  protector rib (``Appearance.ridge_height_m``) is three more segments, flat-shaded.

The scene's Appearance (simulators/scene.py) adds the rim's finish (Phong, a Fresnel mirror of
the workshop), brake dust and dirt on the lip, the lettering's band and the arch's shadow
(simulators/wheel_looks.py); its defaults leave the random vehicles' images as they are.

Every part is a plane annulus or a cone frustum ``r = A + B t`` along the ray: one linear or
quadratic equation per ray, solved in float64.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from simulators.scene import Appearance, Lighting
from simulators.shading import LABEL_WHEEL, Hits, mirror_reflection, shade
from simulators.vehicle import WheelGeometry
from simulators.wheel_looks import arch_shadow, dirt_blotches, dust_weight, ridge_points

# part numbers (label = LABEL_WHEEL + 40 * wheel index + part)
FLANGE, BARREL, SPOKE, RING, HUB, HUB_SIDE, LUG, CALIPER, DISC, CAVITY, INNER = range(11)
TYRE_TEXT = 13
RIDGE = 14   # a protector rib on the tyre (Appearance.ridge_height_m)
N_OUTER = 4  # segments of the tyre's outer sidewall profile (without a rib)
TYRE = 12  # one label for the whole tyre (its shading is smooth across profile segments)


@dataclass(frozen=True)
class Finish:
    """Surface finish of a vehicle's wheels (derived deterministically from the geometry)."""

    spoke_albedo: float
    flange_specular: float
    spoke_specular: float
    caliper_albedo: float


def wheel_finish(g: WheelGeometry) -> Finish:
    """Vary finishes between vehicles without a new random stream: hash the geometry."""
    h = np.modf(np.sin(np.array([1.0, 2.0, 3.0, 4.0]) * (g.rim_albedo * 91.7 + g.spoke_count * 7.3
                                                          + g.hub_radius_m * 311.0)) * 43758.5453)[0]
    h = np.abs(h)
    return Finish(spoke_albedo=float(np.clip(g.rim_albedo * (0.45 + 0.9 * h[0]), 0.08, 0.95)),
                  flange_specular=float(0.2 + 0.8 * h[1]), spoke_specular=float(0.1 + 0.9 * h[2]),
                  caliper_albedo=float(0.12 + 0.35 * h[3]))


def tyre_profile(g: WheelGeometry, look: Appearance | None = None) -> tuple[np.ndarray, int, list[int]]:
    """(P,2) closed tyre outline (r, w) from the outer bead (rim_radius, 0) round to the inner
    bead; the number of its outer sidewall's segments; the indices of the protector rib's
    segments (none unless ``look.ridge_height_m``)."""
    rr, tr, b, W = g.rim_radius_m, g.tyre_radius_m, g.sidewall_bulge_m, g.tyre_width_m
    S = tr - rr
    shoulder = min(0.035, 0.2 * W)
    outer = np.array([  # N_OUTER segments
        [rr, 0.0], [rr + 0.03 * S, 0.6 * b], [rr + 0.3 * S, b], [tr - 0.1 * S, 0.6 * b - 0.3 * shoulder],
        [tr, b - shoulder]])
    rib = []
    if look is not None and look.ridge_height_m > 0:
        outer, rib = ridge_points(outer, look)
    w_mid = b - W / 2
    inner = outer[::-1].copy()
    inner[:, 1] = 2 * w_mid - inner[:, 1]
    return np.vstack([outer, inner]), len(outer) - 1, rib


def _profile_normals(profile: np.ndarray) -> np.ndarray:
    """(P,2) vertex normals (n_r, n_w) of the outline, outward from the tyre's inside."""
    seg = np.diff(profile, axis=0)
    n = np.stack([-seg[:, 1], seg[:, 0]], axis=1)
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    vn = np.vstack([n[:1], n[:-1] + n[1:], n[-1:]])
    return vn / np.linalg.norm(vn, axis=1, keepdims=True)


class _Rays:
    """Rays in the wheel frame with the terms shared by every part; parts work on index subsets.

    o: (3,) origin; du, dv, dw: (N,) unit direction components, all in the wheel frame.
    """

    def __init__(self, o_w: np.ndarray, dirs: np.ndarray, R: np.ndarray):
        """o_w: (3,) wheel frame; dirs: (N,3) station frame; R: R_station_wheel (3,3)."""
        self.o = o_w
        # d_wheel = R^T d, one component at a time (no BLAS, no (N,3) temporaries)
        self.du, self.dv, self.dw = (dirs[:, 0] * R[0, k] + dirs[:, 1] * R[1, k] + dirs[:, 2] * R[2, k]
                                     for k in range(3))
        self.a2 = self.du * self.du + self.dv * self.dv
        self.b1 = o_w[0] * self.du + o_w[1] * self.dv
        self.c0 = o_w[0] ** 2 + o_w[1] ** 2
        with np.errstate(divide="ignore", invalid="ignore"):
            self.inv_dw = 1.0 / self.dw
            self.tc = -self.b1 / self.a2          # t of the closest approach to the axis
        self.b2 = 2.0 * self.b1

    def r2_at(self, sub, t):
        return self.c0 + t * (2.0 * self.b1[sub] + t * self.a2[sub])

    def subset(self, sub: np.ndarray) -> "_Rays":
        """The same rays restricted to ``sub`` (avoids repeated gathers)."""
        out = _Rays.__new__(_Rays)
        out.o, out.c0 = self.o, self.c0
        for name in ("du", "dv", "dw", "a2", "b1", "b2", "tc", "inv_dw"):
            setattr(out, name, getattr(self, name)[sub])
        return out

    def reaching(self, sub: np.ndarray, best_t: np.ndarray, w_lo: float, w_hi: float,
                 r_lo: float, r_hi: float) -> np.ndarray:
        """The rays of ``sub`` that pass through the region w_lo<=w<=w_hi, r_lo<=r<=r_hi before
        their current nearest hit (a conservative cull: r along a ray is convex in t)."""
        inv = self.inv_dw[sub]
        with np.errstate(invalid="ignore"):
            ta = (w_lo - self.o[2]) * inv
            tb = (w_hi - self.o[2]) * inv
        t0 = np.maximum(np.minimum(ta, tb), 0.0)
        t1 = np.minimum(np.maximum(ta, tb), best_t[sub])
        keep = np.flatnonzero(t1 >= t0)           # cheap first stage: slab before the nearest hit
        sub, t0, t1 = sub[keep], t0[keep], t1[keep]
        a2 = self.a2[sub]
        b2 = self.b2[sub]
        ts = np.minimum(np.maximum(self.tc[sub], t0), t1)   # closest approach to the axis
        with np.errstate(invalid="ignore"):
            r2_0 = t0 * (b2 + t0 * a2)
            r2_1 = t1 * (b2 + t1 * a2)
            r2_s = ts * (b2 + ts * a2)
            keep = (r2_s <= r_hi * r_hi * (1 + 1e-9) - self.c0) & (
                np.maximum(r2_0, r2_1) >= r_lo * r_lo * (1 - 1e-9) - self.c0)
        return sub[keep]

    def plane(self, sub: np.ndarray, w0: float, r_lo: float, r_hi: float):
        """Hits of the annulus w = w0, r_lo <= r <= r_hi: (t, r2) over sub; misses t = inf."""
        t = (w0 - self.o[2]) * self.inv_dw[sub]
        r2 = self.r2_at(sub, t)
        ok = (t > 1e-9) & (r2 >= r_lo * r_lo) & (r2 <= r_hi * r_hi)
        return np.where(ok, t, np.inf), r2

    def cone(self, sub: np.ndarray, r0: float, w0: float, r1: float, w1: float):
        """Nearest hit (t, s) over sub of the frustum between profile points (r0,w0)-(r1,w1)."""
        dw_seg = w1 - w0
        k = (r1 - r0) / dw_seg
        A = r0 + k * (self.o[2] - w0)
        dw = self.dw[sub]
        B = k * dw
        a = self.a2[sub] - B * B
        hb = self.b1[sub] - A * B
        c = self.c0 - A * A
        disc = hb * hb - a * c
        with np.errstate(invalid="ignore", divide="ignore"):
            sq = np.sqrt(np.maximum(disc, 0.0))
            q = -(hb + np.copysign(sq, hb))
            roots = (q / a, c / q)
        best_t = np.full(len(a), np.inf)
        best_s = np.zeros(len(a))
        for t in roots:
            with np.errstate(invalid="ignore"):
                s = (self.o[2] + t * dw - w0) / dw_seg
                ok = (disc >= 0) & (t > 1e-9) & (s >= 0) & (s <= 1) & (A + B * t >= 0) & (t < best_t)
            best_t = np.where(ok, t, best_t)
            best_s = np.where(ok, s, best_s)
        return best_t, best_s


def trace_wheel(o: np.ndarray, d: np.ndarray, idx: np.ndarray, hits: Hits, lighting: Lighting,
                center: np.ndarray, R_station_wheel: np.ndarray, g: WheelGeometry, wheel_index: int,
                caliper_angle: float, look: Appearance = Appearance()) -> None:
    """Intersect rays d[idx] (M,3) from o with one wheel and store the nearer hits in ``hits``.

    caliper_angle: angle (rad, in the wheel's u-v plane) of the brake caliper, which does not
    turn with the wheel. look: the scenario's finish, dust, dirt, tyre and shadow.
    """
    if idx.size == 0:
        return
    # rays already stopped before the wheel's bounding sphere cannot reach it
    bound = np.hypot(g.tyre_radius_m, g.tyre_width_m)
    idx = idx[hits.t[idx] > np.linalg.norm(o - center) - bound]
    if idx.size == 0:
        return
    R = R_station_wheel
    rays = _Rays(R.T @ (o - center), d[idx], R)
    n = idx.size
    r_in = g.rim_radius_m - g.flange_width_m
    D = g.rim_face_depth_m
    hub_h = min(0.015, 0.5 * D)
    profile, n_outer, rib = tyre_profile(g, look)
    best_t = hits.t[idx].copy()
    part = np.full(n, -1, np.int32)
    aux = np.zeros(n)  # profile parameter for the tyre, r^2 or a flag for planes
    first = rays.reaching(np.arange(n), best_t, profile[:, 1].min(), profile[:, 1].max(),
                          0.0, g.tyre_radius_m)
    if first.size == 0:
        return
    # from here on, work only on the rays that can reach the wheel
    idx, rays, best_t = idx[first], rays.subset(first), best_t[first]
    n = idx.size
    part = np.full(n, -1, np.int32)
    aux = np.zeros(n)
    everything = np.arange(n)

    def offer(sub, t, p, a=None):
        win = t < best_t[sub]
        wi = sub[win]
        best_t[wi] = t[win]
        part[wi] = p
        if a is not None:
            aux[wi] = a[win]

    # rim first (flange: the measured circle is its outer edge; barrel, hub, spokes, brake):
    # its hits then cull the tyre segments behind them
    rim = rays.reaching(everything, best_t, -D - 0.08, 0.0, 0.0, r_in + 1e-3)
    sub = rays.reaching(everything, best_t, -1e-9, 1e-9, r_in, g.rim_radius_m)
    t, r2 = rays.plane(sub, 0.0, r_in, g.rim_radius_m)
    offer(sub, t, FLANGE, r2)
    if rim.size:
        t, _ = rays.cone(rim, r_in, 0.0, r_in, -D)
        offer(rim, t, BARREL)
        t, r2 = rays.plane(rim, -D + hub_h, 0.0, g.hub_radius_m)
        offer(rim, t, HUB, r2)
        t, _ = rays.cone(rim, g.hub_radius_m, -D, g.hub_radius_m, -D + hub_h)
        offer(rim, t, HUB_SIDE)
        # spoke face with angular gaps
        t, r2 = rays.plane(rim, -D, g.hub_radius_m, r_in)
        hit = np.flatnonzero(t < best_t[rim])
        sub, t, r2 = rim[hit], t[hit], r2[hit]
        ring_w = min(0.012, 0.15 * (r_in - g.hub_radius_m))
        theta = np.arctan2(rays.o[1] + t * rays.dv[sub], rays.o[0] + t * rays.du[sub])
        f = np.mod(theta * g.spoke_count / (2 * np.pi) + g.spoke_width_frac / 2, 1.0)
        ring = (r2 >= (r_in - ring_w) ** 2) | (r2 <= (g.hub_radius_m + 0.012) ** 2)
        spoke = (f < g.spoke_width_frac) | ring
        offer(sub, np.where(spoke, t, np.inf), SPOKE, np.where(ring, -1.0, 1.0))
        # behind the spokes: caliper (fixed), brake disc, dark cavity
        back = rays.reaching(rim, best_t, -D - 0.075, -D - 0.015, 0.0, r_in + 1e-3)
        t, r2 = rays.plane(back, -D - 0.02, 0.55 * r_in, 0.92 * r_in)
        hit = np.flatnonzero(t < best_t[back])
        ang = np.arctan2(rays.o[1] + t[hit] * rays.dv[back[hit]], rays.o[0] + t[hit] * rays.du[back[hit]])
        dth = np.abs(np.mod(ang - caliper_angle + np.pi, 2 * np.pi) - np.pi)
        offer(back[hit], np.where(dth < 0.45, t[hit], np.inf), CALIPER)
        t, r2 = rays.plane(back, -D - 0.035, g.hub_radius_m, 0.85 * r_in)
        offer(back, t, DISC, r2)
        t, _ = rays.plane(back, -D - 0.07, 0.0, r_in + 1e-3)
        offer(back, t, CAVITY)

    # tyre: only rays that pass through its annulus before their nearest hit so far
    tyre_rays = rays.reaching(everything, best_t, profile[:, 1].min(), profile[:, 1].max(),
                              g.rim_radius_m, g.tyre_radius_m)
    for k in range(len(profile) - 1):   # outer sidewall, tread, inner sidewall
        (r0, w0), (r1, w1) = profile[k], profile[k + 1]
        sub = rays.reaching(tyre_rays, best_t, min(w0, w1), max(w0, w1), min(r0, r1), max(r0, r1))
        if sub.size == 0:
            continue
        if abs(w1 - w0) < 1e-12:
            t, r2 = rays.plane(sub, w0, min(r0, r1), max(r0, r1))
            s = (np.sqrt(r2) - r0) / (r1 - r0)
        else:
            t, s = rays.cone(sub, r0, w0, r1, w1)
        offer(sub, t, TYRE, k + np.clip(s, 0, 1))
    sub = rays.reaching(everything, best_t, profile[-1, 1] - 1e-9, profile[-1, 1] + 1e-9, 0.0, g.rim_radius_m)
    t, _ = rays.plane(sub, profile[-1, 1], 0.0, g.rim_radius_m)
    offer(sub, t, INNER)

    won = part >= 0
    if not won.any():
        return
    sel = np.flatnonzero(won)
    t = best_t[sel]
    p = part[sel]
    a = aux[sel]
    du, dv, dw = rays.du[sel], rays.dv[sel], rays.dw[sel]
    pu = rays.o[0] + t * du                      # hit points in the wheel frame, (M,) each
    pv = rays.o[1] + t * dv
    r = np.hypot(pu, pv)
    inv_r = 1.0 / np.maximum(r, 1e-12)
    # shading normal as n_r * e_r + n_w * w (every part is a surface of revolution or a plane)
    n_r = np.zeros(len(sel))
    n_w = np.ones(len(sel))
    albedo = np.zeros(len(sel))
    spec = np.zeros(len(sel))
    label_part = p.copy()
    fin = wheel_finish(g)
    flange_spec = fin.flange_specular if look.rim_specular is None else look.rim_specular
    spoke_spec = fin.spoke_specular if look.rim_specular is None else look.rim_specular
    spoke_albedo = fin.spoke_albedo if look.spoke_albedo is None else look.spoke_albedo
    clean = None  # the lip's share left clean of dust and dirt (None: all of it)

    m = p == FLANGE  # rounded lip: the shading normal turns outward toward the edge
    phi = (1.3 * (r[m] - r_in) / g.flange_width_m - 0.25)
    n_r[m], n_w[m] = np.sin(phi), np.cos(phi)
    albedo[m], spec[m] = g.rim_albedo, flange_spec
    if look.dust > 0 or look.dirt > 0:
        lip = np.flatnonzero(m)
        theta = np.arctan2(pv[lip], pu[lip])
        dust = dust_weight(theta, look) if look.dust > 0 else np.zeros(lip.size, np.float32)
        dirt = dirt_blotches(theta, r[lip], look) if look.dirt > 0 else np.zeros(lip.size, np.float32)
        albedo[lip] = (g.rim_albedo * (1 - dust) + look.dust_albedo * dust) * (1 - look.dirt * dirt)
        clean = np.ones(len(sel), np.float32)
        clean[lip] = (1 - dust) * (1 - dirt)
        spec[lip] *= clean[lip]
    m = p == BARREL
    n_r[m], n_w[m] = -1.0, 0.0
    albedo[m], spec[m] = 0.8 * g.rim_albedo, 0.3 * flange_spec
    m = p == SPOKE
    ringm = m & (a < 0)
    albedo[m], spec[m] = spoke_albedo, spoke_spec
    albedo[ringm] = 0.9 * g.rim_albedo
    label_part[ringm] = RING
    m = (p == HUB) | (p == HUB_SIDE)
    albedo[m], spec[m] = 0.5, 0.3
    m = p == HUB_SIDE
    n_r[m], n_w[m] = 1.0, 0.0
    # lug holes: five dark circles on the hub disc
    hub = np.flatnonzero(p == HUB)
    if hub.size:
        lug_r = 0.6 * g.hub_radius_m
        near = np.round(np.arctan2(pv[hub], pu[hub]) / (2 * np.pi / 5)) * (2 * np.pi / 5)
        dist2 = (pu[hub] - lug_r * np.cos(near)) ** 2 + (pv[hub] - lug_r * np.sin(near)) ** 2
        lug = hub[dist2 < (0.17 * g.hub_radius_m) ** 2]
        albedo[lug], spec[lug] = 0.06, 0.0
        label_part[lug] = LUG
    m = p == CALIPER
    albedo[m], spec[m] = fin.caliper_albedo, 0.1
    m = p == DISC
    albedo[m] = 0.26 + 0.04 * np.cos(40 * np.arctan2(pv[m], pu[m]))
    spec[m] = 0.15
    albedo[p == CAVITY] = 0.025
    albedo[p == INNER] = 0.04
    tyre = np.flatnonzero(p == TYRE)
    if tyre.size:
        vn = _profile_normals(profile)
        at = a[tyre]
        k = np.clip(np.floor(at).astype(int), 0, len(profile) - 2)
        f = at - k
        nr = vn[k, 0] * (1 - f) + vn[k + 1, 0] * f
        nw = vn[k, 1] * (1 - f) + vn[k + 1, 1] * f
        norm = np.hypot(nr, nw)
        n_r[tyre], n_w[tyre] = nr / norm, nw / norm
        albedo[tyre] = g.tyre_albedo
        spec[tyre] = 0.04
        if rib:  # the protector rib: flat-shaded faces and a label of its own (its edges supersampled)
            on_rib = np.isin(k, rib)
            seg = np.diff(profile, axis=0)[k[on_rib]]
            face = np.stack([-seg[:, 1], seg[:, 0]], axis=1) / np.hypot(seg[:, 0], seg[:, 1])[:, None]
            n_r[tyre[on_rib]], n_w[tyre[on_rib]] = face[:, 0], face[:, 1]
            label_part[tyre[on_rib]] = RIDGE
        # raised lettering on the outer sidewall: lighter rubber blocks in two arcs
        text = tyre[_lettering(np.arctan2(pv[tyre], pu[tyre]), r[tyre], at, g, n_outer, look.letter_band)]
        albedo[text] = np.minimum(2.4 * g.tyre_albedo, 0.45) if look.letter_albedo <= 0 else look.letter_albedo
        label_part[text] = TYRE_TEXT
    # shade in the wheel frame: normals, rays and the key light all expressed in (u, v, w)
    nr_over_r = n_r * inv_r
    normals = (nr_over_r * pu, nr_over_r * pv, n_w)
    key_w = R.T @ np.asarray(lighting.key_direction_station, float)
    metal = (p == FLANGE) | (p == BARREL) | (p == SPOKE)
    shininess = 24.0 if look.rim_shininess == 24.0 else np.where(metal, look.rim_shininess, 24.0)
    key_scale = None
    if look.shadow_height is not None:
        up = R.T @ np.array([0.0, 0.0, 1.0])
        key_scale = arch_shadow(pu, pv, up[:2] / np.hypot(up[0], up[1]), g.rim_radius_m, look)
    value = shade(albedo, normals, (du, dv, dw), replace(lighting, key_direction_station=tuple(key_w)),
                  specular=spec, shininess=shininess, key_scale=key_scale)
    if look.rim_mirror > 0:  # the workshop mirrored in the metal, less where dust and dirt cover it
        mm = np.flatnonzero(metal)
        mirror = mirror_reflection(tuple(c[mm] for c in normals), (du[mm], dv[mm], dw[mm]), R, look.rim_mirror,
                                   look.surround)
        value[mm] += mirror if clean is None else mirror * clean[mm]
    hits.store(idx[sel], t, LABEL_WHEEL + 40 * wheel_index + label_part, value)


def _lettering(theta: np.ndarray, r: np.ndarray, seg: np.ndarray, g: WheelGeometry, n_outer: int = N_OUTER,
               band: tuple[float, float] = (0.4, 0.62)) -> np.ndarray:
    """(N,) bool: the tyre point at angle theta, radius r (outer sidewall: seg < n_outer) is a
    letter; the letters fill the radial ``band`` (fractions of the sidewall height S above the
    flange edge)."""
    S = g.tyre_radius_m - g.rim_radius_m
    r_a, r_b = g.rim_radius_m + band[0] * S, g.rim_radius_m + band[1] * S
    cell = 0.022 / ((r_a + r_b) / 2)                  # ~22 mm per character
    j = np.floor(theta / cell)
    frac = theta / cell - j
    phase = np.mod(theta, np.pi)                      # the brand name twice round the tyre
    in_arc = phase < 0.55
    h = np.abs(np.modf(np.sin(j * 12.9898 + 78.233) * 43758.5453)[0])
    rr = (r - r_a) / (r_b - r_a)
    glyph = (frac > 0.12) & (frac < 0.82) & ((h > 0.55) | (np.abs(rr - 0.5) < 0.12) | (rr < 0.18 + 0.3 * h))
    return (seg < n_outer) & (r > r_a) & (r < r_b) & in_arc & (h > 0.12) & glyph


def wheel_outline_points(center: np.ndarray, R_station_wheel: np.ndarray, g: WheelGeometry,
                         n: int = 72) -> np.ndarray:
    """(3n, 3) station points on the tyre's bounding cylinder: both rims and the middle circle
    (for image bounding regions)."""
    a = np.linspace(0, 2 * np.pi, n, endpoint=False)
    r = g.tyre_radius_m * 1.02
    w_out = g.sidewall_bulge_m + 0.002
    w_in = g.sidewall_bulge_m - g.tyre_width_m - 0.002
    pts = []
    for w in (w_out, (w_out + w_in) / 2, w_in):
        local = np.stack([r * np.cos(a), r * np.sin(a), np.full(n, w)], axis=1)
        pts.append(local @ R_station_wheel.T + center)
    return np.vstack(pts)
