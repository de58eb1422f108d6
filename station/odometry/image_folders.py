"""Which folders of a sequence hold the left and right images, and which files pair up.

The folder pairs read, first found first (docs/odometry.md): KITTI odometry's ``image_0/
image_1/`` (grey; calib.txt P0, P1) and ``image_2/ image_3/`` (colour; P2, P3), KITTI raw's
``image_02/ image_03/`` (P2, P3; images directly or in ``data/``), and ``image_l/ image_r/``,
``left/ right/`` (ours; the first two matrices of calib.txt, or P0, P1). Files are sorted
naturally (``1.png`` before ``10.png``); left and right pair by name, or by the numbers in
their names when the two folders name their files differently (``left_007.png``,
``right_007.png``).
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

from station.errors import OdometryError

IMAGE_EXTS = (".png", ".jpg", ".jpeg", ".bmp", ".pgm", ".ppm", ".tif", ".tiff")

# (left folder, right folder, the calib.txt labels of their projection matrices)
FOLDER_PAIRS = (
    ("image_0", "image_1", ("P0", "P1")),
    ("image_l", "image_r", ("P0", "P1")),
    ("left", "right", ("P0", "P1")),
    ("image_2", "image_3", ("P2", "P3")),
    ("image_02", "image_03", ("P2", "P3")),
)
EXPECTED = ("image_0/ image_1/, image_l/ image_r/ or left/ right/ "
            "(colour KITTI: image_2/ image_3/ or image_02/ image_03/)")


@dataclass(frozen=True)
class ImageFolders:
    """The sequence's image files, paired: ``left_files[i]`` and ``right_files[i]`` are image i."""

    left_dir: Path
    right_dir: Path
    calib_labels: tuple[str, str]
    left_files: list[Path]
    right_files: list[Path]

    @property
    def names(self) -> str:
        """The two folders as a user sees them, e.g. ``image_l/ image_r/``."""
        return f"{self.left_dir.name}/ {self.right_dir.name}/"


def natural_key(name: str) -> tuple:
    """Sort key: runs of digits compare as numbers (``'1.png' < '2.png' < '10.png'``).

    ``re.split`` with a group alternates text (even places) and digits (odd places), so two keys
    never compare a number with a text."""
    return tuple(int(t) if k % 2 else t.lower() for k, t in enumerate(re.split(r"(\d+)", name)))


def list_images(folder: Path) -> list[Path]:
    """Image files of ``folder`` (or of ``folder/data``, KITTI raw's), sorted naturally."""
    try:
        files = [p for p in folder.iterdir() if p.is_file() and p.suffix.lower() in IMAGE_EXTS]
    except OSError as e:
        raise OdometryError(f"{folder}: cannot list the images ({e.strerror or e})") from e
    if not files and (folder / "data").is_dir():
        return list_images(folder / "data")
    return sorted(files, key=lambda p: natural_key(p.name))


def _folders_found(d: Path) -> str:
    subdirs = sorted((p.name for p in d.iterdir() if p.is_dir() and not p.name.startswith(".")),
                     key=natural_key)
    if subdirs:
        shown = " ".join(f"{s}/" for s in subdirs[:8]) + (" ..." if len(subdirs) > 8 else "")
        return f"{d} has folders {shown}"
    n_images = sum(1 for p in d.iterdir() if p.is_file() and p.suffix.lower() in IMAGE_EXTS)
    plural = "s" if n_images != 1 else ""
    return f"{d} has no folders" + (f" ({n_images} image{plural} directly in it)" if n_images else "")


def _rename_hint(d: Path) -> str:
    with_images = [p.name for p in sorted(d.iterdir(), key=lambda p: natural_key(p.name))
                   if p.is_dir() and list_images(p)]
    if len(with_images) == 2:
        a, b = with_images
        return f"rename {a}/ to left/ and {b}/ to right/ (if {a}/ holds the left camera's images)"
    return "put the left camera's images in left/ and the right camera's in right/"


def find_folders(d: Path) -> tuple[Path, Path, tuple[str, str]]:
    """The first known folder pair in ``d``; OdometryError saying what was found otherwise."""
    for lname, rname, labels in FOLDER_PAIRS:
        if (d / lname).is_dir() and (d / rname).is_dir():
            return d / lname, d / rname, labels
    for lname, rname, _ in FOLDER_PAIRS:
        for have, lack in ((lname, rname), (rname, lname)):
            if (d / have).is_dir():
                raise OdometryError(f"{d} has {have}/ but no {lack}/: a stereo sequence needs both "
                                    "cameras' images", hint=f"expected {EXPECTED}")
    raise OdometryError(f"{_folders_found(d)}: expected {EXPECTED}", hint=_rename_hint(d))


def _pair_keys(left: list[Path], right: list[Path]) -> tuple[list, list]:
    """Keys pairing left and right files: the names when the two folders share any, else the
    numbers in the names."""
    if {p.stem for p in left} & {p.stem for p in right}:
        return [p.stem for p in left], [p.stem for p in right]
    return ([tuple(int(n) for n in re.findall(r"\d+", p.stem)) for p in left],
            [tuple(int(n) for n in re.findall(r"\d+", p.stem)) for p in right])


def pair_images(left_dir: Path, right_dir: Path, labels: tuple[str, str]) -> ImageFolders:
    """List and pair the images of the two folders; OdometryError when they do not pair up."""
    left, right = list_images(left_dir), list_images(right_dir)
    for folder, files in ((left_dir, left), (right_dir, right)):
        if not files:
            raise OdometryError(f"{folder}: no images ({' '.join(IMAGE_EXTS)})",
                                hint="the folder of each camera holds one image per time step")
    folders = ImageFolders(left_dir, right_dir, labels, left, right)
    kl, kr = _pair_keys(left, right)
    if kl == kr and len(set(kl)) == len(kl):
        return folders
    by_key = {k: p.name for p, k in zip(left + right, kl + kr)}
    only = sorted(set(kl) ^ set(kr), key=lambda k: natural_key(by_key[k]))
    unpaired = ", ".join(by_key[k] for k in only[:5]) + (" ..." if len(only) > 5 else "")
    counts = (f"{left_dir.name}/ has {len(left)} images, {right_dir.name}/ has {len(right)}"
              if len(left) != len(right) else f"{len(left)} images each")
    detail = f" (unpaired: {unpaired})" if only else " (the same names in another order or twice)"
    raise OdometryError(f"{left_dir.parent}: left and right images do not pair up: {counts}{detail}",
                        hint="every left image needs the right image of the same name or number")


def find_images(d: Path) -> ImageFolders:
    """The paired left and right images of the sequence folder ``d``."""
    return pair_images(*find_folders(d))
