"""The station's own search on a photograph stretched round a candidate (``photo_search``).

The station's search (``detector.detect_rim``) finds a rim by evidence of its own: chords of
edges whose gradients face each other, a closed contour, a tyre band just outside that is
darker than the band just inside (relative to that rim, not to the photo), a tyre outline
further out, and a hub or a tyre outline told apart from the rim. It is made for near-frontal
views. A photograph's candidate (``photo_candidates``: a bright region's elliptical outline)
says where a wheel stands and how it is seen - its centre, tilt and axis ratio - even when
it is not the lip: a spoke star, a disc or the lip's inner edge are concentric with the rim
and of its shape. Warped by the affine map that turns the candidate into a circle (the
view's foreshortening undone), the wheel looks near-frontal, and the station's search runs on
it at each of ``REACHES`` (the canvas spans that many times the candidate's size: its own
size, and the wheel round a smaller candidate).

A rim is taken from a canvas only when the canvas shows it with its surroundings
(``TYRE_ROOM``: the canvas spans 1.6 times its size): the station's search tells a rim from a
contour on the tyre by the tyre's outline 1.15-2 times further out, which a larger ellipse has
cut off (on the 61 photographs of bench/real_photos.py, a contour on a tyre's sidewall, 1.2
times its rim, came from a candidate 0.55 of that rim, 1.8 times smaller than the contour).
Its ellipse is carried back exactly (a conic under an affine map), then refined and judged on
the photograph as a candidate of the photo search is (``photo_search._refined``,
``_after_refinement``), with one demand more: the tyre's far outline on at least
``MIN_OUTLINE_SHARE`` of the turn. A contour found this way had no bright region of its own,
and the contours it adds that are not rims are a wheel's inner ones (a disc at 0.6 of the
rim, its "tyre" the rim's dark face); beyond those the light rises again on 0.29-0.43 of the
turn, beyond the rims found this way on 0.58-0.88 (the same photographs).

Arrays: ``grey`` (H,W) float32 light; ellipses in photograph pixels unless named otherwise.
"""

from __future__ import annotations

import cv2
import numpy as np

from station.errors import StationError
from station.rim.ellipse import Ellipse

CANVAS_PX = 1000           # the stretched image's side
REACHES = (1.6, 2.6)       # the canvas spans this many candidate diameters
MAX_STRETCHED = 8          # candidates stretched, the most supported first
MIN_OUTLINE_SHARE = 0.5    # of the turn: the tyre's far outline round a rim found this way
TYRE_ROOM = 1.6            # a rim is kept from a canvas that holds it this much larger (its tyre's outline)


def to_canvas(e: Ellipse, reach: float) -> np.ndarray:
    """(2,3) the affine map from photograph pixels to the canvas on which ``e`` is a circle of
    radius CANVAS_PX / (2 reach) at the centre, its major axis vertical."""
    u = np.array([np.cos(e.angle_rad), np.sin(e.angle_rad)])   # the major axis
    v = np.array([-u[1], u[0]])
    r = CANVAS_PX / (2.0 * reach)
    a, b = e.axes_px
    M = np.array([v * (r / b), u * (r / a)])                    # (2,2): x along the minor, y along the major axis
    t = np.full(2, CANVAS_PX / 2.0) - M @ e.center_px
    return np.column_stack([M, t])


def back_to_photo(e_canvas: Ellipse, affine: np.ndarray) -> Ellipse:
    """The ellipse ``e_canvas`` (canvas px) in photograph pixels: the conic Q pulled back
    through the affine map H (photo -> canvas) is H^T Q H."""
    H = np.vstack([affine, [0.0, 0.0, 1.0]])
    return Ellipse.from_conic_matrix(H.T @ e_canvas.conic_matrix() @ H)


def stretched_search(grey: np.ndarray, e: Ellipse, cut: list | None = None) -> list[Ellipse]:
    """The station search's rim (photograph px) on the photograph stretched round the
    candidate ``e`` at each of ``REACHES``, those it found with room for their tyre's outline
    on the canvas (``TYRE_ROOM``: a larger ellipse, its surroundings cut off, was chosen
    without the tyre outline and hub tests that tell a rim from a contour on the tyre). Those
    too large are appended to ``cut`` where it is given."""
    from station.rim.detector import detect_rim

    found = []
    for reach in REACHES:
        affine = to_canvas(e, reach)
        canvas = cv2.warpAffine(grey, affine, (CANVAS_PX, CANVAS_PX), flags=cv2.INTER_LINEAR,
                                borderMode=cv2.BORDER_CONSTANT, borderValue=0)
        try:
            rim = back_to_photo(detect_rim(canvas).ellipse, affine)
        except (StationError, ValueError):
            continue
        if rim.axes_px[0] * TYRE_ROOM <= reach * e.axes_px[0]:  # its tyre's outline in view: judged as a rim
            found.append(rim)
        elif cut is not None:
            cut.append(rim)
    return found
