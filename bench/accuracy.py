"""Accuracy of toe and camber on random simulated vehicles (issue 3's benchmark).

For each scenario, N random vehicles (toe within +/-2 deg, camber within +/-3 deg, offset and
yaw on the lift, lighting differing between cameras) are rendered by the simulator and
measured with the calibration that `station calibrate` produced ("file") and with the
simulator's true cameras ("truth"), which separates calibration error from the rest.
Prints per angle the mean, RMS and max error (deg) and the failed cycles, for both methods
(the paper's section 3.2 and the 3-D circle fit), and how well the stated uncertainty
matches the observed spread.

    .venv/bin/python bench/accuracy.py --n 50            # all scenarios
    .venv/bin/python bench/accuracy.py --n 10 --scenario sigma2
    .venv/bin/python bench/accuracy.py --n 20 --scenario sigma2 --repeat 2   # and repeatability
    .venv/bin/python bench/accuracy.py --n 50 --scenario sigma2 --calibration file \
        --more-calibrations /tmp/cal11,/tmp/cal12    # data dirs of `station calibrate --seed K`: pooled

Scenarios: sigma2 (the issue's), sigma5 (more sensor noise), dark-cam (cam2 20 % darker than
its pair), dark-rim (rim albedo 0.2-0.4: anthracite rims against black tyres). Outside the
random vehicles' envelope, sigma 2 (not in "all"): the scenarios of bench/outside_envelope.py
(big angles, odd rims and bodies, a soft focus, narrow lips, a big sidewall bulge, bright tyres,
harsh light, diffuse light, strong vignetting, gamma-encoding cameras). Every rim a shop sees
(issue 37), sigma 2, not in "all": the scenarios of bench/rim_scenarios.py (rim finishes from
silver to chrome, brake dust, dirt, tyre lettering, protector ridges, low contrast, the arch's
shadow, a low sun with auto or fixed exposure, shop reflections in the paint, the glossy
finishes under the station's diffuse light panels).

Each table also counts the wheels refused (a cycle's failure 404 names them; any other failure
refuses the cycle's four wheels), with their reasons, and the wheels silently wrong: off by
more than 3 times their stated uncertainty in toe or camber with no warning flag of theirs.
"""

from __future__ import annotations

import argparse
import sys
import time
from collections import Counter
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from bench import outside_envelope, rim_scenarios  # noqa: E402
from simulators import image_cache  # noqa: E402
from calibration.station_frame import WHEELS  # noqa: E402
from station.config import load_config
from station.capture.exposure_bracket import measure_bracketed  # noqa: E402
from station.capture.frame_average import mean_image  # noqa: E402
from station.measure import measure_frames  # noqa: E402
from station.result import Measurement  # noqa: E402

SCENARIOS = {
    # name: (noise sigma, darker camera or None, rim albedo range or None (the random vehicle's))
    "sigma2": (2.0, None, None),
    "sigma5": (5.0, None, None),
    "dark-cam": (2.0, "cam2", None),
    "dark-rim": (2.0, None, (0.2, 0.4)),  # anthracite rims: the flange little brighter than the tyre
}


SCENARIOS.update({kind: (2.0, None, None) for kind in outside_envelope.KINDS})
SCENARIOS.update({kind: (2.0, None, None) for kind in rim_scenarios.KINDS})
NOT_IN_ALL = (*outside_envelope.KINDS, *rim_scenarios.KINDS)
WHEEL_UNCERTAIN = 404  # a cycle's failure code when it refuses some wheels and names them


GROUPS = {
    "toe": [f"{w}.toe" for w in WHEELS],
    "camber": [f"{w}.camber" for w in WHEELS],
    "total toe": ["front.total_toe", "rear.total_toe"],
    "thrust": ["thrust"],
}


def _errors(result: Measurement) -> dict[str, float]:
    e = result.errors
    out = {}
    for w in WHEELS:
        out[f"{w}.toe"] = e[w]["toe_error_deg"]
        out[f"{w}.camber"] = e[w]["camber_error_deg"]
    for k in ("front.total_toe", "rear.total_toe", "thrust"):
        out[k] = e[k]
    return out


