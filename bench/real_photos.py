"""Rim detection on real street photographs with hand-marked rim points.

    .venv/bin/python bench/real_photos.py                     # all photos, markdown table
    .venv/bin/python bench/real_photos.py --split dev --per-photo
    .venv/bin/python bench/real_photos.py --data DIR --json out.json
    .venv/bin/python bench/real_photos.py --perturb mirror       # or smaller, farther, nearer, rolled, cropped, frontal, darker,
                                                                 # dark, contrast, flat, noisy, jpeg, blurred, linear: as if other photos

The photographs are read from ``../shared/data/real-wheels`` (``--data``; never copied into the
repository): ``images/NAME.jpg`` and ``annotations/NAME.json`` with, per marked wheel, its box
and keypoints 0 (top of the rim), 1 (bottom of the rim), 2 (the rim's near side), all on the
rim's outer edge where it meets the tyre (README there). Each photo goes through exactly what
``station detect PHOTO`` runs (``station.commands.detect_photograph``: read, the JPEG's sRGB response
undone, the detection), one photo at a time, on this process's one core.

Definitions (per photo; ``station detect`` returns at most one rim):

* a marked wheel's **rim height** h = |keypoint 1 - keypoint 0| (px);
* a detection **matches** a marked wheel when every visible rim keypoint (0, 1, 2) lies within
  ``MATCH_SHARE`` x h (but at least ``MATCH_MIN_PX``) of the detected ellipse (orthogonal
  distance) and the ellipse's centre lies inside the wheel's box. A photo is **detected** when
  its detection matches a marked wheel (the best matching one, by median keypoint distance);
* a **wrong object** is a detection that matches no marked wheel: a lamp, a grille, the tyre's
  outline, a hub, a wheel nobody marked. Those whose centre lies inside a marked wheel's box are
  counted apart as "wrong contour on a marked wheel";
* **keypoint distances**: over the detected photos, the distance of each visible rim keypoint
  (0, 1, 2) of the matched wheel to the detected ellipse: median, 90th percentile, share under
  5 px;
* a **refusal** is a RimNotFound / ImageError; its reason is the message up to the first
  parenthesis or colon after the photo's name, counted per kind;
* **time**: wall seconds of the detection per photo (decoding excluded), median and max.

The split: ``dev`` are the first ``DEV_COUNT`` photos by name, ``held`` the rest; the table has
a row for each and one for all.
"""

from __future__ import annotations

import argparse
import json
import os
import sys

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):  # one core
    os.environ.setdefault(_var, "1")
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from station.commands.detect_batch import refusal_kind  # noqa: E402
from station.commands.detect_photograph import detect_photograph  # noqa: E402
from station.commands.photo_files import SRGB_GAMMA, default_gamma, read_image  # noqa: E402
from station.errors import StationError  # noqa: E402
from station.rim.ellipse import Ellipse  # noqa: E402

DEFAULT_DATA = ROOT.parent / "shared" / "data" / "real-wheels"
DEV_COUNT = 40
MATCH_SHARE = 0.1   # of the rim height: a matching ellipse passes this near every marked rim point
MATCH_MIN_PX = 10.0
RIM_KEYPOINTS = (0, 1, 2)
FOOT_SAMPLES = 4096   # points round an ellipse to start each mark's foot from


@dataclass
class Wheel:
    """One marked wheel: box (x1, y1, x2, y2) and its visible rim keypoints (K,2)."""

    box: tuple[float, float, float, float]
    rim_points: np.ndarray
    height_px: float

    def contains(self, p) -> bool:
        x1, y1, x2, y2 = self.box
        return bool(x1 <= p[0] <= x2 and y1 <= p[1] <= y2)


@dataclass
class Outcome:
    name: str
    status: str                      # "detected", "wrong object", "wrong contour", "refused"
    seconds: float = 0.0
    reason: str = ""
    distances_px: list = field(default_factory=list)
    ellipse: dict | None = None


