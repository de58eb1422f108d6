"""The choice of "the rim" among the Hough candidates of one image (stage 5 of
``station.rim.detector``): closure (coverage of the perimeter by bright-inside edges), a dark
tyre band just outside (``ring_darkness``), a concentric tyre outline further out
(``outer_contour``); a tyre outline, a hub or a second wheel is told apart.

``sc`` is the detector's scene: its coarse-image edges (``sc.edges``), a bilinear lookup of
the coarse image at ideal coarse points (``sc.sample_coarse``) and the coarse scale ``sc.s``.
"""

from __future__ import annotations

import numpy as np

from station.errors import RimNotFound
from station.rim import hough, hough_loops
from station.rim.ellipse import Ellipse
from station.rim.npfast import percentile

# Added to the hints of the failures a rim the detector cannot see ends in (no rim contour, a
# wrong contour taken): the rim is found by a lip brighter than the tyre round it, and a black
# lip is as dark as the tyre or darker (docs/accuracy.md, "Outside the envelope").
DARK_RIM_NOTE = ("if the rim is black, or no brighter than its tyre, the station cannot find it: "
                 "it looks for a rim lip brighter than the tyre")

MIN_COVERAGE = 0.5         # below: "no closed rim contour" (choosing the candidate)
MIN_SCORE = 0.35
HUB_RATIO = 2.2           # a closed contour this much larger and concentric makes this one the hub
AMBIGUITY_RATIO = 0.85     # a second wheel-like ellipse scoring within this of the best: refuse
RING_FACTORS = (0.95, 0.975, 1.03, 1.06, 1.10)  # two rings just inside, three just outside


def ring_darkness(sc, e: Ellipse, n_angles: int = 96) -> float:
    """Fraction of the visible angles where the band just outside ``e`` is clearly darker than
    the band just inside: a tyre all round (1.0) versus a disc seen between spokes (< 0.8)."""
    t = (np.arange(n_angles) + 0.5) * (2 * np.pi / n_angles)
    rings = sc.sample_coarse(e.scaled_points(RING_FACTORS, t)).reshape(len(RING_FACTORS), n_angles)
    inner = rings[:2].mean(axis=0)
    outer = rings[2:]                                 # one lookup for the five rings
    seen = np.isfinite(outer)
    with np.errstate(all="ignore"):
        outer = np.where(seen.any(axis=0), np.max(np.where(seen, outer, -np.inf), axis=0), np.nan)
    contrast = inner - outer
    vis = np.isfinite(contrast)
    if vis.sum() < n_angles // 4:
        return 0.0
    c = contrast[vis]
    ref = percentile(c, 80)
    if ref <= 4:
        return 0.0
    return float(np.mean(c > 0.5 * ref))


def outer_contour(sc, e: Ellipse) -> float:
    """Evidence (0..1) of a concentric contour 1.15-2.0 times larger (the tyre outline), any polarity."""
    (cx, cy), (a, b), (c, s) = e.center_px, e.axes_px, e.cos_sin
    n_between, r = hough_loops.concentric_radii(*sc.edges.columns(), cx, cy, a, b, c, s, 1.15, 2.0, hough.NORMAL_COS)
    if n_between < 10 or len(r) < 10:  # r: semi-major of the concentric ellipse through each point (coarse px)
        return 0.0
    hist = np.bincount(np.round(r).astype(int))
    hist = np.convolve(hist, np.ones(5), mode="same")
    rad = np.arange(len(hist))
    frac = hist / np.maximum(np.pi * rad * (1 + b / a), 1)  # support relative to the perimeter
    return float(np.clip(frac.max() / 0.4, 0, 1))


