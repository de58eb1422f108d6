"""The solid calibration box (paper section 2.3, Fig. 2): geometry, face boards, textures.

Box frame (``box``): origin at the centre of the bottom face, x along ``size_m[0]``, y along
``size_m[1]``, z up. Metres. The eight vertices ``B_k`` of the paper are :attr:`BoxTarget.vertices`
(k = 1..8 is row k-1: the bottom four counter-clockwise seen from above starting at
(-x, -y), then the top four in the same order).

Every printed face carries a ChArUco board (``cv2.aruco.CharucoBoard``) with its own marker
ids, so a detected corner names its face and therefore its 3-D position in the box frame.
A face is a rectangle with texture axes ``u`` (to the right, seen from outside) and ``v``
(down, seen from outside; for the top face: toward -y); ``u x v = -normal``, so a texture is
never mirrored. Texture convention (shared with ``simulators.scene.TexturedQuad``): texture
coordinate (0, 0) is the face's top-left corner and (w, h) its bottom-right corner, a texel
(row i, column j) covers ``[j, j+1] x [i, i+1]``.

This module knows nothing of the simulator: :meth:`BoxTarget.face_quads` returns plain
``(corners (4,3), texture (h,w) uint8)`` tuples in any frame.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import cv2
import numpy as np

FACE_ORDER = ("px", "py", "nx", "ny", "top")
# outward normal and texture axes (u right, v down, seen from outside) of each face
_FACE_AXES = {
    "px": ((1, 0, 0), (0, 1, 0), (0, 0, -1)),
    "py": ((0, 1, 0), (-1, 0, 0), (0, 0, -1)),
    "nx": ((-1, 0, 0), (0, -1, 0), (0, 0, -1)),
    "ny": ((0, -1, 0), (1, 0, 0), (0, 0, -1)),
    "top": ((0, 0, 1), (1, 0, 0), (0, -1, 0)),
}
POINT_ID_STRIDE = 1000  # global point id = face index * stride + ChArUco corner id


@dataclass(frozen=True)
class Face:
    """One printed face. origin_box: (3,) its top-left corner; u, v: (3,) unit texture axes;
    size_m: (width along u, height along v); board_offset_m: (u, v) of the board's top-left."""

    name: str
    index: int
    normal: np.ndarray
    origin_box: np.ndarray
    u: np.ndarray
    v: np.ndarray
    size_m: tuple[float, float]
    squares: tuple[int, int]
    first_id: int
    board_offset_m: tuple[float, float]
    board: cv2.aruco.CharucoBoard

    def to_box(self, uv_m: np.ndarray) -> np.ndarray:
        """(N,2) face coordinates (m, from the top-left corner along u, v) -> (N,3) box frame."""
        uv_m = np.asarray(uv_m, float).reshape(-1, 2)
        return self.origin_box + uv_m[:, :1] * self.u + uv_m[:, 1:] * self.v

    @property
    def corners_box(self) -> np.ndarray:
        """(4,3) face corners in texture order: top-left, top-right, bottom-right, bottom-left."""
        w, h = self.size_m
        return self.to_box(np.array([[0, 0], [w, 0], [w, h], [0, h]], float))

    @property
    def charuco_uv_m(self) -> np.ndarray:
        """(M,2) chessboard (ChArUco) corners in face coordinates, in ChArUco id order."""
        c = np.asarray(self.board.getChessboardCorners(), float)[:, :2]
        return c + np.asarray(self.board_offset_m)

    @property
    def charuco_box(self) -> np.ndarray:
        """(M,3) chessboard corners in the box frame, in ChArUco id order."""
        return self.to_box(self.charuco_uv_m)


def _dictionary(name: str):
    if not name.startswith("DICT_") or not hasattr(cv2.aruco, name):
        raise ValueError(f"unknown ArUco dictionary {name!r} (expected e.g. DICT_5X5_1000)")
    return cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, name))


