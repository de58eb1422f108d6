"""`station cameras`: the configured cameras and their state."""

from __future__ import annotations

import json
from pathlib import Path


def add_arguments(parser):
    parser.add_argument("--snap", action="store_true", help="grab one frame from every open camera now")
    parser.add_argument("--json", action="store_true", help="print JSON instead of a table")


def last_saved_frames(captures_dir: Path) -> dict[str, dict]:
    """camera id -> {cycle, timestamp/frame id} from the newest saved capture holding it."""
    out: dict[str, dict] = {}
    if not captures_dir.is_dir():
        return out
    for cycle in sorted((p for p in captures_dir.iterdir() if (p / "cycle.json").exists()), reverse=True):
        try:
            meta = json.loads((cycle / "cycle.json").read_text())
        except (OSError, ValueError):
            continue
        for cid, info in meta.get("cameras", {}).items():
            out.setdefault(cid, {"cycle": cycle.name, "saved_utc": meta.get("saved_utc", "?"),
                                 "frame_id": info.get("frame_id")})
        if len(out) >= 8:
            break
    return out


def run(args) -> int:
    from drivers.context import DriverContext
    from drivers.registry import build_context
    from station.capture.cameras import close_cameras, open_cameras, settings_for
    from station.config import load_config
    from station.errors import CODED_ERRORS

    config = load_config(args.config)
    try:
        context = build_context([c.uri for c in config.cameras.values()], config)
    except CODED_ERRORS as e:
        context, context_error = DriverContext(), str(e)
    else:
        context_error = None
    specs = {cid: (c.uri, settings_for(c)) for cid, c in config.cameras.items()}
    cams, failures = open_cameras(specs, context)
    saved = last_saved_frames(config.data_path("captures"))
    rows = []
    try:
        for cid, c in config.cameras.items():
            row = {"id": cid, "wheel": c.wheel, "role": c.role, "uri": c.uri, "open": cid in cams}
            if cid in cams:
                cam = cams[cid]
                if args.snap:
                    try:
                        cam.snap(max(config.capture.timeout_s, context.capture_timeout_s))
                    except CODED_ERRORS as e:
                        row["error"] = str(e)
                st = cam.state()
                if "identity" in st:
                    i = st["identity"]
                    row.update(vendor=i.vendor, model=i.model, serial=i.serial, resolution=f"{i.width}x{i.height}")
                row["error"] = row.get("error") or st.get("error")
                if "last_frame" in st:
                    lf = st["last_frame"]
                    row["last_frame"] = f"now: #{lf['frame_id']} mean {lf['mean']:.1f}"
            else:
                row["error"] = str(failures.get(cid, context_error or "not opened"))
            if "last_frame" not in row and cid in saved:
                s = saved[cid]
                row["last_frame"] = f"{s['cycle']} #{s['frame_id']}"
            rows.append(row)
    finally:
        close_cameras(cams)
        context.close()
    if args.json:
        print(json.dumps(rows, indent=1))
    else:
        _print_table(rows)
    return 0 if not failures and not context_error else 2


def _print_table(rows):
    cols = [("id", "camera"), ("wheel", "wheel"), ("role", "role"), ("state", "state"), ("vendor", "vendor"),
            ("model", "model"), ("serial", "serial"), ("resolution", "resolution"), ("last_frame", "last frame")]
    table = []
    for r in rows:
        r = dict(r, state="open" if r["open"] else "FAILED")
        table.append([str(r.get(k) or "-") for k, _ in cols])
    widths = [max(len(h), *(len(t[i]) for t in table)) for i, (_, h) in enumerate(cols)]
    print("  ".join(h.ljust(w) for (_, h), w in zip(cols, widths)))
    for t in table:
        print("  ".join(v.ljust(w) for v, w in zip(t, widths)))
    for r in rows:
        err = r.get("error")
        if err:
            print(err if err.startswith(f"{r['id']}: ") else f"{r['id']}: {err}")
