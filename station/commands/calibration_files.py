"""`station calibration import|export`: the station's calibration from and to OpenCV's files
(docs/calibration.md, "Import and export").

``import`` reads OpenCV FileStorage files (cameras as OpenCV's calibration sample or
``station calibration export`` writes them, stereo pairs as OpenCV's stereo_calib writes them),
places every camera in the station frame as the files and options say, runs the checks a
calibration file gets on load (and the station configuration's), and saves the result where
``station calibrate`` does, atomically: a refused import saves nothing and leaves the previous
file as it was. ``export`` writes the saved calibration as OpenCV files.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from station.config import load_config

UNITS_M = {"m": 1.0, "cm": 0.01, "mm": 0.001}
NOMINAL_DISTANCE_M = 0.25  # an imported camera this far from its designed mount: a unit or pose mistake


def _source(text: str) -> tuple[str | None, Path]:
    """``[TARGET=]FILE`` -> (target or None, path); a path that exists as given is never split."""
    if "=" in text and not Path(text).exists():
        target, path = text.split("=", 1)
        if not target or not path:
            raise argparse.ArgumentTypeError(f"{text!r}: expected FILE or TARGET=FILE (cam3=FILE, FL=FILE)")
        return target, Path(path)
    return None, Path(text)


def _pose(text: str) -> tuple[str, Path]:
    target, path = _source(text)
    if target is None:
        raise argparse.ArgumentTypeError(f"{text!r}: expected CAM=FILE (e.g. cam3=pose.yml)")
    return target, path


def add_arguments(parser) -> None:
    sub = parser.add_subparsers(dest="action", metavar="ACTION")
    imp = sub.add_parser("import", help="make the station's calibration from OpenCV files",
                         description="Make the station's calibration from OpenCV FileStorage files (YAML, XML, JSON): "
                         "cameras (camera_matrix, distortion_coefficients) and stereo pairs (M1 D1 M2 D2 R T). "
                         "Cameras the files leave out are kept from the current calibration.")
    imp.add_argument("files", nargs="+", type=_source, metavar="[TARGET=]FILE",
                     help="a file, named by what it describes when it does not say so itself: a camera (cam3=FILE), "
                     "a pair (FL=FILE: camera 1 is its precision camera; or cam4,cam3=FILE); files with one target "
                     "are read together (FL=intrinsics.yml FL=extrinsics.yml)")
    imp.add_argument("--anchor", action="append", default=[], metavar="CAM",
                     help="keep CAM's pose in the station frame from the current calibration (the camera has not "
                     "moved); its pair's other camera follows from the pair's R and T")
    imp.add_argument("--pose", action="append", default=[], type=_pose, metavar="CAM=FILE",
                     help="CAM's pose in the station frame from FILE (R or rvec, and T: x_cam = R x_station + T)")
    imp.add_argument("--unit", choices=tuple(UNITS_M), default="m", help="the length unit of every T (default m)")
    imp.add_argument("--dry-run", action="store_true", help="read and check everything, print it, save nothing")
    imp.add_argument("--json", metavar="PATH", help="also write the calibration as JSON to PATH")
    imp.set_defaults(_action=_import)
    exp = sub.add_parser("export", help="write the station's calibration as OpenCV files",
                         description="Write DIR/<camera>.yaml per camera (camera_matrix, distortion_coefficients, "
                         "the station pose R, T in metres) and DIR/pairs/<wheel>.yaml per pair (M1 D1 M2 D2 R T).")
    exp.add_argument("directory", type=Path, metavar="DIR")
    exp.add_argument("--file", type=Path, metavar="PATH", help="the calibration to export (default: the station's)")
    exp.set_defaults(_action=_export)
    parser.set_defaults(_parser=parser)


def run(args) -> int:
    if not getattr(args, "_action", None):
        args._parser.print_help()
        return 2
    return args._action(args)


def _import(args) -> int:
    from calibration.calib_file import load_calibration, save_calibration
    from calibration.errors import CalibrationError
    from calibration.opencv_import import Layout, Source, import_calibration

    config = load_config(args.config)
    layout = Layout({c: (cam.width, cam.height) for c, cam in config.cameras.items()},
                    {w: (p.precision, p.reference) for w, p in config.pairs.items()})
    sources: list[Source] = []
    for target, path in args.files:
        same = next((s for s in sources if target is not None and s.target == target), None)
        if same:
            same.paths.append(path)
        else:
            sources.append(Source(target, [path]))
    poses = {}
    for cam, path in args.pose:
        if cam in poses:
            raise CalibrationError(f"--pose {cam}= is given twice ({poses[cam]}, {path})",
                                   hint="give each camera's pose once")
        poses[cam] = path
    current, unreadable = None, None
    if config.calibration_file.exists():
        try:
            current = load_calibration(config.calibration_file, config)
        except CalibrationError as e:
            unreadable = e
    try:
        result = import_calibration(sources, layout, poses=poses, anchors=args.anchor, current=current,
                                    unit_m=UNITS_M[args.unit], station_name=config.name)
    except CalibrationError as e:
        if unreadable is not None and (args.anchor or "in none of the files" in str(e)):
            raise CalibrationError(f"{e}; the current calibration cannot be used: {unreadable}", hint=e.hint) from None
        raise
    calib = result.calibration
    calib.check_against_config(config, "the imported calibration")
    _check_nominal(result, config)
    _print_import(result, current)
    if args.dry_run:
        print("checked; nothing saved (--dry-run)")
        return 0
    path = save_calibration(calib, config.calibration_file)
    replaced = (f", replacing {current.calibration_id}" if current is not None
                else ", replacing a file that could not be read" if unreadable is not None else "")
    print(f"saved {path} (calibration id {calib.calibration_id}{replaced})")
    if args.json:
        save_calibration(calib, Path(args.json))
        print(f"wrote {args.json}")
    return 0


def _check_nominal(result, config) -> None:
    """Every imported camera within NOMINAL_DISTANCE_M of its configured mount (cameras.<id>.nominal)."""
    import numpy as np

    from calibration.errors import CalibrationRejected

    for cam_id in result.intrinsics_from:
        centre = result.calibration.model(cam_id).center_station
        nominal = np.array(config.cameras[cam_id].nominal.position_m, float)
        off = float(np.linalg.norm(centre - nominal))
        if off > NOMINAL_DISTANCE_M:
            raise CalibrationRejected(
                f"camera {cam_id}: the import places it at ({', '.join(f'{v:.3f}' for v in centre)}) m, {off:.3g} m "
                f"from its mount in the configuration (cameras.{cam_id}.nominal.position_m); placed by "
                f"{result.pose_from[cam_id]}; nothing saved",
                hint="check the length unit of T (--unit) and which pose belongs to which camera; if the camera "
                "really stands there, correct its nominal position in the station configuration")


def _print_import(result, current) -> None:
    calib = result.calibration
    print("camera  fx(px)    fy(px)    cx(px)   cy(px)   dist  k1       centre in station (m)     from")
    for cam_id, c in calib.cameras.items():
        m = c.model
        x, y, z = m.center_station
        where = result.intrinsics_from.get(cam_id, "kept from the current calibration")
        print(f"{cam_id:7s} {m.K[0, 0]:9.2f} {m.K[1, 1]:9.2f} {m.K[0, 2]:8.2f} {m.K[1, 2]:8.2f} {m.dist.size:4d}  "
              f"{m.dist[0]:8.4f} {x:+8.4f} {y:+8.4f} {z:+8.4f}  {where}")
        if cam_id in result.pose_from:
            print(f"{'':7s} pose: {result.pose_from[cam_id]}")
    print("pair  left  right  baseline(mm)")
    for wheel in calib.pairs:
        p = calib.pair(wheel)
        print(f"{wheel:5s} {calib.pairs[wheel][0]:5s} {calib.pairs[wheel][1]:6s} {p.baseline_m * 1000:12.2f}")
    if result.kept:
        print(f"kept from the current calibration ({current.calibration_id}): {', '.join(result.kept)}")
    if result.covariance_dropped:
        print("note: the current calibration's pair covariances are not kept (an import has none, and a file holds "
              "every pair's or none): measurements leave the calibration's share out of their uncertainty")


def _export(args) -> int:
    from calibration.calib_file import load_calibration
    from calibration.opencv_files import export_opencv

    config = load_config(args.config)
    path = args.file or config.calibration_file
    calib = load_calibration(path, None if args.file else config)
    files = export_opencv(calib, args.directory)
    for f in files:
        print(f"wrote {f}")
    print(f"calibration {calib.calibration_id} from {path}: {len(calib.cameras)} camera(s), {len(calib.pairs)} pair(s)")
    return 0
