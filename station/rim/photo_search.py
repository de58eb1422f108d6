"""The rim in a street photograph (``station detect``): steep side views, clutter, any size.

The station's search (``detector.detect_rim``) is made for its own near-frontal views of one
wheel filling the frame. In a photograph the wheel is one object among lamps, grilles and
other cars, seen from the side. This search takes a candidate for the rim only when the
wheel's physical structure is there round it, and refuses, naming what it saw, otherwise:

1. **Candidates** (``photo_candidates``): bright regions whose outer boundary an ellipse
   follows over most of its turn, at several grey levels of a log-light search image.
2. **Geometry of a wheel.** A wheel stands upright on the ground: seen from the side its
   major axis is near the image's vertical (``MAX_TILT_DEG``, room for camera roll and
   pitch). Nearer round than ``MAX_AXIS_RATIO`` that cannot be told ("near-frontal": the
   station's search is for those views); steeper than ``MIN_AXIS_RATIO`` the lip is a sliver
   ("too oblique"); a rim under ``MIN_RIM_PX`` across is "too small".
3. **The tyre's structure** on the candidate's concentric similar ellipses (``structure``):
   black rubber just outside the lip, a light ratio of at least ``MIN_STEP`` (2x) darker than
   the lip on ``MIN_DARK_SHARE`` of the turn (a disc seen between spokes, a grille, a hub
   with metal round it are not); the rubber band is among the darkest things in the photo
   (its light at most the photo's ``RUBBER_PERCENTILE`` percentile: a lamp in a grey body is
   bordered by paint, not rubber); and the band ends: somewhere between 1.2 and 1.9 times the
   rim's size the light rises again by ``MIN_STEP`` on ``MIN_OUTSIDE_SHARE`` of the turn (the
   tyre's outline on its far side; a dark blob or the body's shadow has no such end).
4. **The sub-pixel lip edge** by the station's refinement (``detector._refine``) at each of
   ``REFINE_SCALES``; it must hold on ``MIN_COVERAGE`` of the perimeter, stay within
   ``MAX_EDGE_MOVE`` of the candidate, be one smooth curve (its points within
   ``MAX_EDGE_RMS_PX`` rms of their ellipse: a contour pieced from spokes' ends and arcs of
   the lip is not), and the geometry and the tyre must hold again round the refined ellipse.
5. **Nesting**: a candidate inside a larger one that passed steps 2-3 (the hub, a hubcap's
   ring, the disc or the lip's inner edge) is not the rim, unless the larger one's own lip
   edge came out as this very ellipse (one rim found twice: the larger was the lip and the
   tyre's bead together). Judged after step 4, so that a larger candidate whose edge moved
   onto the rim does not hide it.
6. **Stretched**: the station's own search on the photograph warped round a candidate until
   it is a circle (``photo_stretch``: a spoke star, a disc or the lip's inner edge tells
   where the wheel is and how it is seen), its rim refined and judged as in steps 2-5, with
   the tyre's far outline on half the turn (a rim the station's search took on two canvases -
   round two candidates, or at both reaches round one - is not asked for the tyre's 2x step
   against its lip: the search judged its tyre band against that rim's own lip on each, and a
   sunlit tyre beside a shaded lip has less): round each candidate of a wheel's shape, where
   steps 1-5 took no rim (the candidate stretched round does not hide the rim found inside it:
   its own lip edge was not found, the station's search saw it whole and took the rim). Round
   each rim taken (by steps 1-5, or so): a larger rim round it that passes replaces it (it was
   a hubcap or a disc), else the same rim refined from there where its edge covers more of the
   perimeter; where neither, a closed contour round it that the canvas cut off refuses it (a
   disc or a hubcap inside its rim, or the rim inside its tyre's outline: which is the rim
   cannot be told).

Of the wheels that pass, the largest (the nearest, the most pixels) is returned;
``details["other_wheels"]`` counts the rest. Two different accepted ellipses on one wheel
are refused as "several candidates".
"""

from __future__ import annotations

import numpy as np

from station.errors import RimNotFound
from station.rim.choice import DARK_RIM_NOTE
from station.rim import photo_candidates as pc
from station.rim.ellipse import Ellipse
from station.rim.exposure import check_exposure
from station.rim.photo_stretch import MAX_STRETCHED, MIN_OUTLINE_SHARE, stretched_search