def _wheel_errors(result: Measurement, truth: dict) -> dict[str, tuple[float, float]]:
    """{wheel: (toe error, camber error)} (deg, measured - true) of every wheel the result holds,
    valid or not (a refused wheel's angles are still there): against the rim planes' truth
    (``rim_toe_deg``, ``rim_camber_deg``), or the alignment's where the truth has no rim's."""
    if result.errors is not None:
        return {w: (result.errors[w]["toe_error_deg"], result.errors[w]["camber_error_deg"])
                for w in WHEELS if w in result.errors}
    out = {}
    for w, r in result.wheels.items():
        t = truth["wheels"][w]
        out[w] = (r.toe_deg - t.get("rim_toe_deg", t["toe_deg"]), r.camber_deg - t.get("rim_camber_deg", t["camber_deg"]))
    return out


def _reason(code: int | None, cycle: bool) -> str:
    """A refusal's reason as the tables group it: the code and its error's name (the sentence,
    which names cameras and millimetres, goes to stderr per cycle), "cycle" when the whole
    cycle was refused."""
    from station.errors import all_error_classes

    names = {WHEEL_UNCERTAIN: "WheelUncertain"}
    for cls in reversed(all_error_classes()):
        names[cls.code] = cls.__name__
    return f"{code} {names.get(code, 'error')}" + (", cycle" if cycle else "")


def _refused_and_silent(result: Measurement, truth: dict) -> tuple[dict[str, str], list[str], int, list[str]]:
    """({refused wheel: reason}, [silently wrong wheels], wheels judged, [withheld wrong wheels])
    of one cycle. A failure 404 refuses the wheels it names; any other failure the whole cycle
    (its four wheels). A wheel of a valid cycle is silently wrong when its toe or camber error
    exceeds 3 times its stated std and no warning flag names it. A refused cycle reports no
    angle at all (its JSON has no wheels), so the wheels a 404 does not name are not judged; those
    beyond 3 stated are listed apart as withheld."""
    refused: dict[str, str] = {}
    if not result.valid:
        f = result.failure
        if f is not None and f.code == WHEEL_UNCERTAIN and f.wheel:
            refused = {w.strip(): _reason(f.code, False) for w in f.wheel.split(",")}
        else:
            return {w: _reason(f.code if f is not None else None, True) for w in WHEELS}, [], 0, []
    beyond = []
    for w, (e_toe, e_camber) in _wheel_errors(result, truth).items():
        if w in refused:
            continue
        r = result.wheels[w]
        if ((abs(e_toe) > 3 * r.toe_std_deg or abs(e_camber) > 3 * r.camber_std_deg)
                and not any(f.wheel == w for f in result.warning_flags)):
            beyond.append(w)
    if not result.valid:
        return refused, [], 0, beyond
    return refused, beyond, len(WHEELS), []


def _stated(result: Measurement) -> dict[str, float]:
    out = {}
    for w in WHEELS:
        out[f"{w}.toe"] = result.wheels[w].toe_std_deg
        out[f"{w}.camber"] = result.wheels[w].camber_std_deg
    out["front.total_toe"] = result.axles["front"].total_toe_std_deg
    out["rear.total_toe"] = result.axles["rear"].total_toe_std_deg
    out["thrust"] = result.thrust_std_deg
    return out


def _images(world, scene, scenario: str, seed: int, cache: Path | None, capture: int = 0, frames: int = 1) -> dict:
    """The eight images of one vehicle; with ``cache``, rendered once and kept there
    (``<scenario>-<seed>.npz``) so that a change of the measurement can be re-measured on the
    very same images in minutes instead of re-rendering them. ``capture`` k > 0: the same
    scene captured again, with the k-th fresh draw of sensor noise (``-r<k>`` in the cache).
    ``frames`` N > 1: each camera's image is the mean of N frames, as the station's
    ``capture.frames_averaged`` keeps it (station/capture/frame_average.py; ``-f<N>`` in the cache);
    the first is the single frame's, the others have fresh sensor noise."""
    name = f"{rim_scenarios.images_of(outside_envelope.images_of(scenario))}-{seed}" + (f"-r{capture}" if capture else "")
    name += f"-f{frames}" if frames > 1 else ""
    path = cache / f"{name}.npz" if cache is not None else None
    images = image_cache.load(path, world) if path is not None else None  # None: another station's, or none
    if images is not None:
        return images
    rng = np.random.default_rng(10_000 + seed) if capture == 0 else np.random.default_rng([10_000 + seed, capture])
    bursts = [outside_envelope.encode(scenario, world.render_all(rng))]
    bursts += [outside_envelope.encode(scenario, world.render_all(np.random.default_rng([10_000 + seed, capture, k])))
               for k in range(1, frames)]  # world.clean_image renders the scene once for all of them
    images = bursts[0] if frames == 1 else {c: mean_image([b[c] for b in bursts]) for c in bursts[0]}
    if path is not None:
        image_cache.save(path, images, world)
    return images


