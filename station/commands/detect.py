"""`station detect IMAGE...`: find the rim ellipse in a photograph of a wheel (several, or a
folder of them: station/commands/detect_batch.py)."""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from station.commands import detect_batch
from station.commands.detect_photograph import SEARCHES, detect_file
from station.commands.photo_files import detection_doc, draw, drawing_name, write_json
from station.errors import ImageError


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


def run(args) -> int:
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