MIN_AXIS_RATIO = 0.2      # b/a: steeper views leave a semi-minor axis of a few search pixels
MAX_TILT_DEG = 30.0       # the major axis off the image's vertical (upright wheel, level-ish camera)
MAX_AXIS_RATIO = 0.7      # b/a: nearer round the major axis's direction, hence upright, cannot be told;
#                           a round lamp in a dark bezel then has all of a wheel's structure this search
#                           tests (near-frontal views are the station search's, detector.detect_rim)
MIN_RIM_PX = 100.0        # rim height 2a (photograph px)
MIN_STEP = np.log(2.0)    # a light ratio of 2: rubber against metal or paint
MIN_DARK_SHARE = 0.5      # of the turn: rubber just outside the lip (under the arch the metal mirrors the shadow)
MIN_OUTSIDE_SHARE = 0.25  # of the turn: brighter again beyond the tyre (its far side's outline)
RUBBER_PERCENTILE = 35.0  # the tyre band's median light at most this percentile of the photo's
MIN_COVERAGE = 0.5        # the sub-pixel lip edge on this share of the perimeter
MIN_SIGHTINGS = 2         # canvases on which the station's search took one rim: seen again, see _after_stretch
HELD_COVERAGE = 0.4       # a larger contour round a rim taken, its edge on this share: which is the rim is in doubt
MAX_EDGE_RMS_PX = 1.0     # the lip edge's points off their ellipse (robust rms): a turned lip is one
#                           smooth curve, its edge scatters by tenths of a pixel; a contour pieced from
#                           spokes' ends, the lip's arcs and lettering scatters by a pixel or more
SAME_RIM = 0.1            # centre / axes within this share of a: the same ellipse
MAX_EDGE_MOVE = 0.2       # the lip edge may move this share of a off its candidate: a region's outline at
#                           one grey level lies inside the lip where it is shaded; the refined ellipse is
#                           judged again in full, this keeps the edge on the same wheel
MAX_REFINED = 6           # candidates refined, best first
REFINE_SCALES = (1, 2, 3) # the lip edge refined at these downscales (a blurred edge), see _refined
BLURRED_PX = 4.0          # an edge blur (Gaussian sigma, photograph px) named "blurred" in a refusal: the
#                           rims found in sharp street photographs are blurred by 0.6-2.4 px
BLUR_SCALE = 3            # the downscale the blur is read at (its profiles then reach 12 px either side)

RHOS = np.round(np.arange(0.80, 1.905, 0.02), 2)   # (R,) the concentric ellipses sampled
LIP = (RHOS >= 0.86) & (RHOS <= 0.96)
TYRE = (RHOS >= 1.04) & (RHOS <= 1.22)   # a sidewall is 0.2-0.6 of the rim's radius high
BEYOND = RHOS >= 1.2


def structure(L: np.ndarray, e: Ellipse, rubber_level: float) -> dict:
    """The tyre's evidence round ``e`` (search px) in log-light ``L`` (h,w): ``dark`` (share of
    the turn where the band just outside is MIN_STEP darker than the lip), ``outside`` (share
    where the light rises MIN_STEP beyond the band), ``rubber`` (band median <= rubber_level)."""
    P = pc.profile(L, e, RHOS)                     # (R, 72)
    seen = np.isfinite(P[LIP | TYRE]).all(axis=0)  # (72,) the lip and the tyre band in the photo
    if seen.mean() < 0.75:                         # mostly outside the photo
        return {"dark": 0.0, "outside": 0.0, "rubber": False, "seen": float(seen.mean())}
    P = P[:, seen]
    lip = P[LIP].max(axis=0)
    tyre = np.percentile(P[TYRE], 75, axis=0)     # dark across the whole band, lettering aside
    dark = float(np.mean(lip - tyre >= MIN_STEP))
    beyond = np.where(np.isfinite(P[BEYOND]), P[BEYOND], -np.inf).max(axis=0)  # beyond the border: not seen
    outside = float(np.mean(beyond - tyre >= MIN_STEP))
    return {"dark": dark, "outside": outside, "rubber": bool(np.median(tyre) <= rubber_level),
            "seen": float(seen.mean())}


def where(e: Ellipse) -> str:
    return (f"at ({e.center_px[0]:.0f}, {e.center_px[1]:.0f}) px, {2 * e.axes_px[0]:.0f} px high, "
            f"b/a {e.axes_px[1] / e.axes_px[0]:.2f}")