def load_wheels(path: Path) -> list[Wheel]:
    doc = json.loads(path.read_text())
    wheels = []
    for box, kps in zip(doc["bboxes"], doc["keypoints"]):
        k = np.asarray(kps, float)
        vis = [i for i in RIM_KEYPOINTS if k[i, 2] > 0]
        wheels.append(Wheel(tuple(box), k[vis, :2], float(np.hypot(*(k[1, :2] - k[0, :2])))))
    return wheels


def exact_distance_px(ellipse: Ellipse, pts: np.ndarray) -> np.ndarray:
    """(K,) signed distance (+ outside) of the points (K,2) to ``ellipse``, exact wherever the
    points lie. ``Ellipse.distance`` starts Newton's method from a point's angle, which is exact
    near the curve (the edge points it is made for) but can run off for a mark far inside a
    steep ellipse, near its major axis: the nearest of ``FOOT_SAMPLES`` points round the
    ellipse starts it here instead."""
    t = np.linspace(0.0, 2 * np.pi, FOOT_SAMPLES, endpoint=False)
    along = ellipse.point_at(t)                                                    # (S,2)
    near = np.argmin(((pts[:, None, :] - along[None]) ** 2).sum(axis=2), axis=1)  # (K,)
    return ellipse.distance(pts, iterations=8, t0=t[near])[0]


def judge(ellipse: Ellipse, wheels: list[Wheel]) -> tuple[str, list[float]]:
    """("detected", distances of the matched wheel's rim points) or a wrong-object kind."""
    best = None
    for w in wheels:
        if len(w.rim_points) == 0:
            continue
        d = np.abs(exact_distance_px(ellipse, w.rim_points))
        if w.contains(ellipse.center_px) and np.all(d <= max(MATCH_SHARE * w.height_px, MATCH_MIN_PX)):
            if best is None or np.median(d) < np.median(best):
                best = d
    if best is not None:
        return "detected", [float(x) for x in best]
    on_wheel = any(w.contains(ellipse.center_px) for w in wheels)
    return ("wrong contour" if on_wheel else "wrong object"), []


PERTURBATIONS = ("none", "mirror", "smaller", "farther", "nearer", "larger", "rolled", "cropped", "frontal", "darker", "dark",
                 "contrast", "flat", "noisy", "jpeg", "blurred", "linear")
ROLL_DEG = 8.0      # "rolled": the camera turned about its axis
FRONTAL_RATIO = 0.9  # "frontal": the largest marked rim's axis ratio b/a after the stretch
CUT_MARGIN = 0.5      # "cropped", "frontal": the cut reaches this share of the wheel's box height beyond its box
FRONTAL_MAX_STRETCH = 4.0
NOISE_GREY = 8.0     # "noisy": sensor noise (grey levels, sigma) of a small sensor at a high ISO
JPEG_QUALITY = 25    # "jpeg": saved again, strongly compressed


def _frontal_stretch(wheel: Wheel) -> float:
    """How much ``wheel`` is stretched across for its rim to look near-frontal (b/a
    FRONTAL_RATIO, at most FRONTAL_MAX_STRETCH). The rim's half-width is the near-side mark's
    distance from the line through the top and bottom marks; a wheel without all three marks
    has its box's half-width instead."""
    if len(wheel.rim_points) == 3:
        top, bottom, side = wheel.rim_points
        along = (bottom - top) / max(float(np.hypot(*(bottom - top))), 1e-9)
        off = side - 0.5 * (top + bottom)
        half_width = abs(float(off[0] * along[1] - off[1] * along[0]))
    else:
        half_width = 0.5 * (wheel.box[2] - wheel.box[0])
    return float(np.clip(FRONTAL_RATIO * 0.5 * wheel.height_px / max(half_width, 1.0), 1.0, FRONTAL_MAX_STRETCH))


