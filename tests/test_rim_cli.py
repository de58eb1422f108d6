"""`station detect`: a photograph in, the rim ellipse out; every bad file a clear message and
a non-zero exit, never a traceback."""

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from station.cli import main
from tests.synthetic_wheel import WheelSpec, render_wheel


@pytest.fixture(scope="module")
def wheel(tmp_path_factory):
    d = tmp_path_factory.mktemp("detect")
    img, truth = render_wheel(WheelSpec(axis_ratio=0.88, rim_a_px=200, center_px=(400.2, 300.6)),
                              shape=(640, 800), seed=21)
    colour = cv2.merge([img, (img * 0.9).astype(np.uint8), img])
    cv2.imwrite(str(d / "wheel.png"), img)
    cv2.imwrite(str(d / "wheel.jpg"), colour, [cv2.IMWRITE_JPEG_QUALITY, 95])
    return d, truth


def test_detect_png_prints_and_writes_json_and_drawing(wheel, capsys):
    d, truth = wheel
    code = main(["detect", str(d / "wheel.png"), "--json", str(d / "out.json"), "--draw", str(d / "out.png")])
    out = capsys.readouterr().out
    assert code == 0
    assert "centre" in out and "semi-axes" in out and "score" in out
    shown = float(out.split("  time")[1].split("ms")[0])  # the whole search, not one stage's clock
    assert shown >= sum(json.loads((d / "out.json").read_text())["timing_ms"].values())
    doc = json.loads((d / "out.json").read_text())
    np.testing.assert_allclose(doc["ellipse"]["center_px"], truth.center_px, atol=0.05)
    np.testing.assert_allclose(doc["ellipse"]["axes_px"], truth.axes_px, atol=0.05)
    assert 0.8 < doc["score"] <= 1.0 and doc["n_points"] > 300
    drawn = cv2.imread(str(d / "out.png"))
    assert drawn.shape == (640, 800, 3)
    # the drawn curve is red on the rim
    p = np.round(truth.points(50)).astype(int)
    assert (drawn[p[:, 1], p[:, 0], 2].astype(int) - drawn[p[:, 1], p[:, 0], 1]).mean() > 50


def test_detect_colour_jpeg(wheel, capsys):
    d, truth = wheel
    assert main(["detect", str(d / "wheel.jpg"), "--json", "-"]) == 0
    text = capsys.readouterr().out
    doc = json.loads(text[text.index("{"):])
    np.testing.assert_allclose(doc["ellipse"]["center_px"], truth.center_px, atol=0.1)


