"""The simulated station: exact geometry, unbiased anti-aliasing, determinism, the CLI."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from calibration.camera_model import CameraModel, look_at
from simulators.render import lattice_offsets, render, render_radiance
from simulators.scene import Lighting, Scene, TexturedQuad
from simulators.vehicle import Vehicle
from station.config import load_config
from simulators.world import SimWorld

FLAT = Lighting(ambient=1.0, key_strength=0.0, vignetting=0.0, gain=1.0, background_level=0.0)


def small_camera(dist=(0, 0, 0, 0, 0), width=160, height=128, f=600.0, position=(0.0, 0.0, 1.0),
                 target=(0.0, 0.0, 0.0), up=(0.0, 1.0, 0.0)):
    R, t = look_at(np.array(position, float), np.array(target, float), np.array(up, float))
    K = np.array([[f, 0, (width - 1) / 2 + 3.3], [0, f, (height - 1) / 2 - 2.1], [0, 0, 1]])
    return CameraModel("test", width, height, K, np.array(dist, float), R, t)


def white_square_quad(center, half_side, texels=64):
    """A horizontal square quad with a white texture (the quad itself is the bright shape)."""
    c = np.asarray(center, float)
    e = half_side
    corners = c + np.array([[-e, e, 0], [e, e, 0], [e, -e, 0], [-e, -e, 0]])
    return TexturedQuad(corners, np.full((texels, texels), 255, np.uint8), 1.0)


def test_lattice_has_distinct_levels_and_centred_mean():
    off = lattice_offsets(34)
    assert len(np.unique(np.round(off[:, 0], 9))) == 34
    assert len(np.unique(np.round(off[:, 1], 9))) == 34
    np.testing.assert_allclose(off.mean(axis=0), 0, atol=1e-12)


def test_determinism_and_gain():
    cam = small_camera()
    scene = Scene(quads=(white_square_quad((0.0, 0.0, 0.2), 0.05),))
    a = render(cam, scene, Lighting(), np.random.default_rng(5), 2.0)
    b = render(cam, scene, Lighting(), np.random.default_rng(5), 2.0)
    c = render(cam, scene, Lighting(), np.random.default_rng(6), 2.0)
    assert np.array_equal(a, b)
    assert not np.array_equal(a, c)
    dark = render(cam, scene, replace(Lighting(), gain=0.8), np.random.default_rng(5), 2.0)
    ratio = dark.astype(float).mean() / a.astype(float).mean()
    assert 0.76 < ratio < 0.84


# --- exact geometry ------------------------------------------------------------------------
def up_camera(dist=(0, 0, 0, 0, 0), width=160, height=128, f=600.0):
    """A camera at z = 1 looking straight up (+z): everything behind a quad is black ceiling."""
    return small_camera(dist, width, height, f, position=(0.0, 0.0, 1.0), target=(0.0, 0.0, 3.0))


def white_quad(corners):
    return TexturedQuad(np.asarray(corners, float), np.full((8, 8), 255, np.uint8), 1.0)


def projected_region_centroid(camera, corners, n=4000):
    """Area centroid (2,) of the exact image of a planar quad: its boundary projected densely."""
    c = np.asarray(corners, float)
    s = np.linspace(0, 1, n, endpoint=False)[:, None]
    boundary = np.vstack([c[k] + s * (c[(k + 1) % 4] - c[k]) for k in range(4)])
    uv = camera.project(boundary)
    x, y = uv[:, 0], uv[:, 1]
    xn, yn = np.roll(x, -1), np.roll(y, -1)
    cross = x * yn - xn * y
    area = cross.sum() / 2
    return np.array([((x + xn) * cross).sum(), ((y + yn) * cross).sum()]) / (6 * area)


def rendered_centroid(radiance):
    v, u = np.mgrid[0:radiance.shape[0], 0:radiance.shape[1]]
    w = radiance.astype(float)
    return np.array([(w * u).sum(), (w * v).sum()]) / w.sum()


@pytest.mark.parametrize("dist", [(0, 0, 0, 0, 0), (-0.25, 0.1, 4e-4, -3e-4, 0.01)])
def test_quad_image_centroid_matches_projection(dist):
    """The rendered coverage of a tilted quad has the centroid of its exact (distorted) image."""
    cam = up_camera(dist)
    corners = [[0.04, -0.03, 2.0], [-0.08, 0.0, 2.05], [-0.06, 0.07, 2.1], [0.06, 0.04, 2.05]]
    assert cam.in_image(cam.project(np.array(corners)), margin=3).all()
    scene = Scene(quads=(white_quad(corners),))
    radiance, _ = render_radiance(cam, scene, FLAT)
    assert radiance.max() == pytest.approx(1.0, abs=1e-6)
    err = rendered_centroid(radiance) - projected_region_centroid(cam, corners)
    assert np.abs(err).max() < 0.01, err


def test_point_marker_lands_where_project_says_under_strong_distortion():
    cam = up_camera((-0.3, 0.12, 5e-4, -5e-4, -0.02), width=200, height=160, f=300.0)
    centre = np.array([0.29, -0.21, 2.0])  # far off-axis: ~0.36 rad, large distortion
    h = 0.004
    corners = centre + np.array([[-h, -h, 0], [h, -h, 0], [h, h, 0], [-h, h, 0]])
    radiance, _ = render_radiance(cam, Scene(quads=(white_quad(corners),)), FLAT)
    expected = cam.project(centre[None])[0]
    undistorted = replace(cam, dist=np.zeros(5)).project(centre[None])[0]
    assert cam.in_image(expected[None], margin=3).all()
    assert np.linalg.norm(expected - undistorted) > 3.0  # the distortion matters here
    # the small square's centroid equals its centre's projection up to a tiny second-order term
    np.testing.assert_allclose(rendered_centroid(radiance), expected, atol=0.02)


@pytest.mark.parametrize("frac", [0.0, 0.25, 0.5, 0.73])
def test_antialiased_edge_is_unbiased(frac):
    """A straight vertical edge at a known sub-pixel column: each row's coverage sum finds it."""
    cam = up_camera()
    K = cam.K
    u_edge = 70.0 + frac
    # camera x = -station x here (look_at with up = +y, looking along +z): u = cx - f X / Z
    X_edge = -(u_edge - K[0, 2]) / K[0, 0]
    corners = [[X_edge, -1, 2.0], [5, -1, 2.0], [5, 1, 2.0], [X_edge, 1, 2.0]]
    radiance, _ = render_radiance(cam, Scene(quads=(white_quad(corners),)), FLAT)
    estimate = radiance.astype(float).sum(axis=1) - 0.5  # covered from u = -0.5 to the edge
    # an exactly axis-aligned edge is quantised to 1/34 px by the 34-sample lattice: the
    # error is at most half of that, the same in every row (a tilted edge averages out, below)
    assert np.abs(estimate - u_edge).max() <= 0.5 / 34 + 1e-6


