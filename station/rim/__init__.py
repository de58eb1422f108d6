"""Rim detection (paper sections 2.1-2.2 and 3.1): find the rim-flange ellipse in one image.

    from station.rim import detect_rim, RimDetection, Ellipse
    det = detect_rim(image, camera=None, prior=None, camera_id="cam5")

See docs/rim-detection.md for the pipeline, the voting scheme and measured accuracy.
"""

from station.rim.detector import RimDetection, detect_rim
from station.rim.ellipse import Ellipse

__all__ = ["detect_rim", "RimDetection", "Ellipse"]