def choose(sc, cands: list[hough.Candidate], tag: str) -> tuple[hough.Candidate, dict]:
    """The rim among the Hough candidates ``cands`` of one image (coarse pixels) and the
    choice's record (``candidates``: the ranked list in full-resolution pixels, for the
    runner-up pairings; ``ring``, ``outer`` of the chosen one). Raises RimNotFound naming
    ``tag`` when none is closed and tyre-bordered enough, or when two wheels compete."""
    scored = []
    for cd in cands:
        ring = ring_darkness(sc, cd.ellipse)
        outer = outer_contour(sc, cd.ellipse)
        score = cd.coverage * (0.6 + 0.4 * ring) * (0.8 + 0.2 * outer)
        scored.append({"cand": cd, "ring": ring, "outer": outer, "score": score})
    # a contour with a closed, tyre-bordered concentric ellipse well inside it is a tyre outline
    for r in scored:
        e = r["cand"].ellipse
        for o in scored:
            eo = o["cand"].ellipse
            ratio = eo.axes_px[0] / e.axes_px[0]
            if (o is not r and 0.5 < ratio < 0.87 and np.linalg.norm(eo.center_px - e.center_px) < 0.08 * e.axes_px[0]
                    and o["cand"].coverage > 0.7 and o["ring"] > 0.9):
                r["score"] *= 0.5
                r["tyre_outline"] = True
                break
    # a closed, tyre-bordered contour much larger and concentric: this one is the hub or disc;
    # more than HUB_RATIO larger, tyre-bordered or not, and closed as well as a rim must be to
    # be chosen at all: the hub (no tyre outline is twice its rim: even an 80-series tyre on a
    # 14-inch rim is 1.8x; a dark rim's flange shows on less of its perimeter than 80 %)
    for r in scored:
        e = r["cand"].ellipse
        for o in scored:
            eo = o["cand"].ellipse
            if (o is not r and not o.get("tyre_outline") and eo.axes_px[0] > 1.3 * e.axes_px[0]
                    and np.linalg.norm(eo.center_px - e.center_px) < 0.08 * eo.axes_px[0]
                    and ((o["cand"].coverage > 0.8 and o["ring"] > 0.8)
                         or (o["cand"].coverage >= MIN_COVERAGE and eo.axes_px[0] > HUB_RATIO * e.axes_px[0]))):
                r["score"] *= 0.5
                break
    scored.sort(key=lambda r: -r["score"])
    if not scored or scored[0]["cand"].coverage < MIN_COVERAGE or scored[0]["score"] < MIN_SCORE:
        best = f" (best candidate: {scored[0]['cand'].coverage:.0%} of its perimeter)" if scored else ""
        raise RimNotFound(f"{tag}: no closed rim contour{best}",
                          hint=f"check that the wheel is in view, lit, and in focus; {DARK_RIM_NOTE}")
    best = scored[0]
    for r in scored[1:]:  # another wheel: a non-concentric, similarly good ellipse outside this one
        e, eb = r["cand"].ellipse, best["cand"].ellipse
        apart = (eb.radius_ratio(e.center_px[None])[0] > 1.0 and e.radius_ratio(eb.center_px[None])[0] > 1.0)
        if np.linalg.norm(e.center_px - eb.center_px) > 0.5 * eb.axes_px[1] and r["score"] >= AMBIGUITY_RATIO * best["score"] \
                and r["cand"].coverage >= MIN_COVERAGE and apart:  # two wheels never hold each other's centre
            raise RimNotFound(f"{tag}: two wheel-like ellipses of similar score "
                              f"({best['score']:.2f} at ({eb.center_px[0] * sc.s:.0f}, {eb.center_px[1] * sc.s:.0f}) px and "
                              f"{r['score']:.2f} at ({e.center_px[0] * sc.s:.0f}, {e.center_px[1] * sc.s:.0f}) px)",
                              hint="only one wheel may be in the camera's view")
    info = {"candidates": [{"ellipse": r["cand"].ellipse.scaled(sc.s).to_dict(), "coverage": r["cand"].coverage,
                            "ring": r["ring"], "outer": r["outer"], "score": r["score"]} for r in scored[:6]],
            "ring": best["ring"], "outer": best["outer"]}
    return best["cand"], info