@pytest.mark.parametrize("case,expect", [
    ("truncated.png", "PNG file is truncated"),
    ("truncated.jpg", "JPEG file is truncated"),
    ("garbage.png", "not a readable image"),
    ("empty.png", "file is empty"),
    ("missing.png", "no such file"),
    ("black.png", "image is black"),
    ("tiny.png", "too small"),
    ("nowheel.png", "no closed rim contour"),
])
def test_bad_input_gives_a_message_and_nonzero_exit(wheel, capsys, case, expect):
    d, _ = wheel
    path = d / case
    if case.startswith("truncated"):
        data = (d / ("wheel" + path.suffix)).read_bytes()
        path.write_bytes(data[: len(data) // 2])
    elif case == "garbage.png":
        path.write_bytes(b"\x89PNG\r\n\x1a\n this is not a png IEND")
    elif case == "empty.png":
        path.write_bytes(b"")
    elif case == "black.png":
        cv2.imwrite(str(path), np.zeros((480, 640), np.uint8))
    elif case == "tiny.png":
        cv2.imwrite(str(path), np.full((16, 16), 90, np.uint8))
    elif case == "nowheel.png":
        rng = np.random.default_rng(0)
        img = np.clip(120 + 30 * np.sin(np.arange(640) / 40)[None, :] + rng.normal(0, 2, (480, 640)), 0, 255)
        cv2.imwrite(str(path), img.astype(np.uint8))
    code = main(["detect", str(path)])
    err = capsys.readouterr().err
    assert code != 0
    assert expect in err
    assert "Traceback" not in err and "internal error" not in err


@pytest.mark.parametrize("out", ["out.xyz", "out", "out.exr"])
def test_a_drawing_path_without_an_image_suffix_is_refused_before_detecting(wheel, capsys, out):
    d, _ = wheel
    with pytest.raises(SystemExit) as e:
        main(["detect", str(d / "wheel.png"), "--draw", str(d / out)])
    err = capsys.readouterr().err
    assert e.value.code == 2 and "--draw" in err and "use .png or .jpg" in err
    assert "Traceback" not in err and "internal error" not in err and not (d / out).exists()


def test_a_drawing_opencv_cannot_write_is_an_image_error(wheel, tmp_path):
    from station.commands.photo_files import draw, read_image
    from station.errors import ImageError
    from station.rim import detect_rim

    d, _ = wheel
    image = read_image(d / "wheel.png")
    with pytest.raises(ImageError, match="cannot write the drawing"):
        draw(image, detect_rim(image), tmp_path / "out.xyz")
    with pytest.raises(ImageError, match="cannot write the drawing"):
        draw(image, detect_rim(image), tmp_path / "no" / "dir" / "out.png")


def test_an_srgb_photograph_is_measured_once_its_gamma_is_undone(tmp_path, capsys):
    """A phone or webcam JPEG encodes grey as light^0.45: the blurred edge's middle grey moves
    toward the dark tyre and the rim comes out too large; --response-gamma 0.45 undoes it."""
    img, truth = render_wheel(WheelSpec(axis_ratio=0.9, rim_a_px=220, center_px=(400.2, 300.6), blur_sigma_px=1.2),
                              shape=(640, 800), seed=22)
    lut = np.round(255 * (np.arange(256) / 255) ** 0.45).astype(np.uint8)
    cv2.imwrite(str(tmp_path / "srgb.png"), lut[img])
    errors = {}
    for g in ("1", "0.45"):
        assert main(["detect", str(tmp_path / "srgb.png"), "--response-gamma", g, "--json", str(tmp_path / f"{g}.json")]) == 0
        doc = json.loads((tmp_path / f"{g}.json").read_text())
        errors[g] = np.abs(np.array(doc["ellipse"]["axes_px"]) - truth.axes_px).max()
    assert errors["0.45"] < 0.05 and errors["1"] > 3 * errors["0.45"], errors
    cv2.imwrite(str(tmp_path / "srgb.jpg"), lut[img], [cv2.IMWRITE_JPEG_QUALITY, 95])
    assert main(["detect", str(tmp_path / "srgb.jpg"), "--json", str(tmp_path / "jpg.json")]) == 0  # JPEG: sRGB by default
    doc = json.loads((tmp_path / "jpg.json").read_text())
    assert np.abs(np.array(doc["ellipse"]["axes_px"]) - truth.axes_px).max() < 0.06
    assert "edge blur" in capsys.readouterr().out
    assert main(["detect", str(tmp_path / "srgb.png"), "--response-gamma", "0"]) != 0
    assert "expected a value in [0.2, 5]" in capsys.readouterr().err


def test_an_underexposed_photograph_is_measured_and_named_dark(tmp_path, capsys):
    """An sRGB photograph whose brightest grey level is about 40 of 255 holds light of 2 % of
    full scale: dark, not black. Its light is scaled up (still proportional to light) and the
    rim found; a refusal on such a photograph says it is dark and what to do."""
    img, truth = render_wheel(WheelSpec(axis_ratio=0.9, rim_a_px=220, center_px=(400.2, 300.6), blur_sigma_px=1.2),
                              shape=(640, 800), seed=23)
    encoded = np.round(255 * (0.02 * img.astype(float) / 255) ** 0.45).astype(np.uint8)
    assert 30 <= np.percentile(encoded, 99.5) <= 50
    cv2.imwrite(str(tmp_path / "dark.png"), encoded)
    assert main(["detect", str(tmp_path / "dark.png"), "--response-gamma", "0.45", "--json", str(tmp_path / "d.json")]) == 0
    doc = json.loads((tmp_path / "d.json").read_text())
    np.testing.assert_allclose(doc["ellipse"]["center_px"], truth.center_px, atol=0.3)
    np.testing.assert_allclose(doc["ellipse"]["axes_px"], truth.axes_px, atol=0.5)
    capsys.readouterr()
    flat = np.full((640, 800), 20, np.uint8)
    flat[::7, :] = 40  # stripes: a dark photograph without a wheel
    cv2.imwrite(str(tmp_path / "dark-nowheel.png"), flat)
    assert main(["detect", str(tmp_path / "dark-nowheel.png"), "--response-gamma", "0.45"]) != 0
    err = capsys.readouterr().err
    assert "A dark photograph, its brightest grey level 40 of 255" in err and "longer exposure" in err


def test_a_folder_of_photographs_is_searched_image_by_image_with_a_summary(wheel, tmp_path, capsys):
    """Several images (here a folder): a line per image, an unreadable one among them an error
    line that does not stop the others, one JSON with every entry and the counts, a drawing per
    rim found (two names alike kept apart), exit code 1 as one image had no rim."""
    d, truth = wheel
    folder = tmp_path / "photos"
    folder.mkdir()
    for name in ("wheel.png", "wheel.jpg"):
        (folder / name).write_bytes((d / name).read_bytes())
    data = (d / "wheel.png").read_bytes()
    (folder / "cut.png").write_bytes(data[: len(data) // 2])
    (folder / "notes.txt").write_text("not an image")
    drawings = tmp_path / "drawn"
    drawings.mkdir()
    code = main(["detect", str(folder), "--json", str(tmp_path / "all.json"), "--draw", str(drawings)])
    out = capsys.readouterr().out
    assert code == 1
    assert "3 images" in out and "1/3 cut.png: error 402: the PNG file is truncated" in out
    assert "3/3 wheel.png: rim at (400.2, 300.6) px" in out
    assert "3 of 3 images searched: 2 rims found, 1 not (error 402 x1)" in out
    doc = json.loads((tmp_path / "all.json").read_text())
    assert doc["summary"] == {"images": 3, "searched": 3, "found": 2, "not_found": {"402": 1},
                              "why_not": {"the PNG file is truncated": 1}}
    assert "why not: the PNG file is truncated x1" in out
    assert doc["interrupted"] is False
    found = [e for e in doc["images"] if e["found"]]
    assert [Path(e["image"]).name for e in found] == ["wheel.jpg", "wheel.png"]
    for e in found:
        np.testing.assert_allclose(e["ellipse"]["center_px"], truth.center_px, atol=0.1)
    assert doc["images"][0]["error"]["code"] == 402 and doc["images"][0]["error"]["hint"]
    assert sorted(p.name for p in drawings.iterdir()) == ["wheel.3.rim.png", "wheel.rim.png"]


def test_several_images_each_with_a_rim_exit_zero(wheel, capsys):
    d, _ = wheel
    assert main(["detect", str(d / "wheel.png"), str(d / "wheel.jpg")]) == 0
    assert "2 of 2 images searched: 2 rims found" in capsys.readouterr().out


@pytest.mark.parametrize("case,expect", [("empty folder", "the folder holds no image"),
                                         ("drawing file", "the drawings go to a folder"),
                                         ("json in no folder", "cannot write the JSON")])
def test_a_batch_that_cannot_start_says_why(wheel, tmp_path, capsys, case, expect):
    d, _ = wheel
    (tmp_path / "empty").mkdir()
    two = [str(d / "wheel.png"), str(d / "wheel.jpg")]
    argv = {"empty folder": ["detect", str(tmp_path / "empty")],
            "drawing file": ["detect", *two, "--draw", str(tmp_path / "one.png")],
            "json in no folder": ["detect", *two, "--json", str(tmp_path / "no" / "all.json")]}[case]
    code = main(argv)
    captured = capsys.readouterr()
    assert code != 0 and "images searched" not in captured.out
    assert expect in captured.err
    assert "Traceback" not in captured.err


def _with_chunk(png: bytes, kind: bytes, data: bytes) -> bytes:
    """``png`` with a chunk ``kind`` inserted after its header (IHDR: 8 + 25 bytes)."""
    import zlib

    chunk = len(data).to_bytes(4, "big") + kind + data + zlib.crc32(kind + data).to_bytes(4, "big")
    return png[:33] + chunk + png[33:]


@pytest.mark.parametrize("kind,data,expect", [
    (b"sRGB", b"\x00", 0.45), (b"gAMA", (45455).to_bytes(4, "big"), 0.45455), (b"gAMA", (100000).to_bytes(4, "big"), 1.0),
    (b"cICP", bytes([1, 13, 0, 1]), 0.45), (b"cICP", bytes([1, 8, 0, 1]), 1.0), (None, b"", 1.0),
])
def test_a_png_is_decoded_as_its_colour_chunk_says(tmp_path, kind, data, expect):
    """A PNG says how its grey encodes light in its sRGB, gAMA, iCCP or cICP chunk (a photograph
    saved as PNG is sRGB); without one it is taken as a machine-vision camera's linear grey."""
    from station.commands.photo_files import default_gamma

    ok, png = cv2.imencode(".png", np.full((8, 8), 100, np.uint8))
    png = png.tobytes()
    (tmp_path / "x.png").write_bytes(png if kind is None else _with_chunk(png, kind, data))
    assert cv2.imread(str(tmp_path / "x.png"), cv2.IMREAD_UNCHANGED) is not None
    assert default_gamma(tmp_path / "x.png") == pytest.approx(expect)


def test_an_srgb_png_is_measured_as_srgb_without_being_told(tmp_path, capsys):
    img, truth = render_wheel(WheelSpec(axis_ratio=0.9, rim_a_px=220, center_px=(400.2, 300.6), blur_sigma_px=1.2),
                              shape=(640, 800), seed=22)
    lut = np.round(255 * (np.arange(256) / 255) ** 0.45).astype(np.uint8)
    ok, png = cv2.imencode(".png", lut[img])
    (tmp_path / "srgb.png").write_bytes(_with_chunk(png.tobytes(), b"sRGB", b"\x00"))
    assert main(["detect", str(tmp_path / "srgb.png"), "--json", str(tmp_path / "d.json")]) == 0
    assert "from the PNG's sRGB chunk" in capsys.readouterr().out
    doc = json.loads((tmp_path / "d.json").read_text())
    assert np.abs(np.array(doc["ellipse"]["axes_px"]) - truth.axes_px).max() < 0.06


def test_a_jpeg_is_read_upright_as_its_exif_orientation_says(tmp_path):
    """A phone stores a portrait photograph sideways with an EXIF orientation; read as stored,
    its wheel lies on its side and the photograph search refuses it as not upright."""
    import struct

    from station.commands.photo_files import read_image

    img = np.full((60, 100), 40, np.uint8)
    img[:10] = 220  # the stored image's top rows
    ok, jpg = cv2.imencode(".jpg", img)
    tiff = b"II*\x00" + struct.pack("<I", 8) + struct.pack("<H", 1) + struct.pack("<HHIHH", 0x0112, 3, 1, 6, 0) + b"\0" * 4
    app1 = b"Exif\x00\x00" + tiff  # orientation 6: shown turned 90 deg clockwise
    jpg = jpg.tobytes()
    (tmp_path / "portrait.jpg").write_bytes(jpg[:2] + b"\xff\xe1" + struct.pack(">H", len(app1) + 2) + app1 + jpg[2:])
    image = read_image(tmp_path / "portrait.jpg")
    assert image.shape == (100, 60)
    assert image[:, -5:].mean() > 200 and image[:, :40].mean() < 60  # the stored top is now the right side


@pytest.mark.parametrize("message,kind", [
    ("1_001.jpg: no rim found. The station's search: no closed rim contour (best candidate: 28% of its perimeter); "
     "the photograph search: no rim taken; the best candidate at (31, 1132) px, 218 px high, b/a 0.29: no dark tyre "
     "round it (rubber-dark on 44% of the turn < 50%)", "no dark tyre round it"),
    ("big.jpg: no rim found. The station's search: no closed rim contour; the photograph search: no rim taken; the "
     "best candidate at (4879, 1734) px, 1112 px high, b/a 0.38: not one smooth contour (the edge points lie 2.8 px rms "
     "off their ellipse > 1.0); the photograph is blurred there (edge blur 4.9 px > 4)", "not one smooth contour, blurred"),
    ("1_045.jpg: the rim at (2361, 783) px, 363 px high, b/a 0.44 is not sure: another ellipse in the photograph 0.75 "
     "times the size (at (2363, 806) px, 399 px high, back at this size), and not found again in the photograph 1.33 "
     "times the size (no rim taken)", "not sure: another ellipse at a smaller size"),
    ("1_016.jpg: the rim at (2257, 819) px, 409 px high, b/a 0.44 is not sure: not found again in the photograph 0.75 "
     "times the size (no rim found)", "not sure: not found again at a smaller size"),
    ("s.jpg: the rim at (257, 819) px, 209 px high, b/a 0.44 is not sure: another ellipse in the photograph 1.33 "
     "times the size (at (263, 806) px, 299 px high, back at this size), and another again 0.75 times the size",
     "not sure: another ellipse at a larger size"),
    ("/x/cut.png: the PNG file is truncated (no end chunk)", "the PNG file is truncated"),
])
def test_a_refusal_is_counted_by_its_kind_without_its_figures(message, kind):
    from station.commands.detect_batch import refusal_kind

    assert refusal_kind(message) == kind
