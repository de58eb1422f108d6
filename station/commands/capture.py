"""`station capture --out DIR`: one synchronised set from all eight cameras, saved losslessly."""

from __future__ import annotations

from station.commands.arguments import seed


def add_arguments(parser):
    parser.add_argument("--out", metavar="DIR", help="directory to create for the set "
                        "(default: <data_dir>/captures/<cycle id>)")
    parser.add_argument("--seed", type=seed, default=None,
                        help="simulated station only: the random vehicle on the lift (default: none)")
    parser.add_argument("--timeout", type=float, default=None, help="capture deadline in s (default: capture.timeout_s)")
    parser.add_argument("--frames", type=int, default=None, metavar="N",
                        help="frames per camera, kept as their mean (default: capture.frames_averaged; 1: one raw frame)")


def run(args) -> int:
    import time
    from pathlib import Path

    from drivers.registry import build_context
    from station.capture.cameras import close_cameras, open_station_cameras, open_trigger_board
    from station.capture.saving import capture_and_save, new_cycle_id
    from station.config import load_config
    from station.errors import CODED_ERRORS, StationError

    config = load_config(args.config)
    n_frames = config.capture.frames_averaged if args.frames is None else args.frames
    if not 1 <= n_frames <= 64:
        raise StationError(f"--frames {n_frames}: expected 1 to 64 frames per camera", hint="e.g. --frames 8")
    cycle_id = new_cycle_id()
    out = Path(args.out) if args.out else config.data_path("captures", cycle_id)
    if out.exists():
        raise StationError(f"{out} already exists; a capture is never written over another",
                           hint="choose a new --out directory")
    context = build_context([c.uri for c in config.cameras.values()], config, seed=args.seed)
    timeout = args.timeout or max(config.capture.timeout_s, context.capture_timeout_s)
    board = None
    cameras: dict = {}
    try:
        cameras = open_station_cameras(config, context)
        board = open_trigger_board(config, context)
        truth = context.simulation.truth() if context.simulation is not None else None
        t0 = time.monotonic()
        try:
            frames, path = capture_and_save(cameras, timeout, out, trigger_board=board, truth=truth,
                                            extra={"station": config.name}, frames_averaged=n_frames)
        except CODED_ERRORS as e:
            if getattr(e, "saved_to", None):
                print(f"partial set ({len(e.frames)} of {len(cameras)} frames) kept in {e.saved_to}")
            raise
    finally:
        if board is not None:
            board.close()
        close_cameras(cameras)
        context.close()
    stamps = [f.timestamp_ns for f in frames.values()]
    burst = f" (each the mean of {n_frames})" if n_frames > 1 else ""
    print(f"captured {len(frames)} frames{burst} in {time.monotonic() - t0:.2f} s, frame timestamps within "
          f"{(max(stamps) - min(stamps)) / 1e6:.1f} ms -> {path}")
    return 0