def _reexposed(world, scenario: str, seed: int, cams: list[str], factor: float, frames: int) -> dict:
    """The cameras ``cams`` of the world's scene taken again at ``factor`` times their exposure,
    as the station's cycle does for a lip at the white (station/capture/exposure_bracket.py):
    ``frames`` fresh frames each, averaged. Rendered for each run, not kept in ``cache``."""
    index = {c: i for i, c in enumerate(world.cameras)}
    out = {}
    for c in cams:
        shots = [outside_envelope.encode(scenario, {c: world.render(
            c, np.random.default_rng([20_000 + seed, index[c], round(factor * 1000), k]), exposure=factor)})[c]
            for k in range(frames)]
        out[c] = shots[0] if frames == 1 else mean_image(shots)
    return out


def run(config, cameras_by_source: dict, n: int, scenario: str, seed0: int, methods,
        covariance_by_source: dict | None = None, cache: Path | None = None, repeat: int = 0,
        frames: int = 1) -> dict:
    """Per (calibration, method): errors, stated std, failures, times, warnings; with
    ``repeat`` k, the first calibration and method also measure every vehicle k more times on
    fresh captures of the same scene ("captures": per vehicle, the errors of each capture)."""
    from simulators.world import SimWorld

    sigma, dark, albedo = SCENARIOS[scenario]
    world = SimWorld.from_config(config, noise_sigma=sigma, gain_override={dark: 0.8} if dark else None)
    rows = {(src, m): {"err": [], "std": [], "failed": 0, "time": [], "warnings": Counter(), "captures": [],
                       "refused": Counter(), "silent": [], "judged": 0, "withheld": [], "exposures": Counter()}
            for src in cameras_by_source for m in methods}
    first = (next(iter(cameras_by_source)), methods[0])
    config = outside_envelope.configured(scenario, config)
    for i in range(n):
        seed = seed0 + i
        over = {}
        if albedo is not None:  # its own stream: the vehicle itself stays that of the seed
            over["rim_albedo"] = float(np.random.default_rng([seed, 1]).uniform(*albedo))
        if scenario in rim_scenarios.KINDS:
            scene = rim_scenarios.scene_for(world, scenario, seed, config.nominal_vehicle, **over)
        else:
            scene = outside_envelope.scene_for(world, scenario, seed, config.nominal_vehicle, **over)
        world.set_scene(scene)
        images = _images(world, scene, scenario, seed, cache, frames=frames)
        truth = world.truth(scene)
        retaken: dict = {}  # (camera, factor) -> image, rendered once per vehicle for every source and method
        render_s = [0.0]

        def recapture(ids: list[str], factor: float) -> dict:
            t = time.perf_counter()
            missing = [c for c in ids if (c, factor) not in retaken]
            retaken.update({(c, factor): im for c, im in
                            _reexposed(world, scenario, seed, missing, factor, frames).items()})
            render_s[0] += time.perf_counter() - t
            return {c: retaken[(c, factor)] for c in ids}

        for src, cams in cameras_by_source.items():
            for m in methods:
                t0, render_s[0] = time.perf_counter(), 0.0
                res, _, exposures = measure_bracketed(
                    images, lambda ims: measure_frames(ims, cams, config, method=m,
                                                       calibration_cov=(covariance_by_source or {}).get(src)),
                    recapture, config.capture.exposure_steps)
                rows[(src, m)]["time"].append(time.perf_counter() - t0 - render_s[0])  # the second take's rendering left out
                rows[(src, m)]["exposures"].update(exposures.values())
                res.add_truth(truth)
                refused, silent, judged, withheld = _refused_and_silent(res, truth)
                rows[(src, m)]["refused"].update(refused.values())
                rows[(src, m)]["silent"] += [f"{seed}:{w}" for w in silent]
                rows[(src, m)]["withheld"] += [f"{seed}:{w}" for w in withheld]
                rows[(src, m)]["judged"] += judged
                if not res.valid:
                    rows[(src, m)]["failed"] += 1
                    print(f"  seed {seed} {src}/{m}: FAILED {res.failure.message}", file=sys.stderr)
                    continue
                rows[(src, m)]["warnings"].update(f.kind for f in res.warning_flags)
                errs = _errors(res)
                worst = max(errs, key=lambda k: abs(errs[k]))
                if abs(errs[worst]) > 0.05:
                    q = {w: res.wheels[w].quality for w in WHEELS}
                    print(f"  seed {seed} {src}/{m}: worst {worst} {errs[worst]:+.3f} deg; epipolar px "
                          + " ".join(f"{w}:{q[w].epipolar_rms_px:.2f}" for w in WHEELS), file=sys.stderr)
                rows[(src, m)]["err"].append(errs)
                rows[(src, m)]["std"].append(_stated(res))
                if repeat and (src, m) == first:
                    rows[first]["captures"].append([errs] + _recaptured(world, scene, scenario, seed, cache, repeat,
                                                                        cams, config, m, covariance_by_source, src,
                                                                        frames))
        print(f"  {scenario}: vehicle {i + 1}/{n} done", file=sys.stderr, flush=True)
    return rows


