"""`station detect IMAGE...`: find the rim ellipse in a photograph of a wheel (several, or a
folder of them: station/commands/detect_batch.py)."""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from station.errors import ImageError, RimNotFound, StorageError, sentence_without

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
JPEG_MAGIC = b"\xff\xd8"
SRGB_GAMMA = 0.45  # sRGB's curve, as one exponent
SEARCHES = ("auto", "station", "photo")


def add_arguments(parser):
    parser.add_argument("image", metavar="IMAGE", nargs="+",
                        help="the photograph (PNG, JPEG, BMP, TIFF); several, or a folder of them: one line each as "
                             "it is searched, then a summary (exit code 1 if any has no rim found)")
    parser.add_argument("--json", metavar="PATH",
                        help="write the detection as JSON to PATH ('-': stdout); of several images, one document "
                             "with every image's detection or error and the summary")
    parser.add_argument("--draw", metavar="OUT.png", type=drawing_path,
                        help="draw the rim ellipse and its edge points on the image (.png, .jpg, .bmp, .tif, ...); "
                             "of several images, a folder: NAME.rim.png for each rim found")
    parser.add_argument("--search", choices=SEARCHES, default="auto",
                        help="auto (default): the station's search, and where it finds no rim the photograph search; "
                             "station: only the station's own search, as station measure runs it on its cameras' "
                             "near-frontal views; photo: only the search for a wheel in a street photograph, steep "
                             "side views among other things (docs/rim-detection.md, 'Photographs')")
    parser.add_argument("--equalization", choices=("clahe", "global", "none"), default="clahe",
                        help="equalisation before Canny: clahe (default), global (the paper's), none")
    parser.add_argument("--response-gamma", type=float, default=None, metavar="G",
                        help="the exponent the camera applied to light (grey = light^G), undone before the "
                             "sub-pixel edges: 1 for a linear machine-vision camera, about 0.45 for sRGB; "
                             "default: 0.45 for a JPEG (a phone's or webcam's photograph), a PNG's as its sRGB, gAMA, "
                             "iCCP or cICP chunk says, else 1 (a machine-vision camera's linear grey)")


def drawing_path(text: str) -> str:
    """--draw's path: an existing folder (the drawings of several images), or a file whose suffix
    names a format OpenCV writes (checked before the detection)."""
    import cv2

    if not Path(text).is_dir() and not cv2.haveImageWriter(text):
        suffix = Path(text).suffix
        raise argparse.ArgumentTypeError(
            f"cannot write a drawing to {text!r}: " + (f"no image format has the suffix {suffix!r}" if suffix
                                                     else "the name has no image suffix") + "; use .png or .jpg")
    return text


def read_image(path: str | Path) -> np.ndarray:
    """Read an image file as it is stored (grey, BGR or 16-bit; an alpha channel dropped), turned
    upright as its EXIF orientation says; ImageError for anything unusable, including a truncated
    PNG or JPEG (which decoders otherwise half-decode silently)."""
    import cv2

    path = Path(path)
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        raise ImageError(f"{path}: no such file", hint="check the path") from None
    except IsADirectoryError:
        raise ImageError(f"{path}: is a directory, not an image") from None
    except OSError as e:
        raise ImageError(f"{path}: cannot be read ({e.strerror})") from e
    if not data:
        raise ImageError(f"{path}: the file is empty")
    if data.startswith(PNG_MAGIC) and b"IEND" not in data[-64:]:
        raise ImageError(f"{path}: the PNG file is truncated (no end chunk)",
                         hint="copy the image again; the file was cut short")
    if data.startswith(JPEG_MAGIC) and b"\xff\xd9" not in data[data.rfind(b"\xff\xda"):]:
        raise ImageError(f"{path}: the JPEG file is truncated (no end marker)",
                         hint="copy the image again; the file was cut short")
    try:
        # any depth and colour as stored, turned as the EXIF orientation says (a phone's portrait photograph)
        image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_ANYDEPTH | cv2.IMREAD_ANYCOLOR)
    except cv2.error as e:
        raise ImageError(f"{path}: cannot be decoded as an image ({e.err})") from e
    if image is None:
        raise ImageError(f"{path}: not a readable image (PNG, JPEG, BMP or TIFF expected)",
                         hint="check that the file is an image and not damaged")
    return image