def tilt_from_vertical_deg(e: Ellipse) -> float:
    """The angle (deg, 0-90) between the ellipse's major axis and the image's vertical."""
    return 90.0 - abs(np.degrees(e.angle_rad))


def geometry_verdict(e: Ellipse) -> str | None:
    """Why an ellipse (photograph px) cannot be a measurable upright rim, or None."""
    a, b = e.axes_px
    if 2 * a < MIN_RIM_PX:
        return f"too small (rim {2 * a:.0f} px high < {MIN_RIM_PX:.0f})"
    if b / a < MIN_AXIS_RATIO:
        return f"too oblique (b/a {b / a:.2f} < {MIN_AXIS_RATIO})"
    tilt = tilt_from_vertical_deg(e)
    if b / a >= MAX_AXIS_RATIO:
        return (f"near-frontal (b/a {b / a:.2f} >= {MAX_AXIS_RATIO}: whether it stands upright cannot be told, "
                "a round lamp looks the same; --search station is made for near-frontal views)")
    if tilt > MAX_TILT_DEG:
        return f"not upright (major axis {tilt:.0f} deg off the vertical)"
    return None


def structure_verdict(st: dict, any_step: bool = False) -> str | None:
    """Why the surroundings of a candidate are not a tyre's, or None; with ``any_step`` the
    band's step against the lip (``dark``) is not asked."""
    if st["seen"] < 0.75:
        return f"cut by the photo's border ({st['seen']:.0%} of the tyre in view)"
    if st["dark"] < MIN_DARK_SHARE and not any_step:
        return f"no dark tyre round it (rubber-dark on {st['dark']:.0%} of the turn < {MIN_DARK_SHARE:.0%})"
    if not st["rubber"]:
        return f"its dark band is not rubber-dark (lighter than {RUBBER_PERCENTILE:.0f} % of the photo, paint rather than a tyre)"
    if st["outside"] < MIN_OUTSIDE_SHARE:
        return f"no tyre outline (the dark band does not end on {1 - st['outside']:.0%} of the turn)"
    return None


def _refined(grey: np.ndarray, e: Ellipse, camera_id: str, verdict):
    """The station's sub-pixel lip edge along ``e`` (photograph px), on the photograph
    downscaled by each of ``REFINE_SCALES`` (a photograph's edge may be blurred over more
    pixels than the edge model's windows reach), each judged by ``verdict`` (RimDetection ->
    why not, or None): (the passing one covering most of the rim, None), else (the one
    covering most, why), as a RimDetection in photograph px; RimNotFound if none holds. A
    coarser scale replaces a finer one only when it covers 5 % more of the perimeter."""
    from station.rim.detector import _Clock, _refine, _rescaled, _result
    from station.rim.preprocess import PixelMap, downscale

    results, error = [], None
    for r in REFINE_SCALES:
        clock = _Clock()
        fit, samples, mask, blur = _refine(downscale(grey, r), e.scaled(1 / r), PixelMap(None))
        clock.lap("refine")
        try:
            det = _result(fit, samples, mask, {"path": "photo", "blur_px": blur}, clock, None, PixelMap(None), camera_id)
        except RimNotFound as ex:
            error = ex
            continue
        det = _rescaled(det, r) if r > 1 else det
        results.append((det, verdict(det)))
    if not results:
        raise error
    pool = [t for t in results if t[1] is None] or results
    best = pool[0]
    for t in pool[1:]:  # finest first
        if t[0].coverage > best[0].coverage + 0.05:
            best = t
    return best