def test_tilted_edge_profile_crosses_half_at_the_true_position():
    cam = up_camera()
    K = cam.K
    slope = 0.21  # du/dv of the edge line in the image
    u0 = 60.37
    Z = 2.0 - 1.0
    # camera x = -X, y = -Y here: image line u = u0 + slope (v - cy) <=> X = -(u - cx) Z / f,
    # Y = -(v - cy) Z / f
    def X_at(v):
        return -(u0 + slope * (v - K[1, 2]) - K[0, 2]) * Z / K[0, 0]
    Y = lambda v: -(v - K[1, 2]) * Z / K[1, 1]
    corners = [[X_at(-50), Y(-50), 2.0], [5, Y(-50), 2.0], [5, Y(300), 2.0], [X_at(300), Y(300), 2.0]]
    radiance, _ = render_radiance(cam, Scene(quads=(white_quad(corners),)), FLAT)
    rows = np.arange(10, 118)
    truth = u0 + slope * (rows - K[1, 2])
    estimate = radiance[rows].astype(float).sum(axis=1) - 0.5
    # per row the 34-sample lattice's discrepancy for a slanted edge stays under 1/25 px; along
    # the edge the errors cancel: the edge as a whole is unbiased to well under 1/50 px
    assert np.abs(estimate - truth).max() < 0.04
    assert abs((estimate - truth).mean()) < 0.005


# --- the wheel -----------------------------------------------------------------------------
def wheel_camera(dist=(-0.2, 0.08, 3e-4, -2e-4, 0.0), width=320, height=256, f=450.0):
    """Looks at the default vehicle's FR wheel face-on from 1.3 m, like the precision camera."""
    return small_camera(dist, width, height, f, position=(2.08, 1.37, 0.35),
                        target=(0.78, 1.35, 0.33), up=(0.0, 0.0, 1.0))