def _recaptured(world, scene, scenario, seed, cache, repeat, cams, config, method, covariances, src,
                frames: int = 1) -> list[dict]:
    """The errors of ``repeat`` more captures of the same scene (fresh sensor noise), the
    failed ones left out."""
    out = []
    for k in range(1, repeat + 1):
        res = measure_frames(_images(world, scene, scenario, seed, cache, capture=k, frames=frames), cams, config, method=method,
                             calibration_cov=(covariances or {}).get(src))
        if res.valid:
            res.add_truth(world.truth(scene))
            out.append(_errors(res))
        else:
            print(f"  seed {seed} capture {k}: FAILED {res.failure.message}", file=sys.stderr)
    return out


def _values(per_cycle: list[dict], names: list[str]) -> np.ndarray:
    """The angles ``names`` of every cycle's {angle: value} (errors or stated std), flat (cycles x names,)."""
    return np.array([[row[k] for k in names] for row in per_cycle], float).ravel()


def honest_ratio_range(std: list[dict], names: list[str], draws: int = 2000) -> tuple[float, float]:
    """The 5th and 95th percentiles of stated std / RMS had each wheel's error been drawn from
    its own statement (a normal of the stated std, independent; ``draws`` sets, fixed seed). Where
    a few wheels state far more than the rest, their few draws carry the RMS, and honest
    statements alone spread the ratio widely: an observed ratio inside this range is what honest
    statements of these sizes give (the wheels' common calibration error, left out, widens it)."""
    s = _values(std, names)                                                   # (wheels,)
    draws_e = np.random.default_rng(0).normal(size=(draws, len(s))) * s       # (draws, wheels)
    ratio = np.sqrt(np.mean(s ** 2)) / np.maximum(np.sqrt(np.mean(draws_e ** 2, axis=1)), 1e-30)
    lo, hi = np.percentile(ratio, [5, 95])
    return float(lo), float(hi)


def print_repeatability(rows: dict) -> None:
    """Same vehicle, same pose, captured again with fresh sensor noise: the spread of the
    readings a technician sees when measuring twice (the edge biases repeat, so this is
    smaller than the error)."""
    for (src, m), r in rows.items():
        caps = [c for c in r["captures"] if len(c) >= 2]
        if not caps:
            continue
        k = max(len(c) for c in caps)
        print(f"\nrepeatability, {src}/{m}: {len(caps)} vehicles, {k} captures each (fresh sensor noise)\n")
        print("| angle | RMS of per-wheel std (deg) | max spread (deg) | share spread > 0.02 deg | RMS error (deg) |")
        print("|---|---|---|---|---|")
        for group, names in GROUPS.items():
            sd, spread = [], []
            for c in caps:
                vals = np.array([[e[key] for key in names] for e in c])       # (captures, angles)
                sd.extend(np.std(vals, axis=0, ddof=1))
                spread.extend(np.ptp(vals, axis=0))
            e = _values(r["err"], names)
            spread = np.array(spread)
            print(f"| {group} | {np.sqrt(np.mean(np.square(sd))):.4f} | {spread.max():.4f} | "
                  f"{np.mean(spread > 0.02):.0%} | {np.sqrt(np.mean(e ** 2)):.4f} |")


