"""Find the calibration box in one image: ChArUco corners of every visible face, and the
box's vertices.

Markers are detected once for the whole image (one ArUco dictionary, distinct ids per face);
each face's markers then go to that face's ``cv2.aruco.CharucoDetector``, so a face that is
partly hidden (by the other faces, the image border, a hand) still gives the corners around
its visible markers. Every corner is refined to sub-pixel with ``cv2.cornerSubPix`` in a
window sized from the face's local square size, so it stays inside the white gap between the
chessboard corner and the neighbouring markers.

The vertices (the paper's ``B_k``) are found from the boards: each face with enough corners
gives a homography face-plane -> image, which places that face's four corners; a vertex seen
on two faces is the mean of both. These vertex pixels ignore lens distortion: they are for
the paper's closed-form start (calibration/box_linear.py); the refinement uses the corners.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from calibration.box_target import POINT_ID_STRIDE, BoxTarget

MIN_FACE_CORNERS = 6


@dataclass
class BoxDetection:
    """What one image shows of the box.

    ids: (N,) global point ids (face index * 1000 + ChArUco id). points_box: (N,3) their box
    coordinates. pixels: (N,2) sub-pixel corners. face: (N,) face index of each point.
    vertex_pixels: (8,2) pixels of the box vertices, NaN where no detected face shows them.
    faces: names of the faces found, with their corner counts.
    """

    ids: np.ndarray
    points_box: np.ndarray
    pixels: np.ndarray
    face: np.ndarray
    vertex_pixels: np.ndarray
    faces: dict = field(default_factory=dict)
    vertices_box: np.ndarray = field(default_factory=lambda: np.full((8, 3), np.nan))  # (8,3) B_k

    @property
    def n_points(self) -> int:
        return len(self.ids)

    @property
    def vertex_mask(self) -> np.ndarray:
        return np.all(np.isfinite(self.vertex_pixels), axis=1)

    def select(self, mask: np.ndarray) -> "BoxDetection":
        return BoxDetection(self.ids[mask], self.points_box[mask], self.pixels[mask], self.face[mask],
                            self.vertex_pixels, dict(self.faces), self.vertices_box)


def _to_gray(image: np.ndarray) -> np.ndarray:
    img = np.asarray(image)
    if img.ndim == 3:
        img = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY if img.shape[2] == 3 else cv2.COLOR_BGRA2GRAY)
    if img.dtype != np.uint8:
        img = cv2.normalize(img, None, 0, 255, cv2.NORM_MINMAX).astype(np.uint8)
    return img


class BoxDetector:
    """Detects a :class:`BoxTarget` in images. Reuse one instance for many images."""

    def __init__(self, box: BoxTarget, subpix: bool = True):
        self.box = box
        self.subpix = subpix
        params = cv2.aruco.DetectorParameters()
        params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
        self.marker_detector = cv2.aruco.ArucoDetector(box.dictionary, params)
        self.face_detectors = [cv2.aruco.CharucoDetector(f.board) for f in box.faces]
        self._face_of_marker = {mid: self.box.face(name).index for mid, name in box.marker_face.items()}

    def detect(self, image: np.ndarray) -> BoxDetection:
        gray = _to_gray(image)
        corners, ids, _ = self.marker_detector.detectMarkers(gray)
        out_ids, out_px, faces = [], [], {}
        homographies = {}
        if ids is not None and len(ids):
            ids = ids.ravel()
            face_idx = np.array([self._face_of_marker.get(int(i), -1) for i in ids])
            for f, det in zip(self.box.faces, self.face_detectors):
                sel = np.flatnonzero(face_idx == f.index)
                if len(sel) < 2:
                    continue
                ch_corners, ch_ids, _, _ = det.detectBoard(gray, markerCorners=[corners[i] for i in sel],
                                                           markerIds=ids[sel].reshape(-1, 1))
                if ch_ids is None or len(ch_ids) < MIN_FACE_CORNERS:
                    continue
                ch_ids = ch_ids.ravel().astype(int)
                px = ch_corners.reshape(-1, 2).astype(np.float64)
                uv_face = f.charuco_uv_m[ch_ids]
                H, _ = cv2.findHomography(uv_face, px, 0)
                if H is None:
                    continue
                if self.subpix:
                    px = self._refine(gray, px, uv_face, H)
                    H, _ = cv2.findHomography(uv_face, px, 0)
                ok = np.all(np.isfinite(px), axis=1)
                out_ids.append(f.index * POINT_ID_STRIDE + ch_ids[ok])
                out_px.append(px[ok])
                faces[f.name] = int(ok.sum())
                homographies[f.index] = H
        if out_ids:
            ids_all = np.concatenate(out_ids)
            px_all = np.vstack(out_px)
        else:
            ids_all, px_all = np.zeros(0, int), np.zeros((0, 2))
        points = self.box.points_for_ids(ids_all) if len(ids_all) else np.zeros((0, 3))
        return BoxDetection(ids_all, points, px_all, ids_all // POINT_ID_STRIDE,
                            self._vertices(homographies), faces, self.box.vertices.copy())

    def _refine(self, gray: np.ndarray, px: np.ndarray, uv_face: np.ndarray, H: np.ndarray) -> np.ndarray:
        """cornerSubPix with a window that fits inside the white gap around each corner."""
        sq, mk = self.box.square_m, self.box.marker_m
        gap = 0.5 * (sq - mk)
        # local scale: image distance of a gap-long step along both face axes, per corner
        step = np.array([[gap, 0.0], [0.0, gap]])
        base = cv2.perspectiveTransform(uv_face.reshape(-1, 1, 2), H).reshape(-1, 2)
        lens = []
        for d in step:
            q = cv2.perspectiveTransform((uv_face + d).reshape(-1, 1, 2), H).reshape(-1, 2)
            lens.append(np.linalg.norm(q - base, axis=1))
        gap_px = np.min(lens, axis=0)
        out = px.copy()
        # group corners by window size (cornerSubPix takes one window per call)
        half = np.clip(np.floor(gap_px * 0.9), 2, 10).astype(int)
        crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 50, 1e-4)
        for h in np.unique(half):
            sel = half == h
            pts = out[sel].astype(np.float32).reshape(-1, 1, 2)
            cv2.cornerSubPix(gray, pts, (int(h), int(h)), (-1, -1), crit)
            out[sel] = pts.reshape(-1, 2)
        # a corner that moved by more than its window is not trusted
        moved = np.linalg.norm(out - px, axis=1)
        out[moved > half] = np.nan
        return out

    def _vertices(self, homographies: dict) -> np.ndarray:
        return vertices_from_homographies(self.box, homographies)


def face_homographies(box: BoxTarget, ids: np.ndarray, pixels: np.ndarray) -> dict:
    """face index -> 3x3 homography face plane (m) -> image, from a face's detected corners."""
    out = {}
    faces = ids // POINT_ID_STRIDE
    for f in box.faces:
        sel = faces == f.index
        if sel.sum() < MIN_FACE_CORNERS:
            continue
        H, _ = cv2.findHomography(f.charuco_uv_m[ids[sel] % POINT_ID_STRIDE], pixels[sel], 0)
        if H is not None:
            out[f.index] = H
    return out


def vertices_from_homographies(box: BoxTarget, homographies: dict) -> np.ndarray:
    """(8,2) vertex pixels: each face's corners placed by its homography, averaged over the
    faces sharing a vertex; NaN for vertices on no detected face."""
    acc = np.zeros((8, 2))
    n = np.zeros(8)
    for f in box.faces:
        H = homographies.get(f.index)
        if H is None:
            continue
        w, h = f.size_m
        uv = np.array([[0, 0], [w, 0], [w, h], [0, h]], float)
        px = cv2.perspectiveTransform(uv.reshape(-1, 1, 2), H).reshape(-1, 2)
        k = box.face_vertex_indices(f)
        acc[k] += px
        n[k] += 1
    with np.errstate(invalid="ignore"):
        out = acc / n[:, None]
    out[n == 0] = np.nan
    return out