def draw(image: np.ndarray, det, path: str | Path) -> None:
    import cv2

    if image.dtype != np.uint8:
        image = (image / 257).astype(np.uint8) if image.dtype == np.uint16 else np.clip(image, 0, 255).astype(np.uint8)
    out = cv2.cvtColor(image, cv2.COLOR_GRAY2BGR) if image.ndim == 2 else image.copy()
    thick = max(1, round(max(out.shape[:2]) / 600))
    e = det.ellipse
    pts = e.points(720)
    if det.ellipse_frame != "pixels":  # drawn where the rim is in the (distorted) image: the points
        pts = det.points_px
    for p in det.points_px[:: max(1, len(det.points_px) // 120)]:  # edge points under the curve
        cv2.circle(out, (int(round(p[0])), int(round(p[1]))), 2 * thick, (0, 255, 0), -1)
    shift = 4
    poly = np.round(pts * (1 << shift)).astype(np.int32).reshape(-1, 1, 2)
    cv2.polylines(out, [poly], True, (0, 0, 255), thick, cv2.LINE_AA, shift)
    c = np.round(e.center_px * (1 << shift)).astype(np.int32)
    cv2.drawMarker(out, tuple(int(x) >> shift for x in c), (0, 255, 255), cv2.MARKER_CROSS, 10 * thick, thick)
    label = f"rim a={e.axes_px[0]:.1f} b={e.axes_px[1]:.1f} px  score {det.score:.2f}"
    cv2.putText(out, label, (10, 10 + 20 * thick), cv2.FONT_HERSHEY_SIMPLEX, 0.6 * thick, (0, 0, 255), thick, cv2.LINE_AA)
    try:
        written = cv2.imwrite(str(path), out)
    except cv2.error as e:  # OpenCV raises for a suffix it has no writer for
        raise ImageError(f"{path}: cannot write the drawing ({e.err})", hint="use a .png or .jpg path") from e
    if not written:
        raise ImageError(f"{path}: cannot write the drawing (is the directory there, is the suffix .png/.jpg?)")


def default_gamma(path: str | Path) -> float:
    """The response a file's grey levels are taken to have (``file_response``)."""
    return file_response(path)[0]


def file_response(path: str | Path) -> tuple[float, str]:
    """(gamma, where it comes from) of a file's grey levels, grey = light^gamma: a JPEG is a
    photograph's format, sRGB-encoded (SRGB_GAMMA); a PNG as its colour chunks say (``png_response``),
    linear (1) without one (a machine-vision camera's grey, as `station capture` writes it);
    any other file linear."""
    with open(path, "rb") as f:
        head = f.read(1 << 16)
    if head.startswith(JPEG_MAGIC):
        return SRGB_GAMMA, "a JPEG: sRGB"
    if head.startswith(PNG_MAGIC):
        said = png_response(head)
        if said is not None:
            return said
    return 1.0, "linear"


def png_response(data: bytes) -> tuple[float, str] | None:
    """(gamma, which chunk) that a PNG's colour chunks before its image data give, in the PNG
    standard's precedence (cICP, iCCP, sRGB, gAMA), or None without any. cICP names its transfer
    (8: linear, else sRGB-like); an ICC profile and the sRGB chunk mean sRGB's curve; gAMA holds
    the encoding exponent x 100000."""
    chunks, pos = {}, len(PNG_MAGIC)
    while pos + 8 <= len(data):
        length = int.from_bytes(data[pos:pos + 4], "big")
        kind = data[pos + 4:pos + 8]
        if kind in (b"IDAT", b"IEND"):
            break
        chunks.setdefault(kind, data[pos + 8:pos + 8 + length])
        pos += 12 + length
    if b"cICP" in chunks and len(chunks[b"cICP"]) >= 2:
        return (1.0, "the PNG's cICP chunk: linear") if chunks[b"cICP"][1] == 8 else (SRGB_GAMMA, "the PNG's cICP chunk")
    if b"iCCP" in chunks:
        return SRGB_GAMMA, "the PNG's ICC profile"
    if b"sRGB" in chunks:
        return SRGB_GAMMA, "the PNG's sRGB chunk"
    if b"gAMA" in chunks and len(chunks[b"gAMA"]) == 4:
        g = int.from_bytes(chunks[b"gAMA"], "big") / 100000
        if 0.2 <= g <= 5:
            return g, "the PNG's gAMA chunk"
    return None


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
    ``SEARCH_SIDE_PX`` ("auto", "photo"), in the photograph shrunk below it by an integer factor
    (area averages of light), in the full photograph's pixels. The photograph search's limits
    (an edge within 1 px of one curve, blurred under 4 px) are set in the pixels of a 5-Mpx
    photograph: in a 28-Mpx phone photograph the same lip's edge spreads over two or three
    times as many pixels."""
    from station.rim.detector import _rescaled
    from station.rim.preprocess import downscale, to_grey

    try:
        return _searched_at(light, name, equalization, search)
    except RimNotFound as e:
        s = -(-max(light.shape[:2]) // SEARCH_SIDE_PX)
        if search == "station" or s == 1:
            raise
        try:
            det = _searched_at(downscale(to_grey(light, name), s), name, equalization, search)
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
    search) of one image file; ImageError / RimNotFound as ``read_image`` and
    ``detect_photograph`` raise them."""
    image = read_image(path)
    gamma, source = file_response(path) if gamma is None else (gamma, "--response-gamma")
    t0 = time.perf_counter()
    det = detect_photograph(image, gamma, Path(path).name, equalization, search)
    det.details.update(response_gamma=gamma, response_from=source)
    return image, det, gamma, time.perf_counter() - t0


def run(args) -> int:
    from station.commands import detect_batch

    gamma = args.response_gamma
    if gamma is not None and not 0.2 <= gamma <= 5:
        raise ImageError(f"--response-gamma {gamma}: expected a value in [0.2, 5]",
                         hint="1 for a linear camera, about 0.45 for an sRGB photograph")
    if len(args.image) > 1 or Path(args.image[0]).is_dir():
        return detect_batch.run(args, detect_batch.image_paths(args.image))
    path = args.image[0]
    image, det, gamma, seconds = detect_file(path, gamma, args.equalization, args.search)
    wall_ms = seconds * 1e3
    e = det.ellipse
    std = np.sqrt(np.maximum(np.diag(det.ellipse_cov), 0))
    print(f"rim ellipse in {path} ({image.shape[1]}x{image.shape[0]} px)")
    print(f"  centre      u = {e.center_px[0]:9.3f} px   v = {e.center_px[1]:9.3f} px   (+/- {std[0]:.3f}, {std[1]:.3f})")
    print(f"  semi-axes   a = {e.axes_px[0]:9.3f} px   b = {e.axes_px[1]:9.3f} px   (+/- {std[2]:.3f}, {std[3]:.3f})")
    print(f"  angle         {np.degrees(e.angle_rad):9.3f} deg  (b/a = {e.axes_px[1] / e.axes_px[0]:.4f})")
    print(f"  score         {det.score:9.3f}      edge points {len(det.points_px)}, "
          f"rms {det.point_sigma_px:.3f} px, coverage {det.coverage:.0%}")
    print(f"  edge blur     {det.details.get('blur_px', float('nan')):9.2f} px (Gaussian sigma of the rim edge)")
    print(f"  search        {det.details.get('search', args.search):>9}      (--search: {args.search})")
    print(f"  grey response {gamma:9.2f}      (grey = light^{gamma:.2f}, undone; from {det.details['response_from']}; "
          "--response-gamma to change)")
    if "exposure_gain" in det.details:
        print(f"  exposure gain {det.details['exposure_gain']:9.1f}      (a dark photograph: its light taken this much brighter)")
    white = det.details.get("white_share", 0.0)
    if white > 0:
        print(f"  at the white  {white:9.0%}      of the rim edge reaches the sensor's white: the edge found lies "
              f"toward the tyre there; shorten the exposure")
    dark = det.details.get("metal_side_dark_share", 0.0)
    if dark > 0:
        print(f"  dark lip      {dark:9.0%}      of the rim edge has a lip no brighter than the tyre beside it: the "
              f"edge found there is not the rim's (a tyre lit past a shaded lip, a dirty lip, a glossy lip mirroring "
              f"something dark)")
    print(f"  time          {wall_ms:9.1f} ms      (the whole search; the last sub-pixel fit's stages "
          f"{sum(det.timing_s.values()) * 1e3:.1f} ms)")
    if args.json:
        write_json(args.json, detection_doc(path, image, det, args.search))
    if args.draw:
        draw(image, det, Path(args.draw) / drawing_name(Path(path)) if Path(args.draw).is_dir() else args.draw)
    return 0


def detection_doc(path: str | Path, image: np.ndarray, det, search: str) -> dict:
    """One image's detection as the JSON output has it."""
    return {"image": str(path), "width": int(image.shape[1]), "height": int(image.shape[0]),
            "search": det.details.get("search", search), "response_gamma": det.details.get("response_gamma"),
            "response_from": det.details.get("response_from"), **det.to_dict()}


def drawing_name(path: Path) -> str:
    """The drawing of ``path``'s rim in a --draw folder."""
    return f"{path.stem}.rim.png"


def write_json(target: str, doc) -> None:
    """``doc`` as indented JSON to the file ``target``, or to stdout for '-'."""
    text = json.dumps(doc, indent=1)
    if target == "-":
        print(text)
        return
    try:
        Path(target).write_text(text)
    except OSError as ex:
        raise StorageError(f"{target}: cannot write the JSON ({ex.strerror})") from ex