def test_rim_flange_edge_is_exact():
    """Pixel coverage along the rim-flange edge circle equals a brute-force reference computed
    with the camera model's own exact rays (20x20 samples per pixel, plane w = 0)."""
    vehicle = Vehicle(toe_deg={w: 0.7 for w in ("FL", "FR", "RL", "RR")},
                      camber_deg={w: -1.2 for w in ("FL", "FR", "RL", "RR")})
    g = vehicle.wheel
    cam = wheel_camera()
    radiance, label = render_radiance(cam, Scene(vehicle=vehicle), FLAT, body=False)
    center, Rw = vehicle.wheel_frame_station("FR")
    w = Rw[:, 2]

    def radius_on_flange_plane(uv):
        o, d = cam.rays_station(uv)
        t = ((center - o) @ w) / (d @ w)
        return np.linalg.norm(o + t[:, None] * d - center, axis=1)

    v, u = np.mgrid[0:cam.height, 0:cam.width]
    uv = np.stack([u.ravel(), v.ravel()], 1).astype(float)
    r = radius_on_flange_plane(uv).reshape(cam.height, cam.width)
    px_m = 1.3 / 450.0
    near = np.abs(r - g.rim_radius_m) < 1.5 * px_m
    rows, cols = np.nonzero(near)
    assert rows.size > 500
    # label at pixel centres: flange inside the edge, tyre outside
    inner = (r < g.rim_radius_m - px_m) & (r > g.rim_radius_m - g.flange_width_m + px_m)
    outer = (r > g.rim_radius_m + px_m) & (r < g.rim_radius_m + 0.015)
    assert np.all(np.mod(label[inner] - 100, 40) == 0)           # FLANGE of some wheel
    assert np.all(np.mod(label[outer] - 100, 40) == 12)          # TYRE
    # coverage: brute force with 20 x 20 samples per edge pixel
    s = (np.arange(20) + 0.5) / 20 - 0.5
    su, sv = np.meshgrid(s, s)
    sub = np.stack([su.ravel(), sv.ravel()], 1)
    pts = (np.stack([cols, rows], 1)[:, None, :] + sub[None]).reshape(-1, 2)
    ref = (radius_on_flange_plane(pts).reshape(len(rows), -1) <= g.rim_radius_m).mean(axis=1)
    got = (radiance[rows, cols] - g.tyre_albedo) / (g.rim_albedo - g.tyre_albedo)
    err = got - ref
    # per pixel the 34-sample lattice is off by up to ~3/34 of a pixel's area for some edge
    # directions; along the edge these errors cancel: no bias, the edge is where geometry says
    assert np.abs(err).max() < 0.1
    assert abs(err.mean()) < 0.002


# --- the simulated station -----------------------------------------------------------------
@pytest.fixture(scope="module")
def config():
    return load_config()


def test_true_cameras_scatter_around_the_nominal_mounts(config):
    world = SimWorld.from_config(config)
    again = SimWorld.from_config(config)
    ks = []
    for cam_id, cam in world.cameras.items():
        nom = config.cameras[cam_id].nominal
        assert np.array_equal(cam.K, again.cameras[cam_id].K)
        assert np.abs(cam.center_station - np.array(nom.position_m)).max() <= 0.005
        R_nom, _ = look_at(np.array(nom.position_m), np.array(nom.look_at_m))
        angle = np.degrees(np.arccos(np.clip((np.trace(cam.R_cam_station @ R_nom.T) - 1) / 2, -1, 1)))
        assert 0 < angle <= 0.5 * np.sqrt(3) + 1e-9
        assert abs(cam.K[0, 0] / nom.focal_px - 1) <= 0.03
        assert abs(cam.K[0, 2] - (cam.width - 1) / 2) <= 15 and abs(cam.K[1, 2] - (cam.height - 1) / 2) <= 15
        k1, k2, p1, p2, k3 = cam.dist
        assert -0.25 <= k1 <= 0.05 and -0.05 <= k2 <= 0.15 and abs(k3) <= 0.02
        assert abs(p1) <= 5e-4 and abs(p2) <= 5e-4
        assert 0.6 <= world.blur_sigma[cam_id] <= 0.9
        ks.append(k1)
    assert np.std(ks) > 0.02  # the lenses differ