class BoxTarget:
    """The calibration box described by config/box.yaml (read by :func:`station.config.load_box`)."""

    def __init__(self, size_m, dictionary: str, square_m: float, marker_m: float,
                 faces: dict, texel_m: float = 0.0005, source: str = "box"):
        self.source = source
        self.size_m = tuple(float(s) for s in size_m)
        self.dictionary_name = dictionary
        self.square_m = float(square_m)
        self.marker_m = float(marker_m)
        self.texel_m = float(texel_m)
        if len(self.size_m) != 3 or min(self.size_m) <= 0:
            raise ValueError("size_m must be three positive lengths")
        if not 0 < self.marker_m < self.square_m:
            raise ValueError("marker_m must be positive and smaller than square_m")
        self.dictionary = _dictionary(dictionary)
        n_dict = self.dictionary.bytesList.shape[0]
        self.faces: list[Face] = []
        used: dict[int, str] = {}
        for name in faces:
            if name not in _FACE_AXES:
                raise ValueError(f"faces: unknown face {name!r}; expected some of {', '.join(FACE_ORDER)}")
        for index, name in enumerate(n for n in FACE_ORDER if n in faces):
            spec = faces[name]
            cols, rows = (int(s) for s in spec["squares"])
            first = int(spec["first_id"])
            n_markers = (cols * rows) // 2
            ids = np.arange(first, first + n_markers)
            if ids[-1] >= n_dict:
                raise ValueError(f"faces.{name}: marker ids up to {ids[-1]} exceed {dictionary} ({n_dict} markers)")
            clash = [i for i in ids if int(i) in used]
            if clash:
                raise ValueError(f"faces.{name}: marker id {clash[0]} is already used by face {used[int(clash[0])]}")
            used.update({int(i): name for i in ids})
            n, u, v = (np.array(a, float) for a in _FACE_AXES[name])
            X, Y, Z = self.size_m
            w = float(np.abs(u) @ [X, Y, Z])
            h = float(np.abs(v) @ [X, Y, Z])
            centre = n * np.array([X, Y, Z]) / 2 + np.array([0, 0, Z / 2])
            origin = centre - u * w / 2 - v * h / 2
            bw, bh = cols * self.square_m, rows * self.square_m
            if bw > w + 1e-9 or bh > h + 1e-9:
                raise ValueError(f"faces.{name}: {cols}x{rows} squares of {self.square_m} m do not fit "
                                 f"on the {w:g} x {h:g} m face")
            board = cv2.aruco.CharucoBoard((cols, rows), self.square_m, self.marker_m, self.dictionary, ids)
            self.faces.append(Face(name, index, n, origin, u, v, (w, h), (cols, rows), first,
                                   ((w - bw) / 2, (h - bh) / 2), board))
        if not self.faces:
            raise ValueError("faces: the box needs at least one printed face")
        self.marker_face = used  # marker id -> face name

    # --- geometry -----------------------------------------------------------------------------
    @cached_property
    def vertices(self) -> np.ndarray:
        """(8,3) the paper's B_k in the box frame (row k-1 is vertex k)."""
        X, Y, Z = self.size_m
        xy = np.array([[-X, -Y], [X, -Y], [X, Y], [-X, Y]]) / 2
        bottom = np.c_[xy, np.zeros(4)]
        top = np.c_[xy, np.full(4, Z)]
        return np.vstack([bottom, top])

    def face(self, name: str) -> Face:
        for f in self.faces:
            if f.name == name:
                return f
        raise KeyError(name)

    def face_vertex_indices(self, face: Face) -> np.ndarray:
        """(4,) indices into :attr:`vertices` of a face's corners, in texture order."""
        d = np.linalg.norm(face.corners_box[:, None, :] - self.vertices[None], axis=2)
        return np.argmin(d, axis=1)

    @cached_property
    def points_box(self) -> np.ndarray:
        """(P,3) every chessboard corner of every face, in the order of :attr:`point_ids`."""
        return np.vstack([f.charuco_box for f in self.faces])

    @cached_property
    def point_ids(self) -> np.ndarray:
        """(P,) global point ids: face index * POINT_ID_STRIDE + ChArUco corner id."""
        return np.concatenate([f.index * POINT_ID_STRIDE + np.arange(len(f.charuco_uv_m)) for f in self.faces])

    def points_for_ids(self, ids: np.ndarray) -> np.ndarray:
        """(N,) global point ids -> (N,3) box-frame positions."""
        ids = np.asarray(ids, int)
        lookup = {int(i): k for k, i in enumerate(self.point_ids)}
        return self.points_box[[lookup[int(i)] for i in ids]]

    # --- textures -------------------------------------------------------------------------------
    def face_texture(self, face: Face, texel_m: float | None = None) -> np.ndarray:
        """(h, w) uint8 image of a face: white, with its ChArUco board placed at true position.

        With the default texel the square side must be a whole number of texels, so the
        texture agrees with the geometry exactly (a pixel-exact print/render)."""
        texel = float(texel_m or self.texel_m)
        w_px = int(round(face.size_m[0] / texel))
        h_px = int(round(face.size_m[1] / texel))
        sq = self.square_m / texel
        cols, rows = face.squares
        tex = np.full((h_px, w_px), 255, np.uint8)
        if abs(sq - round(sq)) < 1e-6:
            bw, bh = int(round(cols * sq)), int(round(rows * sq))
        else:
            bw, bh = int(round(cols * self.square_m / texel)), int(round(rows * self.square_m / texel))
        board_img = face.board.generateImage((bw, bh), marginSize=0, borderBits=1)
        ox = int(round(face.board_offset_m[0] / texel))
        oy = int(round(face.board_offset_m[1] / texel))
        tex[oy:oy + bh, ox:ox + bw] = board_img
        return tex

    @cached_property
    def textures(self) -> list[np.ndarray]:
        return [self.face_texture(f) for f in self.faces]

    def face_quads(self, R_frame_box: np.ndarray, t_frame_box: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
        """The printed faces as ``(corners (4,3), texture (h,w) uint8)`` in another frame.

        ``x_frame = R_frame_box @ x_box + t_frame_box``; corners in texture order."""
        R = np.asarray(R_frame_box, float)
        t = np.asarray(t_frame_box, float)
        return [(f.corners_box @ R.T + t, tex) for f, tex in zip(self.faces, self.textures)]


def box_pose_on_floor(position_m, yaw_deg: float) -> tuple[np.ndarray, np.ndarray]:
    """Pose of a box standing on the floor: bottom centre at ``position_m`` (3,), yawed about z.

    Returns (R_station_box (3,3), t_station_box (3,))."""
    a = np.radians(float(yaw_deg))
    R = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1.0]])
    return R, np.asarray(position_m, float).reshape(3).copy()