def detect_in_photo(image: np.ndarray, camera_id: str = ""):
    """The rim in a photograph (``image``: grey levels proportional to light, grey or BGR,
    uint8/uint16/float): a ``RimDetection`` (``details["path"] == "photo"``), or RimNotFound
    naming what was seen and why it was not taken."""
    from station.rim.preprocess import to_grey

    tag = camera_id or "image"
    grey = to_grey(image, camera_id)
    check_exposure(grey, tag)
    L, s = pc.search_image(grey)
    rubber_level = float(np.percentile(L[::2, ::2], RUBBER_PERCENTILE))
    a_min = 0.5 * MIN_RIM_PX / s
    cands = pc.candidates(L, 0.8 * a_min, 0.5 * max(L.shape), 0.8 * MIN_AXIS_RATIO)
    if not cands:
        raise RimNotFound(f"{tag}: no rim-like ellipse (no bright region with an elliptical outline of "
                          f"{MIN_RIM_PX:.0f} px or more)",
                          hint=f"check that a wheel is in view and in focus; {DARK_RIM_NOTE}")
    passed, refused = [], []
    for c in cands:
        e = c["ellipse"]
        why = geometry_verdict(e.scaled(s))
        st = structure(L, e, rubber_level) if why is None else None
        why = why or structure_verdict(st)
        if why is None:
            passed.append({**c, **st, "score": st["dark"] * c["cover"]})
        else:
            refused.append((c, why, 0 if st is None else 1))
    passed.sort(key=lambda c: -c["score"])
    accepted = []
    for c in passed[:MAX_REFINED]:
        e_full = c["ellipse"].scaled(s)
        try:
            det, why = _refined(grey, e_full, camera_id, lambda d: _after_refinement(d, e_full, L, s, rubber_level))
        except RimNotFound as ex:
            refused.append((c, f"no sub-pixel lip edge ({str(ex).split(': ', 1)[-1]})", 2))
            continue
        c["refined"] = det.ellipse
        if why is None:
            accepted.append((det, c))
        else:
            refused.append((c, why, 2))
    # the hub, a hubcap's ring, the disc, the lip's inner edge: inside a larger candidate with
    # the tyre round it, unless that one's lip edge is this very ellipse (one rim found twice)
    kept = []
    larger = [(o["ellipse"].scaled(s), o.get("refined")) for o in passed]
    for det, c in accepted:
        o = hidden_by(det.ellipse, larger)
        if o is None:
            kept.append((det, c))
        else:
            refused.append((c, f"inside a larger candidate with a tyre round it ({where(o)}; "
                               "a hub, a disc or the lip's inner edge)", 3))
    def looked_round(taken: list) -> list:
        out = []
        for det, c in taken:
            got = _looked_round(grey, det, c, L, s, rubber_level, camera_id)
            if isinstance(got, str):
                refused.append((c, got, 3))
            else:
                out.append(got)
        return out

    accepted = (looked_round(kept)
                or looked_round(_stretched(grey, cands, s, L, rubber_level, camera_id, larger, refused)))
    if not accepted:
        if not refused:
            raise RimNotFound(f"{tag}: no rim taken",
                              hint=f"photograph the wheel from nearer its front; {DARK_RIM_NOTE}")
        # the candidate that came furthest (geometry, tyre, lip edge), then the most stable
        c, why, _ = max(refused, key=lambda r: (r[2], r[0]["support"], r[0]["cover"]))
        blur = edge_blur_px(grey, c["ellipse"].scaled(s))
        if blur > BLURRED_PX:
            why += f"; the photograph is blurred there (edge blur {blur:.1f} px > {BLURRED_PX:.0f})"
        raise RimNotFound(f"{tag}: no rim taken; the best candidate {where(c['ellipse'].scaled(s))}: {why}",
                          hint="photograph the wheel in focus, from nearer its front, the rim 100 px or more high; "
                               f"{DARK_RIM_NOTE}")
    accepted.sort(key=lambda t: -t[0].ellipse.axes_px[0])
    det, c = accepted[0]
    for d2, _ in accepted[1:]:  # a different ellipse over the same wheel: which is the lip is not known
        e, o = det.ellipse, d2.ellipse
        if e.radius_ratio(o.center_px[None])[0] < 1.0 and not pc.same_ellipse(e, o, SAME_RIM):
            raise RimNotFound(f"{tag}: several candidates on one wheel ({where(e)}; {where(o)})",
                              hint="photograph the wheel nearer its front")
    others = sum(not pc.same_ellipse(det.ellipse, d2.ellipse, SAME_RIM) for d2, _ in accepted[1:])
    det.details.update({"path": "photo", "dark_share": c["dark"], "outside_share": c["outside"],
                        "support": c["support"], "other_wheels": int(others)})
    return det