def _cut_round(image: np.ndarray, wheels: list[Wheel], frontal: bool) -> tuple[np.ndarray, list[Wheel]]:
    """The photograph cut round its largest marked wheel (CUT_MARGIN), with ``frontal``
    stretched across so that its rim looks near-frontal (:func:`_frontal_stretch`), and the marks
    moved with it."""
    import cv2

    wheel = max(wheels, key=lambda wh: wh.height_px)
    x1, y1, x2, y2 = wheel.box
    stretch = _frontal_stretch(wheel) if frontal else 1.0
    margin = CUT_MARGIN * (y2 - y1)
    h, w = image.shape[:2]
    c0, r0 = int(max(0, x1 - margin)), int(max(0, y1 - margin))
    c1, r1 = int(min(w, x2 + margin)), int(min(h, y2 + margin))
    crop = image[r0:r1, c0:c1]
    out = cv2.resize(crop, (int(round(crop.shape[1] * stretch)), crop.shape[0]), interpolation=cv2.INTER_CUBIC)

    def moved(p):  # (N,2) photo px -> (N,2) px of the stretched crop (pixel centres map to centres)
        p = np.asarray(p, float).reshape(-1, 2)
        return np.column_stack([(p[:, 0] - c0 + 0.5) * stretch - 0.5, p[:, 1] - r0])

    def box(b):
        (bx1, by1), (bx2, by2) = moved([[b[0], b[1]], [b[2], b[3]]])
        return (bx1, by1, bx2, by2)

    return out, [Wheel(box(wh.box), moved(wh.rim_points), wh.height_px) for wh in wheels]