def test_vehicle_scenes_and_truth(config):
    world = SimWorld.from_config(config)
    a, b, a2 = world.vehicle_scene(1), world.vehicle_scene(2), world.vehicle_scene(1)
    assert world.truth(a) == world.truth(a2)
    ta, tb = world.truth(a), world.truth(b)
    assert ta["wheels"]["FR"]["toe_deg"] != tb["wheels"]["FR"]["toe_deg"]
    assert set(ta["cameras"]) == set(config.cameras)
    assert ta["cameras"]["cam3"] == world.cameras["cam3"].to_dict()
    gains = [lt.gain for lt in a.lighting.values()]
    assert len(set(gains)) == 8 and min(gains) >= 0.8 and max(gains) <= 1.15
    fixed = world.vehicle_scene(1, toe_deg=0.5, rim_radius_m=0.2)
    assert fixed.vehicle.toe_deg["RL"] == 0.5 and fixed.vehicle.wheel.rim_radius_m == 0.2
    with pytest.raises(ValueError, match="unknown override"):
        world.vehicle_scene(1, toe=1.0)


def small_world(config, **kw):
    cams = {"cam1": replace(wheel_camera(width=200, height=160, f=280.0), name="cam1")}
    return SimWorld(config, cams, {"cam1": 0.7}, **kw)


def test_world_render_is_deterministic_and_a_darker_camera_is_darker(config):
    world = small_world(config, noise_sigma=2.0)
    dark = small_world(config, noise_sigma=2.0, gain_override={"cam1": 0.8})
    scene = world.vehicle_scene(5)
    world.set_scene(scene)
    dark.set_scene(scene)
    a = world.render("cam1")
    assert np.array_equal(a, world.render("cam1"))
    assert not np.array_equal(a, world.render_all(np.random.default_rng(3))["cam1"])
    assert np.array_equal(world.render_all(np.random.default_rng(3))["cam1"],
                          world.render_all(np.random.default_rng(3))["cam1"])
    d = dark.render("cam1")
    unsaturated = a < 250
    ratio = d[unsaturated].astype(float).mean() / a[unsaturated].astype(float).mean()
    assert 0.77 < ratio < 0.83
    other = world.render("cam1", scene=world.vehicle_scene(6))
    assert np.abs(other.astype(int) - a).mean() > 5  # another vehicle looks different
    with pytest.raises(KeyError, match="no camera"):
        world.render("cam9")


# --- station simulate ----------------------------------------------------------------------
def small_config(tmp_path):
    from station.config import DEFAULT_CONFIG

    text = DEFAULT_CONFIG.read_text().replace("resolution: [1280, 1024]", "resolution: [256, 205]")
    text = text.replace("focal_px: 1800", "focal_px: 360")
    path = tmp_path / "station.yaml"
    path.write_text(text)
    return path


def test_station_simulate_writes_a_replay_set(tmp_path, capsys):
    import json

    import cv2

    from station.cli import main

    cfg = small_config(tmp_path)
    out = tmp_path / "set1"
    assert main(["--config", str(cfg), "simulate", "--seed", "3", "--out", str(out), "--noise", "1.5"]) == 0
    assert sorted(p.name for p in out.iterdir()) == sorted(
        [f"cam{i}.png" for i in range(1, 9)] + ["cycle.json", "truth.json"])
    image = cv2.imread(str(out / "cam1.png"), cv2.IMREAD_UNCHANGED)
    assert image.shape == (205, 256) and image.dtype == np.uint8 and image.std() > 10
    truth = json.loads((out / "truth.json").read_text())
    assert set(truth["wheels"]) == {"FL", "FR", "RL", "RR"} and len(truth["cameras"]) == 8
    assert truth["simulation"]["noise_sigma"] == 1.5
    cycle = json.loads((out / "cycle.json").read_text())
    assert cycle["seed"] == 3 and set(cycle["cameras"]) == {f"cam{i}" for i in range(1, 9)}
    assert "wrote" in capsys.readouterr().out
    # a used --out is refused with a clear message, nothing overwritten
    before = (out / "cam1.png").read_bytes()
    assert main(["--config", str(cfg), "simulate", "--seed", "4", "--out", str(out)]) != 0
    err = capsys.readouterr().err
    assert "already exists" in err and "Traceback" not in err
    assert (out / "cam1.png").read_bytes() == before