def _stretched(grey: np.ndarray, cands: list, s: int, L: np.ndarray, rubber_level: float, camera_id: str,
               larger: list, refused: list) -> list:
    """Where no candidate was taken: the rims the station's search finds on the photograph
    stretched round the candidates of a wheel's shape (``photo_stretch``), each refined and
    judged as a candidate is, with the tyre's far outline on ``MIN_OUTLINE_SHARE`` of the turn
    and not inside a larger candidate with a tyre round it other than the one stretched round:
    [(RimDetection, record)] as ``detect_in_photo`` takes them; the others go to ``refused``."""
    shaped = [c for c in cands if geometry_verdict(c["ellipse"].scaled(s)) is None][:MAX_STRETCHED]
    found: list[tuple[Ellipse, dict, list]] = []  # (rim, the candidate, the larger ones that may hide it)
    sightings: list[Ellipse] = []                 # every rim the station's search took, on any canvas
    for c in shaped:
        around = c["ellipse"].scaled(s)
        # the candidate stretched round does not hide what is found inside it: the station's
        # search, seeing it whole, took that rim (a candidate's lip edge not found is no rim)
        others = [t for t in larger if not pc.same_ellipse(t[0], around, 0.02)]
        too_large: list[Ellipse] = []
        rims = stretched_search(grey, around, too_large)
        found += [(e, c, others) for e in rims]
        sightings += rims + too_large
    tried: list[Ellipse] = []
    out = []
    for e, c, others in found:
        if geometry_verdict(e) is not None or any(pc.same_ellipse(e, t, SAME_RIM) for t in tried):
            continue
        tried.append(e)
        seen_on = sum(pc.same_ellipse(e, t, SAME_RIM) for t in sightings)
        record = {**c, "ellipse": e.scaled(1 / s), "stretched": True}
        try:
            det, why = _refined(grey, e, camera_id,
                                lambda d: _after_stretch(d, e, L, s, rubber_level, seen_on >= MIN_SIGHTINGS))
        except RimNotFound as ex:
            refused.append((record, f"no sub-pixel lip edge ({str(ex).split(': ', 1)[-1]})", 2))
            continue
        o = hidden_by(det.ellipse, others) if why is None else None
        if o is not None:
            why = f"inside a larger candidate with a tyre round it ({where(o)}; a hub, a disc or the lip's inner edge)"
        if why is None:
            out.append((det, {**record, **structure(L, det.ellipse.scaled(1 / s), rubber_level)}))
        else:
            refused.append((record, why, 2))
    return out


def _looked_round(grey: np.ndarray, det, record: dict, L: np.ndarray, s: int, rubber_level: float,
                  camera_id: str):
    """(det, record) as the station's search sees it on the photograph stretched round an
    accepted rim (``photo_stretch``), where it sees the whole wheel. A concentric rim round
    ``det`` (``_nested``) that passes every test of a stretched rim replaces it: ``det`` was a
    wheel's inner contour (a hubcap, a disc). Else the same rim refined again from the
    station search's ellipse replaces it where that edge covers more of the perimeter: the
    refinement's consensus depends on where it starts (a region's outline at one grey level
    against the station's ellipse of the stretched wheel), as at the scales of ``_refined``.
    Where neither replaces it, a closed contour the station's search found round it, too large
    for its canvas to judge, refuses it (``_held_by_larger``: the reason, a str, is returned)."""
    best = (det, record)
    cut: list = []
    for e in stretched_search(grey, det.ellipse, cut):
        outer = _nested(det.ellipse, e)
        if not (outer or pc.same_ellipse(e, det.ellipse, SAME_RIM)):
            continue
        try:
            found, why = _refined(grey, e, camera_id, lambda d: _after_stretch(d, e, L, s, rubber_level))
        except RimNotFound:
            continue
        if why is not None:
            continue
        taken = (found, {**record, **structure(L, found.ellipse.scaled(1 / s), rubber_level), "stretched": True})
        if outer and _nested(det.ellipse, found.ellipse):
            return taken
        if (not outer and pc.same_ellipse(found.ellipse, det.ellipse, SAME_RIM)
                and found.coverage > best[0].coverage):
            best = taken
    if best[0] is det:
        return _held_by_larger(grey, det, cut, camera_id) or best
    return best


def _held_by_larger(grey: np.ndarray, det, cut: list, camera_id: str) -> str | None:
    """Why ``det`` is refused (str), or None: of the ellipses the station's search found round
    it too large for their canvas to judge (``cut``, photograph px), one holds it
    (``_encloses``) and its sub-pixel edge on the photograph holds it too and covers
    ``HELD_COVERAGE`` of its perimeter (less than a rim must: a doubt needs less evidence).
    Which of the two is the rim cannot be told there: a disc or a hubcap inside its rim, or a
    rim inside its tyre's outline."""
    for e in cut:
        if not _encloses(e, det.ellipse):
            continue
        try:
            found, _ = _refined(grey, e, camera_id, lambda d: None)
        except RimNotFound:
            continue
        if found.coverage >= HELD_COVERAGE and _encloses(found.ellipse, det.ellipse):
            return (f"a larger contour round it ({where(found.ellipse)}): a hubcap, a disc or the lip's "
                    "inner edge, or the rim and its tyre's outline")
    return None


