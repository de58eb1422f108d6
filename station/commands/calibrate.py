"""`station calibrate`: calibrate every camera and pair with the box (docs/calibration.md).

Asks the operator to place the box (the simulated operator on a simulated station), takes the
images through the camera drivers, detects the box, runs the paper's closed form and the
bundle adjustment per pair, prints a table per camera and pair, checks the configured limits,
and saves the calibration atomically. A refused or failed run saves nothing and leaves the
previous file untouched.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path


from calibration.errors import CalibrationError, CalibrationRejected
from station.commands.arguments import seed
from station.config import load_box, load_config


def add_arguments(parser) -> None:
    parser.add_argument("--json", metavar="PATH", help="also write the calibration as JSON to PATH")
    parser.add_argument("--seed", type=seed, default=0, help="simulated operator's seed (box poses)")
    parser.add_argument("--poses", type=int, default=None,
                        help="box poses per pair for the intrinsics (default: calibration.intrinsic_poses)")


def _progress(text: str) -> None:
    print(f"[{time.strftime('%H:%M:%S')}] {text}", file=sys.stderr, flush=True)


def run(args) -> int:
    from calibration.box_detect import BoxDetector
    from calibration.calib_file import save_calibration
    from calibration.station_calibration import assemble, calibrate_pair, check_limits, fixture_poses
    from drivers.registry import build_context
    from station.capture.cameras import close_cameras, open_station_cameras
    from station.capture.linearity import response_warnings
    from station.capture.sync import capture_averaged
    from station.operator import TerminalOperator

    config = load_config(args.config)
    box = load_box(config.box_path)
    n_poses = args.poses or config.calibration.intrinsic_poses
    if n_poses < 3:
        raise CalibrationError(f"--poses {n_poses}: at least 3 box poses are needed for the intrinsics")
    # Assemble once, through the driver registry: sim:// brings its simulated station in the context.
    context = build_context([c.uri for c in config.cameras.values()], config)
    # A simulated station brings the operator who places the box; a real one has a person.
    sim = context.simulation
    operator = sim.calibration_operator(box, args.seed) if sim is not None else TerminalOperator()
    try:
        cameras = open_station_cameras(config, context)
    except BaseException:
        context.close()
        raise
    timeout = max(float(config.capture.timeout_s), context.capture_timeout_s)
    detector = BoxDetector(box)

    # The box stands still like the car: each image is the mean of a burst (capture.frames_averaged),
    # so the corners carry 1/sqrt(N) of one frame's noise into every camera's pose and lens.
    n_frames = config.capture.frames_averaged

    warned = set()  # cameras whose grey is not proportional to light, said once each

    def take(cam_ids, what):
        out = {}
        frames = capture_averaged({c: cameras[c] for c in cam_ids}, timeout, frames=n_frames)
        for cam, text in response_warnings(frames, config):  # the corners hold; the rims will not
            if cam not in warned:
                warned.add(cam)
                _progress(f"warning: {text}")
        for cam in cam_ids:
            det = detector.detect(frames[cam].image)
            _progress(f"{cam}: {what}: {det.n_points} corners on faces {', '.join(det.faces) or 'none'}")
            out[cam] = det
        return out

    fixtures = fixture_poses(config)
    results = {}
    try:
        for wheel, pair in config.pairs.items():
            ids = [pair.precision, pair.reference]
            dets = {c: [] for c in ids}
            for i in range(n_poses):
                operator.place_box_for_intrinsics(ids, i)
                got = take(ids, f"pose {i + 1}/{n_poses}")
                for c in ids:
                    dets[c].append(got[c])
            operator.place_box_at_fixture(wheel)
            fixture_dets = take(ids, f"box at the {wheel} fixture")
            sizes = {c: (config.cameras[c].width, config.cameras[c].height) for c in ids}
            results[wheel] = calibrate_pair(wheel, *ids, sizes, dets, fixture_dets, fixtures[wheel], _progress)
        operator.done()
    finally:
        close_cameras(cameras)
        context.close()
    calib = assemble(config, results, box)
    print_tables(calib)
    reasons = check_limits(calib, config.calibration.limits)
    if reasons:
        raise CalibrationRejected("calibration refused, nothing saved: " + "; ".join(reasons),
                                  hint="check the named camera's view of the box (focus, light, box placement) and recalibrate")
    path = save_calibration(calib, config.calibration_file)
    print(f"saved {path} (calibration id {calib.calibration_id})")
    if args.json:
        save_calibration(calib, Path(args.json))
        print(f"wrote {args.json}")
    return 0


def print_tables(calib) -> None:
    import numpy as np

    from calibration.refine import INTRINSIC_NAMES

    print("camera  fx(px)    fy(px)    cx(px)   cy(px)   k1       k2       k3       p1        p2        "
          "rms(px) points  std fx  std cx  std cy  std k1   pos std(mm) rot std(deg)")
    for cam_id, c in calib.cameras.items():
        m, s = c.model, c.std
        pos = np.max(s.get("position_m", [np.nan])) * 1000
        rot = np.max(s.get("rotation_deg", [np.nan]))
        k1, k2, p1, p2, k3 = m.dist[:5]  # the box calibration's five (an import may add k4.. s4)
        print(f"{cam_id:7s} {m.K[0, 0]:9.2f} {m.K[1, 1]:9.2f} {m.K[0, 2]:8.2f} {m.K[1, 2]:8.2f} {k1:8.4f} {k2:8.4f} "
              f"{k3:8.4f} {p1:9.2e} {p2:9.2e} {c.reprojection_rms_px:7.3f} {c.n_points:6d}  {s.get('fx', np.nan):6.3f}"
              f"  {s.get('cx', np.nan):6.3f}  {s.get('cy', np.nan):6.3f}  {s.get('k1', np.nan):7.5f}  {pos:10.4f}  {rot:11.5f}")
    print("standard deviations")
    print("camera  " + " ".join(f"{n:>9s}" for n in INTRINSIC_NAMES) + "  pos x,y,z (mm)         rot x,y,z (deg)")
    for cam_id, c in calib.cameras.items():
        s = c.std
        pos = " ".join(f"{v * 1000:6.4f}" for v in s.get("position_m", [np.nan] * 3))
        rot = " ".join(f"{v:7.5f}" for v in s.get("rotation_deg", [np.nan] * 3))
        print(f"{cam_id:7s} " + " ".join(f"{s.get(n, np.nan):9.2e}" for n in INTRINSIC_NAMES) + f"  {pos}  {rot}")
    print("pair  left  right  baseline(mm)")
    for wheel in calib.pairs:
        p = calib.pair(wheel)
        print(f"{wheel:5s} {p.left.name:5s} {p.right.name:6s} {p.baseline_m * 1000:12.3f}")