def test_closed_box_shows_only_its_front_faces():
    """Six quads forming a cube: nearest-hit ordering must hide the three faces turned away."""
    cam = small_camera(position=(0.9, -0.7, 0.8), target=(0.0, 0.0, 0.15), up=(0, 0, 1))
    h = 0.15
    v = np.array([[x, y, z] for z in (0, 2 * h) for y in (-h, h) for x in (-h, h)])  # 8 vertices
    faces = {  # (corner order: 0, 1, 2, 3 with 3 = 0 + 2 - 1), outward normal
        "+x": ([1, 3, 7, 5], (1, 0, 0)), "-x": ([2, 0, 4, 6], (-1, 0, 0)),
        "+y": ([3, 2, 6, 7], (0, 1, 0)), "-y": ([0, 1, 5, 4], (0, -1, 0)),
        "+z": ([4, 5, 7, 6], (0, 0, 1)), "-z": ([2, 3, 1, 0], (0, 0, -1)),
    }
    quads, facing = [], []
    for k, (idx, normal) in enumerate(faces.values()):
        c = v[idx].astype(float)
        assert np.allclose(c[3], c[0] + c[2] - c[1])
        quads.append(TexturedQuad(c, np.full((4, 4), 60 + 30 * k, np.uint8)))
        facing.append(np.dot(normal, cam.center_station - c.mean(axis=0)) > 0)
    _, label = render_radiance(cam, Scene(quads=tuple(quads)), FLAT)
    seen = {k for k in range(6) if np.any(label == 1000 + k)}
    assert seen == {k for k in range(6) if facing[k]}


def test_a_burst_of_frames_renders_the_still_scene_once(monkeypatch):
    """Frames of one still scene differ only in their read noise: SimWorld renders the clean
    image once per camera and scene, and a frame is exactly what ``render`` gave before."""
    import simulators.world as world_mod
    from simulators.render import render_clean, sensor_frame

    config = load_config(None)
    world = SimWorld.from_config(config)
    cam = small_camera()
    world.cameras = {"cam1": cam}
    world.blur_sigma = {"cam1": 0.8}
    calls = []

    def counted(*a, **k):
        calls.append(1)
        return render_clean(*a, **k)

    monkeypatch.setattr(world_mod, "render_clean", counted)
    scene = Scene(quads=(white_square_quad((0.0, 0.0, 0.0), 0.2),))
    world.set_scene(scene)
    a = world.render("cam1", np.random.default_rng(1))
    b = world.render("cam1", np.random.default_rng(2))
    assert len(calls) == 1 and not np.array_equal(a, b)
    direct = render(cam, scene, world.lighting_for("cam1"), np.random.default_rng(1), world.noise_sigma, 0.8,
                    supersample=world.supersample, body=world.body)
    assert np.array_equal(a, direct)
    assert np.array_equal(sensor_frame(world.clean_image("cam1"), np.random.default_rng(1), world.noise_sigma), a)
    world.set_scene(Scene(quads=(white_square_quad((0.05, 0.0, 0.0), 0.2),)))  # the car moved
    world.render("cam1", np.random.default_rng(1))
    world.blur_sigma["cam1"] = 1.5                                          # the lens was refocused
    world.render("cam1", np.random.default_rng(1))
    assert len(calls) == 3


def test_the_panels_surround_is_even_but_for_the_cameras_slot():
    """A mirror under the station's panels (``surround``) sees their radiance, a fifth more
    straight up, and a dark slot level with the wheel; the workshop it replaces is neither."""
    from simulators.shading import mirror_reflection

    up, level, down = np.array([0.0, 0.0, 1.0]), np.array([1.0, 0.0, 0.0]), np.array([0.0, 0.0, -1.0])
    seen = {}
    for name, ray_out in (("up", up), ("level", level), ("down", down)):
        n = ray_out + np.array([0.0, 1.0, 0.0])   # the mirror's normal halfway to a ray arriving along -y
        n /= np.linalg.norm(n)
        comps = lambda v: tuple(np.array([c]) for c in v)  # noqa: E731
        panels = mirror_reflection(comps(n), comps([0.0, -1.0, 0.0]), np.eye(3), 1.0, surround=0.5)
        workshop = mirror_reflection(comps(n), comps([0.0, -1.0, 0.0]), np.eye(3), 1.0)
        seen[name] = (float(panels[0]), float(workshop[0]))
    assert seen["up"][0] == pytest.approx(0.6, rel=1e-5) and seen["down"][0] == pytest.approx(0.4, rel=1e-5)
    assert seen["level"][0] == pytest.approx(0.5 * 0.15, rel=1e-5)          # the slot: 85 % darker
    assert seen["up"][1] != pytest.approx(0.6, rel=0.05)                   # the workshop's ceiling is another light
