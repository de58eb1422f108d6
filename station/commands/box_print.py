"""`station box-print`: the calibration box's faces as PNG images at true scale.

One PNG per printed face (``box-<face>.png``) with its physical size and resolution written
into the PNG (pHYs chunk, pixels per metre) and into ``box-print.txt``, so a print shop can
reproduce it at 100 %.
"""

from __future__ import annotations

import zlib
from pathlib import Path

import cv2

from station.config import load_box, load_config
from station.errors import ConfigError, StorageError


def add_arguments(parser) -> None:
    parser.add_argument("--out", required=True, metavar="DIR", help="directory for the PNG files")
    parser.add_argument("--dpi", type=float, default=300.0, help="print resolution (dots per inch), default 300")


def _with_phys(png: bytes, px_per_m: float) -> bytes:
    """Insert a pHYs chunk (pixels per metre) after IHDR."""
    ppm = int(round(px_per_m))
    data = b"pHYs" + ppm.to_bytes(4, "big") * 2 + b"\x01"
    chunk = (9).to_bytes(4, "big") + data + zlib.crc32(data).to_bytes(4, "big")
    ihdr_end = 8 + 8 + 13 + 4
    return png[:ihdr_end] + chunk + png[ihdr_end:]


def run(args) -> int:
    config = load_config(args.config)
    box = load_box(config.box_path)
    if not 50 <= args.dpi <= 2400:
        raise ConfigError(f"--dpi {args.dpi}: expected a print resolution between 50 and 2400 dpi")
    out = Path(args.out)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise StorageError(f"{out}: cannot create the output directory ({e.strerror})") from None
    texel = 0.0254 / args.dpi
    lines = [f"calibration box {box.source}: size {box.size_m} m, squares {box.square_m * 1000:g} mm, "
             f"markers {box.marker_m * 1000:g} mm, {box.dictionary_name}; print at 100 %, {args.dpi:g} dpi"]
    for f in box.faces:
        img = box.face_texture(f, texel)
        ok, buf = cv2.imencode(".png", img)
        if not ok:
            raise StorageError(f"cannot encode face {f.name}")
        path = out / f"box-{f.name}.png"
        path.write_bytes(_with_phys(buf.tobytes(), 1.0 / texel))
        h, w = img.shape
        lines.append(f"{path.name}: {w} x {h} px = {w * texel * 1000:.1f} x {h * texel * 1000:.1f} mm "
                     f"(face {f.size_m[0] * 1000:g} x {f.size_m[1] * 1000:g} mm), marker ids {f.first_id}.."
                     f"{f.first_id + f.squares[0] * f.squares[1] // 2 - 1}")
        print(lines[-1])
    (out / "box-print.txt").write_text("\n".join(lines) + "\n")
    return 0
