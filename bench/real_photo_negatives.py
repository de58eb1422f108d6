"""Wrong objects on real clutter: `station detect` on parts of the street photographs with no wheel.

    .venv/bin/python bench/real_photo_negatives.py                  # station detect's default search
    .venv/bin/python bench/real_photo_negatives.py --search station --per-crop

From each photograph of ``../shared/data/real-wheels`` (bench/real_photos.py) up to three crops
that hold no marked wheel: the full-height strips left and right of every marked wheel's box and
the full-width strip above them (boxes grown by ``GROW`` of their size each way; crops narrower or
lower than ``MIN_CROP_PX`` are skipped). What is left there is the street's clutter: other cars'
bodies, badges, lamps, grilles, mirrors, windows, kerbs. Any rim ``station detect`` returns on such
a crop is a wrong object. Prints the crops tried, the wrong objects (photo, crop, which search,
where) and the time per crop.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from real_photos import DEFAULT_DATA, load_wheels  # noqa: E402
from station.commands.detect_photograph import SEARCHES, detect_photograph  # noqa: E402
from station.commands.photo_files import default_gamma, read_image  # noqa: E402
from station.errors import StationError  # noqa: E402

GROW = 0.15         # each marked wheel's box grown by this share of its size on every side
MIN_CROP_PX = 300   # a crop narrower or lower than this is skipped


def crops(shape: tuple[int, int], boxes: list[tuple[float, float, float, float]]) -> list[tuple[int, int, int, int]]:
    """(x0, y0, x1, y1) regions of an image of ``shape`` (H, W) clear of every box (x1, y1, x2, y2)."""
    h, w = shape
    grown = []
    for x1, y1, x2, y2 in boxes:
        gx, gy = GROW * (x2 - x1), GROW * (y2 - y1)
        grown.append((max(0, int(x1 - gx)), max(0, int(y1 - gy)), min(w, int(np.ceil(x2 + gx))),
                      min(h, int(np.ceil(y2 + gy)))))
    left = min(b[0] for b in grown)
    right = max(b[2] for b in grown)
    top = min(b[1] for b in grown)
    out = [(0, 0, left, h), (right, 0, w, h), (0, 0, w, top)]
    return [c for c in out if c[2] - c[0] >= MIN_CROP_PX and c[3] - c[1] >= MIN_CROP_PX]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", type=Path, default=DEFAULT_DATA)
    ap.add_argument("--search", choices=SEARCHES, default="auto", help="as station detect's")
    ap.add_argument("--per-crop", action="store_true", help="one line per crop")
    args = ap.parse_args(argv)
    images = sorted((args.data / "images").glob("*.jpg"))
    if not images:
        print(f"no photographs in {args.data / 'images'}", file=sys.stderr)
        return 2
    tried, wrong, seconds = 0, [], []
    for path in images:
        image = read_image(path)
        boxes = [w.box for w in load_wheels(args.data / "annotations" / f"{path.stem}.json")]
        for x0, y0, x1, y1 in crops(image.shape[:2], boxes):
            tried += 1
            t0 = time.perf_counter()
            try:
                det = detect_photograph(image[y0:y1, x0:x1], default_gamma(path), path.name, search=args.search)
                u, v = det.ellipse.center_px + (x0, y0)
                wrong.append(f"{path.name} crop ({x0}, {y0})-({x1}, {y1}): {det.details.get('search')} search, "
                             f"at ({u:.0f}, {v:.0f}) px, {2 * det.ellipse.axes_px[0]:.0f} px high")
                verdict = "WRONG OBJECT"
            except StationError as e:
                verdict = "refused: " + str(e).split(": ", 1)[-1][:90]
            seconds.append(time.perf_counter() - t0)
            if args.per_crop:
                print(f"{path.name} ({x0}, {y0})-({x1}, {y1}): {verdict}")
    print(f"\n{tried} crops without a marked wheel from {len(images)} photographs (--search {args.search}): "
          f"{len(wrong)} wrong objects; time per crop median {np.median(seconds):.2f} s, max {np.max(seconds):.2f} s")
    for line in wrong:
        print(f"  {line}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