def print_reliability(rows: dict) -> None:
    """Stated uncertainty against the observed error, wheels grouped by what they state: an
    honest statement has ratio ~1 in every group, not only on average."""
    edges = (0.0, 0.015, 0.03, 0.06, 0.12, np.inf)
    for (src, m), r in rows.items():
        if m != "circle" or not r["err"]:
            continue
        print(f"\nstated against observed, {src}/{m}, wheels grouped by their stated std (deg)\n")
        print("| angle | stated | wheels | RMS stated | RMS error | stated / RMS |")
        print("|---|---|---|---|---|---|")
        for group in ("toe", "camber"):
            e, s = np.abs(_values(r["err"], GROUPS[group])), _values(r["std"], GROUPS[group])
            for lo, hi in zip(edges[:-1], edges[1:]):
                sel = (s >= lo) & (s < hi)
                if sel.any():
                    rs, re = np.sqrt(np.mean(s[sel] ** 2)), np.sqrt(np.mean(e[sel] ** 2))
                    print(f"| {group} | {lo:.3f}-{hi:.3f} | {sel.sum()} | {rs:.4f} | {re:.4f} | "
                          f"{rs / re if re > 0 else float('nan'):.2f} |")


def print_pooled(rows: dict) -> None:
    """With more than one calibration ("file", "file:<dir>"): each angle's RMS and max error and
    stated/RMS over all of them together. One calibration's error is a single draw, the same in
    every cycle: its share of the stated uncertainty can only be judged over several."""
    for m in dict.fromkeys(m for _, m in rows):
        files = [r for (src, mm), r in rows.items() if mm == m and src.startswith("file") and r["err"]]
        if len(files) < 2:
            continue
        print(f"\npooled over {len(files)} calibrations, {m}\n")
        print("| angle | RMS (deg) | max abs (deg) | stated std / RMS | per calibration: RMS | per calibration: stated/RMS |")
        print("|---|---|---|---|---|---|")
        for group, names in GROUPS.items():
            per = [(_values(r["err"], names), _values(r["std"], names)) for r in files]
            e, s = np.concatenate([p[0] for p in per]), np.concatenate([p[1] for p in per])
            rms = float(np.sqrt(np.mean(e ** 2)))
            print(f"| {group} | {rms:.4f} | {np.max(np.abs(e)):.4f} | {np.sqrt(np.mean(s ** 2)) / rms:.2f} | "
                  + " ".join(f"{np.sqrt(np.mean(a ** 2)):.4f}" for a, _ in per) + " | "
                  + " ".join(f"{np.sqrt(np.mean(b ** 2) / np.mean(a ** 2)):.2f}" for a, b in per) + " |")