def perturbed(image: np.ndarray, wheels: list[Wheel], kind: str) -> tuple[np.ndarray, list[Wheel]]:
    """The photograph and its marks changed as another photographer might have taken it:
    ``mirror`` (left and right swapped: the car seen from its other side), ``smaller`` (0.7 of
    the size: from farther away, some rims then under 100 px), ``farther`` (0.5 of the size: most
    rims under 100 px, too small to take), ``nearer`` (1.5 times the size: rims up to 1200 px,
    the edges spread over more pixels), ``larger`` (2.3 times: some 6000 x 4700 px, a phone's
    28 Mpx, rims up to 1800 px high, the edges blurred over 3-6 px), ``rolled`` (turned ROLL_DEG about the photo's centre:
    the camera held askew, every rim's major axis that far off the vertical), ``cropped`` (cut
    round the largest marked wheel, as a refusal's hint asks: :func:`_cut_round`), ``frontal``
    (cut so and stretched across until its rim looks near-frontal, as the station's own cameras
    see it), ``darker`` (0.6 of the grey
    levels: a shorter exposure, a dull day), ``dark`` (0.15 of the grey levels: an sRGB photograph
    some five stops under-exposed, its light about 2 % of the original's), ``contrast`` and
    ``flat`` (another camera's tone curve: grey^1.5 and grey^0.7 on 0..1, read as sRGB all the
    same), ``noisy`` (sensor noise of NOISE_GREY grey levels), ``jpeg`` (saved again at quality
    JPEG_QUALITY: blocks and ringing at the edges), ``blurred`` (a Gaussian blur of 6 px: out
    of focus or shaken), ``linear`` (the sRGB curve undone into 16-bit grey proportional to
    light, as a machine-vision camera's PNG: measured with response 1, a PNG's default)."""
    if kind == "mirror":
        w = image.shape[1]
        flip = [Wheel((w - 1 - x2, y1, w - 1 - x1, y2), np.column_stack([w - 1 - k[:, 0], k[:, 1]]) if len(k) else k,
                      h) for (x1, y1, x2, y2), k, h in ((wh.box, wh.rim_points, wh.height_px) for wh in wheels)]
        return np.ascontiguousarray(image[:, ::-1]), flip
    if kind == "rolled":
        import cv2

        h, w = image.shape[:2]
        M = cv2.getRotationMatrix2D(((w - 1) / 2, (h - 1) / 2), ROLL_DEG, 1.0)   # (2,3)

        def moved(p):  # (N,2) -> (N,2)
            return p @ M[:, :2].T + M[:, 2] if len(p) else p

        def box(b):
            x1, y1, x2, y2 = b
            c = moved(np.array([[x1, y1], [x2, y1], [x1, y2], [x2, y2]], float))
            return (*c.min(axis=0), *c.max(axis=0))

        return (cv2.warpAffine(image, M, (w, h), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE),
                [Wheel(box(wh.box), moved(wh.rim_points), wh.height_px) for wh in wheels])
    if kind in ("cropped", "frontal"):
        return _cut_round(image, wheels, kind == "frontal")
    if kind in ("smaller", "farther", "nearer", "larger"):
        import cv2

        f = {"smaller": 0.7, "farther": 0.5, "nearer": 1.5, "larger": 2.3}[kind]
        return (cv2.resize(image, None, fx=f, fy=f, interpolation=cv2.INTER_AREA if f < 1 else cv2.INTER_CUBIC),
                [Wheel(tuple(f * np.asarray(wh.box)), f * wh.rim_points, f * wh.height_px) for wh in wheels])
    if kind in ("darker", "dark"):
        f = 0.6 if kind == "darker" else 0.15
        return (f * image.astype(np.float32)).round().astype(image.dtype), wheels
    top = 255.0 if image.dtype == np.uint8 else 65535.0   # the file's white
    if kind in ("contrast", "flat"):  # another camera's tone curve: grey' = grey^p on 0..1
        p = 1.5 if kind == "contrast" else 0.7
        return np.clip(top * (image.astype(np.float32) / top) ** p + 0.5, 0, top).astype(image.dtype), wheels
    if kind == "noisy":
        noise = np.random.default_rng(0).normal(0.0, NOISE_GREY * top / 255.0, image.shape)
        return np.clip(image.astype(np.float32) + noise + 0.5, 0, top).astype(image.dtype), wheels
    if kind == "linear":  # as a machine-vision camera gives it: 16-bit grey proportional to light
        light = (image.astype(np.float64) / top) ** (1.0 / SRGB_GAMMA)
        return np.round(65535.0 * light).astype(np.uint16), wheels
    if kind == "jpeg":
        import cv2

        ok, data = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])
        return cv2.imdecode(data, cv2.IMREAD_UNCHANGED), wheels
    if kind == "blurred":
        import cv2

        return cv2.GaussianBlur(image, (0, 0), 6.0), wheels
    return image, wheels


def run_photo(image_path: Path, wheels: list[Wheel], gamma: float | None = None, search: str = "auto",
              perturbation: str = "none") -> Outcome:
    name = image_path.name
    try:
        image = read_image(image_path)
    except StationError as e:
        return Outcome(name, "refused", reason=refusal_kind(str(e)))
    image, wheels = perturbed(image, wheels, perturbation)
    t0 = time.perf_counter()
    try:
        if gamma is None:
            gamma = 1.0 if perturbation == "linear" else default_gamma(image_path)
        det = detect_photograph(image, gamma, name, search=search)
    except StationError as e:
        return Outcome(name, "refused", time.perf_counter() - t0, refusal_kind(str(e)))
    seconds = time.perf_counter() - t0
    status, dist = judge(det.ellipse, wheels)
    return Outcome(name, status, seconds, distances_px=dist, ellipse=det.ellipse.to_dict())