def _after_stretch(det, e: Ellipse, L: np.ndarray, s: int, rubber_level: float, seen_again: bool = False) -> str | None:
    """Why a rim of the stretched search, refined, is not the rim (``_after_refinement``, and
    the tyre's far outline on ``MIN_OUTLINE_SHARE`` of the turn), or None. A rim the station's
    search took on ``MIN_SIGHTINGS`` canvases (``seen_again``) is not asked for a tyre
    ``MIN_STEP`` darker than its lip: the station's search judged the tyre band against that
    rim's own lip on each; the band must still be rubber-dark for the photo and end."""
    why = _after_refinement(det, e, L, s, rubber_level, seen_again)
    if why is not None:
        return why
    outside = structure(L, det.ellipse.scaled(1 / s), rubber_level)["outside"]
    if outside < MIN_OUTLINE_SHARE:
        return (f"a wheel's inner contour, no tyre outline round most of it (the light rises beyond its dark band "
                f"on {outside:.0%} of the turn < {MIN_OUTLINE_SHARE:.0%})")
    return None


def edge_blur_px(grey: np.ndarray, e: Ellipse) -> float:
    """The blur (Gaussian sigma, photograph px) of the bright-inside edges along ``e``
    (photograph px) in ``grey``, read at 1/``BLUR_SCALE``: NaN where none is found."""
    from station.rim.preprocess import PixelMap, downscale
    from station.rim.subpixel import edge_points

    _, sigma = edge_points(downscale(grey, BLUR_SCALE), e.scaled(1 / BLUR_SCALE), PixelMap(None), n=256)
    return float("nan") if sigma is None else BLUR_SCALE * float(sigma)


def _nested(e: Ellipse, o: Ellipse) -> bool:
    """``e`` lies inside the larger ``o``: centre within half of ``o``, ``o`` 15 % larger."""
    return bool(o.axes_px[0] > 1.15 * e.axes_px[0] and o.radius_ratio(e.center_px[None])[0] < 0.5)


def _encloses(o: Ellipse, e: Ellipse) -> bool:
    """``o`` is 15 % larger than ``e`` and holds it (within a tenth of its size)."""
    return bool(o.axes_px[0] > 1.15 * e.axes_px[0] and o.radius_ratio(e.points(36)).max() <= 1.1)


def hidden_by(e: Ellipse, larger: list) -> Ellipse | None:
    """The candidate (of ``larger``: (candidate ellipse, its refined lip edge or None), all
    with the tyre round them) that ``e``, a refined rim, lies inside, or None. A larger
    candidate whose own lip edge came out as ``e`` is the same rim, not an outer one."""
    for o, refined in larger:
        if _nested(e, o) and not (refined is not None and pc.same_ellipse(refined, e, SAME_RIM)):
            return o
    return None


def rough_edge_verdict(det) -> str | None:
    """Why a detection's edge is not one smooth curve (its points farther than
    ``MAX_EDGE_RMS_PX`` robust rms off their ellipse: a contour pieced from several), or None."""
    if det.point_sigma_px > MAX_EDGE_RMS_PX:
        return (f"not one smooth contour (the edge points lie {det.point_sigma_px:.1f} px rms off their ellipse "
                f"> {MAX_EDGE_RMS_PX:.1f})")
    return None


def _after_refinement(det, e: Ellipse, L: np.ndarray, s: int, rubber_level: float,
                      any_step: bool = False) -> str | None:
    """Why a refined candidate is not the rim, or None: the edge left the candidate, holds on
    too little of it, or the tyre's structure fails round the refined ellipse (its step
    against the lip not asked with ``any_step``)."""
    if not pc.same_ellipse(e, det.ellipse, MAX_EDGE_MOVE):
        return f"the sub-pixel edge left the candidate (now {where(det.ellipse)})"
    if det.coverage < MIN_COVERAGE:
        return f"no closed rim contour (sub-pixel edge on {det.coverage:.0%} of the perimeter)"
    why = rough_edge_verdict(det) or geometry_verdict(det.ellipse)
    return why or structure_verdict(structure(L, det.ellipse.scaled(1 / s), rubber_level), any_step)