def print_table(scenario: str, rows: dict, n: int) -> None:
    print(f"\n### {scenario}: {n} vehicles")
    # stated std / RMS weighs the few wheels stated most uncertain; the typical wheel's honesty
    # is the median of |error| / stated over 0.674 (its value for honest Gaussian errors)
    print("| calibration | method | angle | mean (deg) | RMS (deg) | max abs (deg) | median abs (deg) | 95th pct abs (deg) "
          "| stated std / RMS | typical abs error / stated | beyond 3 stated | failed |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    for (src, m), r in rows.items():
        for group, names in GROUPS.items():
            if not r["err"]:
                print(f"| {src} | {m} | {group} | - | - | - | - | - | - | - | - | {r['failed']} |")
                continue
            e, s = _values(r["err"], names), _values(r["std"], names)
            rms = float(np.sqrt(np.mean(e ** 2)))
            ratio = float(np.sqrt(np.mean(s ** 2)) / rms) if rms > 0 else float("nan")
            z = np.abs(e) / np.maximum(s, 1e-12)
            print(f"| {src} | {m} | {group} | {np.mean(e):+.4f} | {rms:.4f} | {np.max(np.abs(e)):.4f} | "
                  f"{np.median(np.abs(e)):.4f} | {np.percentile(np.abs(e), 95):.4f} | {ratio:.2f} | "
                  f"{np.median(z) / 0.674:.2f} | {np.mean(z > 3):.0%} | {r['failed']} |")
    for (src, m), r in rows.items():
        if r["err"]:
            spans = [f"{g} " + "-".join(f"{v:.2f}" for v in honest_ratio_range(r["std"], GROUPS[g])) for g in ("toe", "camber")]
            print(f"\nstated std / RMS, {src}/{m}, 90 % range had every error been drawn from its statement: {', '.join(spans)}")
    # no camera moved after calibration in the simulation: every drift warning is a false alarm
    for (src, m), r in rows.items():
        w = r["warnings"]
        print(f"\nwarnings, {src}/{m}, of {4 * len(r['err'])} wheels: uncertain {w['uncertain']}, "
              f"drift {w['drift']} (false: no camera moved), unchecked {w['unchecked']}, runner-up {w['runner_up']}, "
              f"rim size {w['rim_size']}")
    for (src, m), r in rows.items():
        refused = sum(r["refused"].values())
        reasons = "; ".join(f"{k}: {v}" for k, v in r["refused"].most_common()) or "-"
        print(f"\nrefused, {src}/{m}: {refused} of {4 * n} wheels ({reasons}); silent wrong (> 3 stated, no warning): "
              f"{len(r['silent'])} of {r['judged']} wheels of valid cycles" + (f" ({', '.join(r['silent'])})" if r["silent"] else "")
              + (f"; beyond 3 stated but withheld with their refused cycle: {', '.join(r['withheld'])}" if r["withheld"] else ""))
        if r["exposures"]:
            print(f"\ncameras taken again at a shorter exposure (their lip at the white), {src}/{m}: "
                  + ", ".join(f"{v} at {k:g}x" for k, v in sorted(r["exposures"].items(), reverse=True)))
    print_reliability(rows)
    print_repeatability(rows)
    times = [t for r in rows.values() for t in r["time"]]
    print(f"\nmeasurement time per cycle (capture excluded): median {np.median(times) * 1000:.0f} ms")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--n", type=int, default=50)
    ap.add_argument("--seed", type=int, default=1000)
    ap.add_argument("--config", default=None)
    ap.add_argument("--scenario", choices=list(SCENARIOS) + ["all"], default="all")
    ap.add_argument("--calibration", choices=["file", "truth", "both"], default="both")
    ap.add_argument("--methods", default="circle,paper")
    ap.add_argument("--repeat", type=int, default=0,
                    help="measure every vehicle this many more times on fresh captures (new sensor noise): repeatability")
    ap.add_argument("--frames", type=int, default=None,
                    help="frames averaged per camera and cycle (default: the configuration's capture.frames_averaged)")
    ap.add_argument("--more-calibrations", default="",
                    help="comma-separated data directories, each holding another `station calibrate` of this station "
                         "(e.g. with --seed K): measured as well, and toe, camber and the stated uncertainty pooled "
                         "over every calibration (one calibration is a single draw of its own error)")
    ap.add_argument("--cache", type=Path, default=None,
                    help="keep the rendered images here and reuse them on later runs (same seeds, same images)")
    args = ap.parse_args()
    config = load_config(args.config)
    from simulators.world import SimWorld

    sources, covariances = {}, {}
    if args.calibration in ("truth", "both"):
        sources["truth"] = SimWorld.from_config(config).cameras
    if args.calibration in ("file", "both"):
        from calibration.calib_file import load_calibration

        path = config.calibration_file
        if not path.exists():
            print(f"no calibration at {path}: run `station calibrate` first (or --calibration truth)", file=sys.stderr)
            return 2
        calib = load_calibration(path, config)
        more = [Path(d) / config.tree.calibration.file for d in args.more_calibrations.split(",") if d]
        for name, path in [("file", path)] + [(f"file:{p.parent.parent.name}", p) for p in more]:
            if not path.exists():
                print(f"no calibration at {path}: run `STATION_DATA_DIR={path.parent.parent} station calibrate` "
                      "first (--seed K for another draw of box poses and noise)", file=sys.stderr)
                return 2
            calib = load_calibration(path, config)
            sources[name] = {cid: calib.model(cid) for cid in config.cameras}
            covariances[name] = calib.pair_covariance  # empty for files written before it was stored
            if not calib.pair_covariance:
                print(f"note: {path} holds no pair covariances (written before they were stored): the calibration's "
                      "share of the stated uncertainty is left out; recalibrate to include it", file=sys.stderr)
    methods = args.methods.split(",")
    scenarios = [s for s in SCENARIOS if s not in NOT_IN_ALL] if args.scenario == "all" else [args.scenario]
    frames = config.capture.frames_averaged if args.frames is None else args.frames
    print(f"# Accuracy benchmark: {args.n} vehicles per scenario, seeds from {args.seed}, "
          f"{frames} frame(s) averaged per camera")
    for sc in scenarios:
        srcs = sources if sc == "sigma2" else {k: v for k, v in sources.items() if k.startswith("file")} or sources
        rows = run(config, srcs, args.n, sc, args.seed, methods, covariances, args.cache, args.repeat, frames)
        print_table(sc, rows, args.n)
        print_pooled(rows)
    return 0


if __name__ == "__main__":
    sys.exit(main())
