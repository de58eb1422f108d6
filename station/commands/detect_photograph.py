"""`station detect`'s searches on one photograph: the station's search, then the street-photo
search (station/rim/photo_search.py), each rim kept only where it is found again in the
photograph resized, and a large photograph searched again shrunk."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from station.commands.photo_files import read_photograph
from station.errors import RimNotFound, sentence_without

SEARCHES = ("auto", "station", "photo")


def detect_photograph(image: np.ndarray, gamma: float, name: str = "", equalization: str = "clahe",
                      search: str = "auto"):
    """What ``station detect`` runs on an image as read (``read_image``) whose grey levels are
    light^``gamma``: the RimDetection (``details["search"]`` names the search that found it), or
    RimNotFound / ImageError with the reason. ``search``: "station" (detect_rim, the station's
    search for its own cameras' near-frontal views; ``equalization`` is its), "photo"
    (station.rim.photo_search: a wheel among other things, steep views), or "auto": the
    station's, then, where it finds no rim, the photograph's; refused by both, the error gives
    both reasons."""
    from station.rim.camera_response import linear

    light, gain, brightest = _exposed(image, linear(image, gamma), name)
    try:
        return _with_gain(_searched(light, name, equalization, search), gain)
    except RimNotFound as e:
        if gain == 1.0:
            raise
        raise RimNotFound(f"{e.args[0]}. A dark photograph, its brightest grey level {brightest:.0f} of 255 "
                          f"(its light was taken {gain:.0f}x brighter)",
                          hint="photograph the wheel with a longer exposure or more light") from None


SEARCH_SIDE_PX = 3000  # a photograph larger than this is searched again smaller where nothing was found


def _searched(light: np.ndarray, name: str, equalization: str, search: str):
    """The rim ``search`` finds in ``light``, and where it finds none in a photograph larger than
    ``SEARCH_SIDE_PX`` ("auto", "photo"), the photograph search's rim in the photograph shrunk
    below it by an integer factor (area averages of light), in the full photograph's pixels.
    The photograph search's limits (an edge within 1 px of one curve, blurred under 4 px) are
    set in the pixels of a 5-Mpx photograph: in a 28-Mpx phone photograph the same lip's edge
    spreads over two or three times as many pixels. The station's search has its own working
    scale; shrunk, the one smooth edge it must show in a photograph would be judged in coarser
    pixels (a tyre's outline in a near-frontal photograph passed so)."""
    from station.rim.detector import _rescaled
    from station.rim.preprocess import downscale, to_grey

    try:
        return _searched_at(light, name, equalization, search)
    except RimNotFound as e:
        s = -(-max(light.shape[:2]) // SEARCH_SIDE_PX)
        if search == "station" or s == 1:
            raise
        try:
            det = _searched_at(downscale(to_grey(light, name), s), name, equalization, "photo")
        except RimNotFound:
            raise e from None
        return _rescaled(det, s)


def _searched_at(light: np.ndarray, name: str, equalization: str, search: str):
    """The rim ``search`` finds in ``light``; in a photograph ("auto", "photo") only where the
    same search finds it again in the photograph resized (station/rim/photo_stability.py)."""
    from station.rim.photo_search import where
    from station.rim.photo_stability import why_unstable

    det = _searched_once(light, name, equalization, search)
    if search == "station":
        return det
    why = why_unstable(lambda image: _searched_once(image, name, equalization, search), light, det.ellipse, name)
    if why is not None:
        raise RimNotFound(f"{name or 'image'}: the rim {where(det.ellipse)} is not sure: {why}",
                          hint="its tests hold only just: photograph the wheel nearer, in focus and from nearer its "
                               "front")
    return det


def _searched_once(light: np.ndarray, name: str, equalization: str, search: str):
    from station.rim import detect_rim
    from station.rim.photo_search import detect_in_photo

    if search == "photo":
        return _found_by("photo", detect_in_photo(light, camera_id=name))
    try:
        det = detect_rim(light, camera_id=name, equalization=equalization)
        if search == "auto":
            _stands_upright(det, name)
            _one_smooth_contour(det, name)
            _fills_the_frame(det, light.shape, name)
        return _found_by("station", det)
    except RimNotFound as station_error:
        if search == "station":
            raise
        try:
            return _found_by("photo", detect_in_photo(light, camera_id=name))
        except RimNotFound as photo_error:
            raise RimNotFound(f"{name or 'image'}: no rim found. The station's search: {sentence_without(name, station_error)}; "
                              f"the photograph search: {sentence_without(name, photo_error)}",
                              hint=photo_error.hint or station_error.hint) from None


EXPOSED_LIGHT_LEVEL = 128.0  # a dark photograph's light is scaled to put its brightest here


def _exposed(image: np.ndarray, light: np.ndarray, name: str) -> tuple[np.ndarray, float, float]:
    """(light, gain, the photograph's brightest grey level of 255): a photograph is judged black,
    saturated or flat in its own grey levels (the camera's encoding: an sRGB photograph whose
    brightest level is 40 of 255 is dark, not black, though its light is 2 % of full scale);
    light that dark is scaled up to EXPOSED_LIGHT_LEVEL (still proportional to light, so the
    edge model holds; float, so no level is lost) when the searches would take it for black
    (``exposure.BLACK_GREY``), gain 1 otherwise (the light as it was)."""
    from station.rim.exposure import BLACK_GREY, check_exposure, exposure_levels
    from station.rim.preprocess import to_grey

    brightest = check_exposure(to_grey(image, name), name or "image")
    if light is image:
        return light, 1.0, brightest
    lit = to_grey(light, name)
    hi = exposure_levels(lit)[1]
    if hi >= BLACK_GREY or hi <= 0:  # light the searches would not take for a black image
        return light, 1.0, brightest
    gain = EXPOSED_LIGHT_LEVEL / hi
    return np.minimum(lit * gain, 255.0).astype(np.float32), gain, brightest


def _with_gain(det, gain: float):
    if gain != 1.0:
        det.details["exposure_gain"] = round(gain, 2)
    return det


def _stands_upright(det, name: str) -> None:
    """RimNotFound for an ellipse a standing wheel cannot make. A rim's circle lies in a vertical
    plane: a camera beside it (a station's, a photographer's) sees its major axis near the
    vertical (within photo_search.MAX_TILT_DEG, for roll), and one looking down on it by an angle
    e sees the major axis level and b/a = cos e. With the same MAX_TILT_DEG allowed for looking
    down, an oval flatter than cos(MAX_TILT_DEG) = 0.87 lying on its side is not a wheel seen by
    a camera held about level: a badge, a lamp or a mirror."""
    from station.rim.photo_search import MAX_TILT_DEG, tilt_from_vertical_deg

    a, b = det.ellipse.axes_px
    tilt = tilt_from_vertical_deg(det.ellipse)
    if b / a < np.cos(np.radians(MAX_TILT_DEG)) and tilt > MAX_TILT_DEG:
        raise RimNotFound(f"{name or 'image'}: the ellipse found lies on its side (b/a {b / a:.2f}, major axis "
                          f"{tilt:.0f} deg off the vertical): not a standing wheel seen by a camera held level",
                          hint="a camera looking down on the wheel steeply: --search station")


def _one_smooth_contour(det, name: str) -> None:
    """RimNotFound for an edge that is not one smooth curve, as the photograph search refuses
    (photo_search.rough_edge_verdict). In a photograph the station's search may piece its contour
    from a steel wheel's disc and flange or the tyre's bead and the lip; a lip's edge is one curve."""
    from station.rim.photo_search import rough_edge_verdict

    why = rough_edge_verdict(det)
    if why is not None:
        raise RimNotFound(f"{name or 'image'}: {why}", hint="photograph the wheel in focus, the rim's whole edge in view")


FILLED_FRAME = 0.25  # the station's search in a photograph: its rim at least this share of the smaller side
#                     (the station's own cameras see a rim 0.5-0.65 of theirs; a near-frontal photograph
#                     cut round its wheel, 0.33-0.42; a fog lamp beside a wheel cut round so, 0.11)


def _fills_the_frame(det, shape: tuple, name: str) -> None:
    """RimNotFound for a rim of the station's search that does not fill the frame
    (``FILLED_FRAME``): that search is made for its cameras' views of one wheel filling the
    image, and judges a closed round contour by what lies round it alone. In a photograph a
    round lamp in its bezel passes that judgement; a wheel smaller in its photograph is the
    photograph search's to find, which refuses near-round candidates for that reason."""
    side = min(shape[:2])
    height = 2 * det.ellipse.axes_px[0]
    if height < FILLED_FRAME * side:
        raise RimNotFound(f"{name or 'image'}: the round contour found ({height:.0f} px high) fills "
                          f"{height / side:.0%} of the photograph's {side} px < {FILLED_FRAME:.0%}: the station's "
                          "search is for a wheel filling the frame",
                          hint="photograph a wheel seen from the front so that it fills the frame")


def _found_by(search: str, det):
    det.details["search"] = search
    return det


def detect_file(path: str | Path, gamma: float | None, equalization: str = "clahe", search: str = "auto"):
    """(image as read, RimDetection, the response gamma used and where it came from, seconds of
    search) of one image file, read once; ImageError / RimNotFound as ``read_image`` and
    ``detect_photograph`` raise them."""
    image, said = read_photograph(path)
    gamma, source = said if gamma is None else (gamma, "--response-gamma")
    t0 = time.perf_counter()
    det = detect_photograph(image, gamma, Path(path).name, equalization, search)
    det.details.update(response_gamma=gamma, response_from=source)
    return image, det, gamma, time.perf_counter() - t0
