"""Is a rim found in a photograph found again in the same photograph taken a little bigger or
smaller? (``station detect``'s last test.)

A photograph's rim passes the searches' tests (a dark tyre round it, a closed and smooth lip
edge, no larger contour round it) by some margin. Where the margin is thin, another camera,
another compression or another distance flips the decision, and the contours that pass so are
mostly not rims: a steel wheel's disc whose "tyre" is the wheel's own dark barrel, an ellipse
out on the tyre closed on just half its turn. So the same search runs again on the photograph
resized (``resized_scale``) and the rim is kept only when the same ellipse comes back
(centre and axes within ``SAME_RIM`` of its size). A large rim is looked for at
``SMALLER`` of the size; a small one at ``LARGER`` (made smaller it would fall below the
searches' smallest rim, where their edges no longer hold). Where another ellipse comes back
(the tyre's bead round the rim, a disc inside it: which is the rim is in doubt), the other
of the two scales decides: the rim is kept where it comes back there. Where nothing comes
back, it is not kept: its tests held only just.
"""

from __future__ import annotations

from typing import Callable

import cv2
import numpy as np

from station.errors import StationError, sentence_without
from station.rim.ellipse import Ellipse
from station.rim.photo_candidates import same_ellipse
from station.rim.photo_search import SAME_RIM

SMALLER = 0.75       # a rim of SMALL_RIM_PX / SMALLER or more is looked for again at this scale
LARGER = 1.33        # a smaller rim at this one
SMALL_RIM_PX = 200.0  # the rim made smaller must stay this high (2a, px), else the photograph is enlarged


def resized_scale(ellipse: Ellipse) -> float:
    """The scale the photograph is taken again at, for a rim ``ellipse`` (photograph px)."""
    return SMALLER if SMALLER * 2 * ellipse.axes_px[0] >= SMALL_RIM_PX else LARGER


def resized(image: np.ndarray, scale: float) -> np.ndarray:
    """``image`` (H,W) or (H,W,3) resized by ``scale`` (area mean down, cubic up)."""
    return cv2.resize(image, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA if scale < 1 else cv2.INTER_CUBIC)


def why_unstable(search: Callable[[np.ndarray], object], image: np.ndarray, ellipse: Ellipse, name: str) -> str | None:
    """Why the rim ``ellipse`` that ``search`` (image -> RimDetection, or StationError) found in
    ``image`` is not trusted (the reason, a str), or None when the search finds the same
    ellipse in the photograph resized (``resized_scale``); where it finds another ellipse
    there, when it finds the same one at the other scale (``LARGER`` or ``SMALLER``)."""
    first = resized_scale(ellipse)
    again = _found_at(search, image, first, name)
    if isinstance(again, str):
        return again
    if same_ellipse(ellipse, again, SAME_RIM):
        return None
    other = LARGER if first == SMALLER else SMALLER
    then = _found_at(search, image, other, name)
    if isinstance(then, Ellipse) and same_ellipse(ellipse, then, SAME_RIM):
        return None
    return (f"another ellipse in the photograph {first:g} times the size (at ({again.center_px[0]:.0f}, "
            f"{again.center_px[1]:.0f}) px, {2 * again.axes_px[0]:.0f} px high, back at this size), and "
            + (then if isinstance(then, str) else f"another again {other:g} times the size"))


def _found_at(search: Callable[[np.ndarray], object], image: np.ndarray, scale: float, name: str) -> Ellipse | str:
    """The ellipse ``search`` finds in ``image`` resized by ``scale``, in ``image``'s pixels, or
    why it finds none (a str)."""
    try:
        return search(resized(image, scale)).ellipse.scaled(1 / scale)
    except StationError as e:  # RimNotFound; an ImageError would be the resizing's
        return f"not found again in the photograph {scale:g} times the size ({sentence_without(name, e)})"
