"""`station detect` on several photographs, or a folder of them: one line per image as it is
searched, a summary, one JSON document and a drawing per rim found. An image that cannot be
read or has no rim found is a line and an entry like any other; the rest go on. Interrupted
(Ctrl-C), what was searched is still summarised and written."""

from __future__ import annotations

import re
import sys
from collections import Counter
from pathlib import Path

from station.commands.detect_photograph import detect_file
from station.commands.photo_files import detection_doc, draw, drawing_name, write_json
from station.errors import CODED_ERRORS, ImageError, sentence_without
from station.rim.photo_stability import LARGER

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff")
EXIT_SOME_NOT_FOUND = 1
EXIT_INTERRUPTED = 130


def image_paths(args: list[str]) -> list[Path]:
    """The images named by ``args``: files as given (a missing one is that image's error), and
    each folder's image files (by suffix, ``IMAGE_SUFFIXES``) in name order."""
    paths = []
    for text in args:
        p = Path(text)
        if not p.is_dir():
            paths.append(p)
            continue
        found = sorted(q for q in p.iterdir() if q.is_file() and q.suffix.lower() in IMAGE_SUFFIXES)
        if not found:
            raise ImageError(f"{p}: the folder holds no image ({', '.join(IMAGE_SUFFIXES)})",
                             hint="name the folder with the photographs, or the files themselves")
        paths += found
    return paths


def _drawings_folder(draw_arg: str | None) -> Path | None:
    if draw_arg is None:
        return None
    folder = Path(draw_arg)
    if not folder.is_dir():
        raise ImageError(f"--draw {draw_arg}: of several images the drawings go to a folder, and this is not one",
                         hint="create the folder first, or give one image")
    return folder


def _error_entry(path: Path, error) -> dict:
    return {"image": str(path), "found": False,
            "error": {"code": error.code, "area": error.area, "message": str(error), "hint": error.hint}}


def _sentence(path: Path, error) -> str:
    """The error's sentence without the image's path or name it starts with (the line names it)."""
    text = sentence_without(str(path), error)
    return sentence_without(path.name, error) if text == str(error) else text


def _found_line(det, seconds: float) -> str:
    e = det.ellipse
    a, b = e.axes_px
    return (f"rim at ({e.center_px[0]:.1f}, {e.center_px[1]:.1f}) px, {2 * a:.0f} px high, b/a {b / a:.2f}, "
            f"edge on {det.coverage:.0%} of it, {det.point_sigma_px:.2f} px rms, "
            f"{det.details.get('search', '?')} search, {seconds:.2f} s")


def refusal_kind(message: str) -> str:
    """What kind of refusal ``message`` (a RimNotFound's or an ImageError's sentence) is: the
    reason after the image's name without its figures (the photograph search's for its best
    candidate, where both searches refused), and whether it names the photograph blurred or
    dark. "no dark tyre round it", "not one smooth contour, blurred", "not sure: another
    ellipse at a smaller size", ..."""
    text = message.split(": ", 1)[-1]
    if " is not sure: " in text:  # found, but not found again in the photograph resized
        first = text.split(" times the size", 1)[0]  # the size looked at first
        return "not sure: " + ("another ellipse" if ": another ellipse" in first else "not found again") + (
            " at a larger size" if first.endswith(f" {LARGER:g}") else " at a smaller size")
    if "; the best candidate" in text:  # the photo search: what its best candidate was refused for
        text = text.split("; the photograph is blurred", 1)[0].split(". A dark photograph", 1)[0].rsplit(": ", 1)[-1]
    elif "; the photograph search: " in text:  # refused by both searches: the photograph search's reason
        text = text.split("; the photograph search: ", 1)[1]
    named = [w for w, key in (("blurred", "the photograph is blurred"), ("dark", "A dark photograph")) if key in message]
    return re.split(r"[(:]", text, maxsplit=1)[0].strip() + "".join(f", {w}" for w in named)


def summary(entries: list[dict], total: int) -> dict:
    """Counts of ``entries`` (of ``total`` images): found, and not found by error code and by
    the kind of refusal (``refusal_kind``)."""
    missed = [e for e in entries if not e["found"]]
    codes = Counter(str(e["error"]["code"]) for e in missed)
    kinds = Counter(refusal_kind(e["error"]["message"]) for e in missed)
    return {"images": total, "searched": len(entries), "found": len(entries) - len(missed),
            "not_found": dict(sorted(codes.items())), "why_not": dict(kinds.most_common())}


def run(args, paths: list[Path]) -> int:
    """Search every image of ``paths`` as ``station detect`` searches one; exit code 0 when a rim
    was found in each, ``EXIT_SOME_NOT_FOUND`` otherwise, ``EXIT_INTERRUPTED`` on Ctrl-C."""
    folder = _drawings_folder(args.draw)
    out = sys.stderr if args.json == "-" else sys.stdout  # the JSON alone on stdout
    entries, drawn, interrupted = [], set(), False
    width = len(str(len(paths)))
    if args.json and args.json != "-":  # a JSON path that cannot be written is said before the search
        write_json(args.json, {"images": [], "summary": summary([], len(paths)), "interrupted": False})
    print(f"{len(paths)} images", file=out, flush=True)
    try:
        for i, path in enumerate(paths, 1):
            head = f"{i:>{width}}/{len(paths)} {path.name}:"
            try:
                image, det, _, seconds = detect_file(path, args.response_gamma, args.equalization, args.search)
            except CODED_ERRORS as e:
                entries.append(_error_entry(path, e))
                print(f"{head} error {e.code}: {_sentence(path, e)}", file=out, flush=True)
                continue
            entry = {**detection_doc(path, image, det, args.search), "found": True, "seconds": round(seconds, 3)}
            entries.append(entry)
            line = f"{head} {_found_line(det, seconds)}"
            if folder is not None:
                name = drawing_name(path)
                if name in drawn:  # the same name from another folder: keep both
                    name = f"{path.stem}.{i}.rim.png"
                drawn.add(name)
                try:
                    draw(image, det, folder / name)
                except ImageError as e:  # a full disk: the detection still counts and is written
                    entry["drawing_error"] = str(e)
                    line += f" (no drawing: {e})"
            print(line, file=out, flush=True)
    except KeyboardInterrupt:
        interrupted = True
    counts = summary(entries, len(paths))
    not_found = ", ".join(f"error {code} x{n}" for code, n in counts["not_found"].items())
    print(("interrupted: " if interrupted else "")
          + f"{counts['searched']} of {len(paths)} images searched: {counts['found']} "
          + ("rim found" if counts["found"] == 1 else "rims found")
          + (f", {counts['searched'] - counts['found']} not ({not_found})" if not_found else ""), file=out, flush=True)
    if counts["why_not"]:
        print("why not: " + "; ".join(f"{kind} x{n}" for kind, n in counts["why_not"].items()), file=out, flush=True)
    if args.json:
        write_json(args.json, {"images": entries, "summary": counts, "interrupted": interrupted})
    if interrupted:
        return EXIT_INTERRUPTED
    return 0 if counts["found"] == len(paths) else EXIT_SOME_NOT_FOUND
