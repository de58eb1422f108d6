"""Photograph files for `station detect`: reading one (upright, as stored), the response its grey
levels encode light with, a drawing of the rim found and the JSON written of it."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from station.errors import ImageError, StorageError

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
JPEG_MAGIC = b"\xff\xd8"
SRGB_GAMMA = 0.45  # sRGB's curve, as one exponent


def read_image(path: str | Path) -> np.ndarray:
    """Read an image file as it is stored (grey, BGR or 16-bit; an alpha channel dropped), turned
    upright as its EXIF orientation says; ImageError for anything unusable, including a truncated
    PNG or JPEG (which decoders otherwise half-decode silently)."""
    return _decoded(_file_bytes(path), Path(path))


def read_photograph(path: str | Path) -> tuple[np.ndarray, tuple[float, str]]:
    """(the image as ``read_image`` reads it, (gamma, where from) as ``file_response`` gives it),
    the file read once."""
    data = _file_bytes(path)
    return _decoded(data, Path(path)), bytes_response(data[:RESPONSE_HEAD_BYTES])


def _file_bytes(path: str | Path) -> bytes:
    path = Path(path)
    try:
        return path.read_bytes()
    except FileNotFoundError:
        raise ImageError(f"{path}: no such file", hint="check the path") from None
    except IsADirectoryError:
        raise ImageError(f"{path}: is a directory, not an image") from None
    except OSError as e:
        raise ImageError(f"{path}: cannot be read ({e.strerror})") from e


def _decoded(data: bytes, path: Path) -> np.ndarray:
    import cv2

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


def drawing_name(path: Path) -> str:
    """The drawing of ``path``'s rim in a --draw folder."""
    return f"{path.stem}.rim.png"


def default_gamma(path: str | Path) -> float:
    """The response a file's grey levels are taken to have (``file_response``)."""
    return file_response(path)[0]


RESPONSE_HEAD_BYTES = 1 << 16  # a file's start, where a PNG's colour chunks sit (before its image data)


def file_response(path: str | Path) -> tuple[float, str]:
    """(gamma, where it comes from) of a file's grey levels, grey = light^gamma (``bytes_response``
    of its first RESPONSE_HEAD_BYTES)."""
    with open(path, "rb") as f:
        return bytes_response(f.read(RESPONSE_HEAD_BYTES))


def bytes_response(head: bytes) -> tuple[float, str]:
    """(gamma, where it comes from) of the grey levels of a file starting with ``head``: a JPEG is
    a photograph's format, sRGB-encoded (SRGB_GAMMA); a PNG as its colour chunks say
    (``png_response``), linear (1) without one (a machine-vision camera's grey, as `station
    capture` writes it); any other file linear."""
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


def detection_doc(path: str | Path, image: np.ndarray, det, search: str) -> dict:
    """One image's detection as the JSON output has it."""
    return {"image": str(path), "width": int(image.shape[1]), "height": int(image.shape[0]),
            "search": det.details.get("search", search), "response_gamma": det.details.get("response_gamma"),
            "response_from": det.details.get("response_from"), **det.to_dict()}


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