def summary(rows: list[Outcome]) -> dict:
    n = len(rows)
    dist = np.array([d for r in rows for d in r.distances_px])
    times = np.array([r.seconds for r in rows if r.seconds > 0])
    reasons: dict[str, int] = {}
    for r in rows:
        if r.status == "refused":
            reasons[r.reason] = reasons.get(r.reason, 0) + 1
    count = {k: sum(r.status == k for r in rows) for k in ("detected", "wrong object", "wrong contour", "refused")}
    return {"photos": n, **count,
            "detected_share": count["detected"] / n if n else float("nan"),
            "points": int(len(dist)),
            "median_px": float(np.median(dist)) if len(dist) else float("nan"),
            "p90_px": float(np.percentile(dist, 90)) if len(dist) else float("nan"),
            "under_5px": float(np.mean(dist < 5)) if len(dist) else float("nan"),
            "time_median_s": float(np.median(times)) if len(times) else float("nan"),
            "time_max_s": float(times.max()) if len(times) else float("nan"),
            "refusals": dict(sorted(reasons.items(), key=lambda kv: -kv[1]))}


def table(parts: dict[str, dict]) -> str:
    lines = ["| photos | detected | keypoint distance median / p90 (px) | under 5 px | wrong objects "
             "(of them wrong contour on a marked wheel) | refused | time median / max (s) |",
             "|---|---|---|---|---|---|---|"]
    for label, s in parts.items():
        lines.append(f"| {label} ({s['photos']}) | {s['detected']} ({s['detected_share']:.0%}) | "
                     f"{s['median_px']:.1f} / {s['p90_px']:.1f} ({s['points']} points) | {s['under_5px']:.0%} | "
                     f"{s['wrong object'] + s['wrong contour']} ({s['wrong contour']}) | {s['refused']} | "
                     f"{s['time_median_s']:.2f} / {s['time_max_s']:.2f} |")
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", type=Path, default=DEFAULT_DATA, help="folder with images/ and annotations/")
    ap.add_argument("--split", choices=("all", "dev", "held"), default="all")
    ap.add_argument("--only", nargs="*", help="photo names (without .jpg) to run")
    ap.add_argument("--response-gamma", type=float, help="as station detect's (default: 0.45 for a JPEG)")
    ap.add_argument("--search", choices=("auto", "station", "photo"), default="auto", help="as station detect's")
    ap.add_argument("--perturb", choices=PERTURBATIONS, default="none",
                    help="each photo changed first, as another photographer's might be (see perturbed()): does it hold on other photos?")
    ap.add_argument("--per-photo", action="store_true", help="one line per photo")
    ap.add_argument("--json", type=Path, help="write every outcome and the summaries here")
    args = ap.parse_args(argv)
    images = sorted((args.data / "images").glob("*.jpg"))
    if not images:
        print(f"no photographs in {args.data / 'images'}: give --data DIR", file=sys.stderr)
        return 2
    split = {p.stem: ("dev" if k < DEV_COUNT else "held") for k, p in enumerate(images)}
    if args.split != "all":
        images = [p for p in images if split[p.stem] == args.split]
    if args.only:
        images = [p for p in images if p.stem in set(args.only)]
    outcomes = []
    for p in images:
        r = run_photo(p, load_wheels(args.data / "annotations" / f"{p.stem}.json"), args.response_gamma,
                      args.search, args.perturb)
        outcomes.append(r)
        if args.per_photo:
            extra = r.reason if r.status == "refused" else (
                " ".join(f"{d:.1f}" for d in r.distances_px) if r.distances_px else str(r.ellipse))
            print(f"{r.name:12s} {split[p.stem]:4s} {r.status:13s} {r.seconds:5.2f} s  {extra}", flush=True)
    parts = {}
    for label in ("dev", "held"):
        rows = [r for r in outcomes if split[Path(r.name).stem] == label]
        if rows:
            parts[label] = summary(rows)
    if len(parts) > 1:
        parts["all"] = summary(outcomes)
    print(table(parts))
    for label, s in parts.items():
        if s["refusals"]:
            print(f"refusals ({label}): " + "; ".join(f"{k} x{v}" for k, v in s["refusals"].items()))
    if args.json:
        args.json.write_text(json.dumps({"summaries": parts, "photos": [r.__dict__ for r in outcomes]}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
