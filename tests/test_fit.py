"""specsynth fit: the sensor fitted back from a known camera, the fitted spec file, and a small
build of it against the real LM-O split (installed by `make install`)."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml
from PIL import Image
from scipy.ndimage import gaussian_filter

from specsynth.assets.library.cache import cache_dir
from specsynth.assets.library.realsets import installed, resolve_ref
from specsynth.cli import main
from specsynth.compare import fit
from specsynth.compare.collect import Collected
from specsynth.compare.imagestats import IMAGE_STATS, image_stats, srgb8_to_linear
from specsynth.model.colour import linear_to_srgb8
from specsynth.spec.yamlio import load_spec

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def real_photos() -> list[np.ndarray]:
    assert installed(cache_dir(), "lmo"), "the real LM-O split is installed by `make install`"
    rgb = sorted((resolve_ref("dataset:lmo/test", cache_dir()) / "000002" / "rgb").glob("*.png"))
    return [np.asarray(Image.open(p).convert("RGB")) for p in rgb[::40]]


def _stats_of(images: list[np.ndarray]) -> Collected:
    rows = [image_stats(im) for im in images]
    return Collected(images={k: np.array([r[k] for r in rows]) for k in IMAGE_STATS}, n_images=len(rows))


def test_the_sensor_of_a_known_camera_is_fitted_back(real_photos):
    """Real photographs through a known camera (+1.5 stops, a 1.2 px blur, shot noise 0.02,
    saturation 1.3, tone curve 1.4) are the 'real' side; the photographs themselves are the probe.
    The fit finds that camera again."""
    from specsynth.views.sensor import process

    rng = np.random.default_rng(3)
    made = []
    for im in real_photos:
        x = gaussian_filter(srgb8_to_linear(im) * 2.0 ** 1.5, sigma=(1.2, 1.2, 0), mode="mirror")
        made.append(process(np.clip(x + 0.02 * np.sqrt(x) * rng.standard_normal(x.shape), 0, None), 1.3, 1.4))
    edits = {e.field: e for e in fit.sensor_edits(_stats_of(made), real_photos, "test", "png", seed=1, jobs=2)[0]}
    lo, hi = edits["sensor.exposure"].value
    assert 1.3 < (lo + hi) / 2 < 1.7
    assert 1.25 < edits["sensor.contrast"].value < 1.55
    assert 1.15 < edits["sensor.saturation"].value < 1.45
    blur_lo, blur_hi = edits["sensor.blur"].value
    assert 0.9 < (blur_lo + blur_hi) / 2 < 1.5
    assert 0.012 < edits["sensor.shot_noise"].value < 0.028
    assert edits["sensor.sharpening"].value == 0.0  # blurred, the 'real' side has no halos
    assert edits["outputs.image_format"].value == "png"
    assert all(e.comment.startswith("fit: ") for e in edits.values())


def test_the_sensor_fit_in_two_processes_is_the_fit_in_one(real_photos):
    """The probe developed in worker processes gives the same edits, number for number."""
    from specsynth.views.sensor import process

    made = [process(srgb8_to_linear(im) * 2.0 ** 0.7, 1.2, 1.3) for im in real_photos]
    one, cam_one = fit.sensor_edits(_stats_of(made), real_photos, "test", None, seed=2)
    two, cam_two = fit.sensor_edits(_stats_of(made), real_photos, "test", None, seed=2, jobs=2)
    assert [(e.field, e.value, e.comment) for e in one] == [(e.field, e.value, e.comment) for e in two]
    assert cam_one == cam_two and cam_one.stops != 0.0


def _dead_leaves(seed: int, h: int = 240, w: int = 320, n: int = 400) -> np.ndarray:
    """A dead-leaves chart (overlapping discs of random colours, linear RGB), as camera sharpness is
    tested with: steps of every contrast, perfectly sharp and without halos."""
    rng = np.random.default_rng(seed)
    im = np.zeros((h, w, 3))
    yy, xx = np.mgrid[0:h, 0:w]
    for _ in range(n):
        r, cy, cx = rng.uniform(4, 40), rng.uniform(0, h), rng.uniform(0, w)
        im[(yy - cy) ** 2 + (xx - cx) ** 2 < r * r] = rng.uniform(0.02, 0.9, 3)
    return im


def test_a_known_cameras_sharpening_is_fitted_back_with_its_blur():
    """Dead-leaves charts through a camera that blurs by 0.7 px and sharpens by 1.0 are the 'real'
    side, the charts themselves the probe: the fit finds that sharpening among its steps and the
    blur (which takes halos away as sharpening adds them: the two are searched in turn)."""
    from specsynth.views.sensor import process

    charts = [_dead_leaves(k) for k in range(5)]
    made = [process(gaussian_filter(c, sigma=(0.7, 0.7, 0), mode="mirror"), sharpening=1.0) for c in charts]
    edits = {e.field: e for e in fit.sensor_edits(_stats_of(made), [process(c) for c in charts], "test", None, seed=1)[0]}
    assert edits["sensor.sharpening"].value == 1.0
    blur_lo, blur_hi = edits["sensor.blur"].value
    assert 0.6 < (blur_lo + blur_hi) / 2 < 0.8


def test_a_known_lenss_vignetting_is_fitted_back():
    """Dead-leaves charts through a lens that keeps 60 % of the light in its corners are the 'real'
    side, the charts themselves the probe: the fit finds that lens again (within 0.05)."""
    from specsynth.views.sensor import process, vignette

    charts = [_dead_leaves(k) for k in range(6)]
    made = [process(c * vignette(*c.shape[:2], 0.4)[..., None]) for c in charts]
    edits = {e.field: e for e in fit.sensor_edits(_stats_of(made), [process(c) for c in charts], "test", None, seed=1)[0]}
    assert edits["sensor.vignetting"].value == pytest.approx(0.4, abs=0.05)
    assert edits["sensor.vignetting"].comment.startswith("fit: real corners")


def test_a_probe_as_sharp_and_clean_as_the_real_images_gets_no_blur_and_no_noise(real_photos):
    edits = {e.field: e for e in fit.sensor_edits(_stats_of(real_photos), real_photos, "test", None)[0]}
    assert edits["sensor.blur"].value is None and edits["sensor.shot_noise"].value == 0.0
    lo, hi = edits["sensor.exposure"].value
    assert abs((lo + hi) / 2) < 0.1
    assert edits["sensor.contrast"].value < 1.05 and abs(edits["sensor.saturation"].value - 1.0) < 0.05
    assert edits["sensor.sharpening"].value == 0.0 and edits["sensor.vignetting"].value == 0.0
    assert "unvignetted" in edits["sensor.vignetting"].comment  # searched, not skipped for clipping
    assert "outputs.image_format" not in edits  # not PNG: the spec keeps its format


@pytest.mark.slow  # two sensor fits, or a build and a fit: minutes on 2 cores
def test_a_probe_clipped_at_eight_bits_is_probed_again_at_the_exposure_found(real_photos):
    """A probe two stops too bright clips its highlights at 8 bits: their colour and texture are
    gone, and the tone curve and saturation fitted on it are made up (2.13 and 0.63 here). Rendered
    again at the exposure it found (here: the photographs darkened before their 8 bits), the fit
    finds the photographs' own camera."""
    lin = [srgb8_to_linear(im) for im in real_photos]
    real = _stats_of(real_photos)
    over = [linear_to_srgb8(x * 4.0) for x in lin]
    edits, cam = fit.sensor_edits(real, over, "test", None, jobs=2)
    assert fit.clipped_share(over) > fit.CLIPPED_LIMIT >= fit.clipped_share(real_photos)
    again = fit.reprobe_exposure(over, cam)
    assert again is not None and -2.0 < again < -1.0  # clipped, the probe also looks darker than it is
    assert fit.reprobe_exposure(real_photos, cam) is None  # nothing clipped: the probe stands
    probe = [linear_to_srgb8(x * 4.0 * 2.0**again) for x in lin]
    refit, _ = fit.sensor_edits(real, probe, "test", None, probe_stops=again, jobs=2)
    first, second = ({e.field: e.value for e in x} for x in (edits, refit))
    lo, hi = second["sensor.exposure"]
    assert -2.15 < (lo + hi) / 2 < -1.85  # the probe's stops and the fit's together
    # clipped, the probe had a made-up tone curve and colour; probed again, the photographs' own
    for field, close in (("sensor.contrast", 0.1), ("sensor.saturation", 0.05)):
        assert abs(second[field] - 1.0) < close < abs(first[field] - 1.0), (field, first[field], second[field])


def _fitted(tmp_path: Path, spec: str, probe: int) -> tuple[Path, dict]:
    out = tmp_path / "fitted" / "spec.yaml"
    assert main(["fit", "dataset:lmo/test", spec, "-o", str(out), "--probe-images", str(probe), "--jobs", "2"]) == 0
    return out, yaml.safe_load(out.read_text())


def test_the_fitted_spec_validates_and_keeps_everything_it_does_not_fit(tmp_path, capsys):
    spec = ROOT / "specs" / "lmo_bl.yaml"
    out, doc = _fitted(tmp_path, str(spec), probe=4)
    fitted = load_spec(out, []).spec.model_dump(mode="json")
    original = load_spec(spec, []).spec.model_dump(mode="json")
    edited = {"cameras": {"distance", "elevation", "elevation_sampling", "inplane", "aim_offset"}, "visibility": {"threshold"},
              "sensor": {"exposure", "blur", "shot_noise", "contrast", "saturation", "sharpening", "vignetting"},
              "outputs": {"image_format"}}
    for section, value in original.items():
        keep = {k: v for k, v in value.items() if k not in edited.get(section, ())} if isinstance(value, dict) else value
        got = {k: v for k, v in fitted[section].items() if k not in edited.get(section, ())} if isinstance(value, dict) \
            else fitted[section]
        if section == "objects":  # materials gain colour gains; an object without its own entry gets the default's
            mats, fitted_mats = keep.pop("materials"), got.pop("materials")
            for key, mat in fitted_mats.items():
                assert len(mat.pop("color_gain")) == 3
                expected = dict(mats.get(key, mats["default"]))
                expected.pop("color_gain", None)
                assert mat == expected, key
        assert got == keep, section
    text = out.read_text()
    for line in spec.read_text().splitlines():  # every comment of the original is still there
        refitted = line.split("#", 1)[-1].strip().startswith("fit:")  # an earlier fit's note is replaced
        if "#" in line and not refitted and not line.strip().startswith(("elevation", "distance", "threshold", "image_format")):
            assert line.split("#", 1)[1].strip() in text, line
    for field in ("elevation:", "distance:", "inplane:", "aim_offset:", "threshold:", "exposure:", "shot_noise:"):
        assert any(ln.strip().startswith(field) and "# fit: " in ln for ln in text.splitlines()), field
    real = json.loads((resolve_ref("dataset:lmo/test", cache_dir()) / "000002" / "scene_gt.json").read_text())
    assert len(real) == 200
    assert doc["cameras"]["elevation"][0] >= 5 and doc["cameras"]["distance"][1] <= 1.5
    assert doc["cameras"]["aim_offset"] == [0.05, 0.41]  # docs/compare.md: the real split's 5-95 %
    assert "Traceback" not in capsys.readouterr().err


def _unfitted(tmp_path: Path) -> Path:
    """specs/lmo_bl.yaml with camera ranges far from the real split's (the spec itself is already fitted)."""
    lines = []
    for line in (ROOT / "specs" / "lmo_bl.yaml").read_text().splitlines():
        key = line.strip().split(":", 1)[0]
        if line.startswith("  ") and key in ("elevation", "elevation_sampling", "distance", "inplane"):
            line = {"elevation": "  elevation: [5, 89]", "elevation_sampling": "  elevation_sampling: angle",
                    "distance": "  distance: [0.4, 1.8]", "inplane": "  inplane: [0, 0]"}[key]
        lines.append(line)
    (tmp_path / "unfitted").mkdir()
    spec = tmp_path / "unfitted" / "lmo_bl.yaml"
    spec.write_text("\n".join(lines) + "\n")
    return spec


@pytest.mark.slow  # two sensor fits, or a build and a fit: minutes on 2 cores
def test_a_fitted_spec_built_small_moves_its_geometry_toward_the_real_split(tmp_path, capsys):
    spec = _unfitted(tmp_path)
    out, _ = _fitted(tmp_path, str(spec), probe=0)
    small = ["--set", "arrangements.count=4", "--set", "cameras.per_arrangement=10", "--jobs", "2"]
    distances = {}
    for name, s in (("original", spec), ("fitted", out)):
        if name == "fitted":  # the arrangements are the same: take them from the first build's store
            shutil.copytree(tmp_path / "original" / ".specsynth", tmp_path / name / ".specsynth")
        assert main(["build", str(s), "--out", str(tmp_path / name), *small]) == 0
        capsys.readouterr()
        assert main(["compare", str(tmp_path / name), "dataset:lmo/test", "--json", "--jobs", "2"]) == 0
        distances[name] = json.loads(capsys.readouterr().out)["statistics"]
    for stat in ("elevation", "distance", "aim_offset"):
        assert distances["fitted"][stat]["distance"] < distances["original"][stat]["distance"], stat


def test_fit_gives_the_spec_the_real_cameras_intrinsics(tmp_path, capsys):
    """A spec made for another camera gets the one the real images were taken with (LM-O's
    camera.json), on every field, before anything is probed; a spec that has it is left alone."""
    lines = [("intrinsics: {width: 320, height: 240, fx: 280.0, fy: 281.0, cx: 159.5, cy: 119.5}"
              if ln.startswith("intrinsics:") else ln) for ln in (ROOT / "specs" / "lmo_bl.yaml").read_text().splitlines()]
    (tmp_path / "other").mkdir()
    spec = tmp_path / "other" / "lmo_bl.yaml"
    spec.write_text("\n".join(lines) + "\n")
    out, doc = _fitted(tmp_path, str(spec), probe=0)
    assert doc["intrinsics"] == {"width": 640, "height": 480, "fx": 572.4114, "fy": 573.57043, "cx": 325.2611,
                                 "cy": 242.04899}
    assert "fit: the camera of 200 of 200 real images in dataset:lmo/test" in out.read_text()
    assert load_spec(out, []).spec.intrinsics.fx == 572.4114
    same = load_spec(ROOT / "specs" / "lmo_bl.yaml", []).spec.intrinsics
    cams = [(np.array([[same.fx, 0, same.cx], [0, same.fy, same.cy], [0, 0, 1]]), same.width, same.height)] * 3
    assert fit.intrinsics_edits(cams, same, "x") == []
    other = [(np.array([[500.0, 0, 300], [0, 501, 200], [0, 0, 1]]), 600, 400)]
    got = {e.field: e.value for e in fit.intrinsics_edits(cams[:1] + other * 2, same, "x")}
    assert got == {"intrinsics.width": 600, "intrinsics.height": 400, "intrinsics.fx": 500.0, "intrinsics.fy": 501.0,
                   "intrinsics.cx": 300.0, "intrinsics.cy": 200.0}


@pytest.mark.parametrize("law", ["angle", "area"])
def test_fit_picks_the_elevation_sampling_the_real_elevations_were_drawn_with(law):
    from specsynth.views.cameras import elevation_on_area

    u = np.random.default_rng(5).random(300)
    real = lo, hi = 10.0, 80.0
    values = lo + u * (hi - lo) if law == "angle" else np.array([elevation_on_area(x, *real) for x in u])
    w = fit.elevation_law_distances(values, lo, hi)
    assert min(w, key=w.get) == law
    assert w[law] < 2.0 < max(w.values())


def test_fit_refuses_a_folder_as_its_output(tmp_path, capsys):
    (tmp_path / "out.yaml").mkdir()
    assert main(["fit", "dataset:lmo/test", str(ROOT / "specs" / "lmo_bl.yaml"), "-o", str(tmp_path / "out.yaml"),
                 "--probe-images", "0"]) == 2
    assert "not a file" in capsys.readouterr().err


def test_an_object_rendered_too_dark_gets_the_colour_gain_that_undoes_it():
    """40 real LM-O images are both sides: as they are (real) and as the probe, with the duck (obj 9)
    made half as bright and the glue (obj 11) bluer in linear light. The fit gives them the gains that undo it
    and leaves the other objects near 1."""
    from specsynth.compare.gtinfo import complete
    from specsynth.compare.split import open_split

    from specsynth.compare.imagestats import OBJECT_STATS, object_stats

    split = complete(open_split("dataset:lmo/test"))
    probe, rows = [], []
    for im in list(split.iter_images())[::5]:
        rgb = np.asarray(Image.open(im.rgb).convert("RGB"))
        masks = [(i.obj_id, np.asarray(Image.open(m)) > 0) for i, m in zip(im.instances, im.mask_visib)]
        rows += [(obj_id, object_stats(rgb, mask)) for obj_id, mask in masks]
        x = srgb8_to_linear(rgb)
        for obj_id, mask in masks:
            x[mask] *= {9: np.array([0.5, 0.5, 0.5]), 11: np.array([0.8, 0.9, 1.3])}.get(obj_id, 1.0)
        probe.append((linear_to_srgb8(np.clip(x, 0, 1).astype(np.float32)), masks))
    rows = [(i, st) for i, st in rows if st is not None]  # the real side: the same images, untouched
    real = Collected(objects={"obj_id": np.array([i for i, _ in rows]),
                              **{k: np.array([st[k] for _, st in rows]) for k in OBJECT_STATS}})
    fitted = fit.object_gains(real, probe, fit.Camera())
    gains = {i: g for i, (g, _, _) in fitted.items()}
    np.testing.assert_allclose(gains[9][:2], [2.0, 2.0], rtol=0.12)  # its blue is near 0: only the colour counts
    after = fit._median_lab(fit._object_colours(probe, fit.Camera(), gains)[9])
    assert np.linalg.norm(after - fitted[9][1]) < 3.0  # within 3 CIELAB units of the real duck
    np.testing.assert_allclose(gains[11], [1 / 0.8, 1 / 0.9, 1 / 1.3], rtol=0.12)
    for obj_id in (1, 5, 6, 8, 10, 12):
        np.testing.assert_allclose(gains[obj_id], 1.0, atol=0.03)  # 8-bit rounding only
    edits = fit.object_edits(real, probe, fit.Camera(), {"default": {"specular": 0.3}, "9": {"roughness": 0.2}}, "t")
    by = {e.field: e.value for e in edits}
    assert by["objects.materials.9"]["roughness"] == 0.2 and "specular" not in by["objects.materials.9"]
    assert by["objects.materials.1"]["specular"] == 0.3 and len(by["objects.materials.1"]["color_gain"]) == 3
    again = fit.object_edits(real, probe, fit.Camera(), {"9": {"color_gain": (2.0, 2.0, 1.0)}}, "t")  # on top of it
    np.testing.assert_allclose({e.field: e.value for e in again}["objects.materials.9"]["color_gain"][:2],
                               2.0 * np.array(by["objects.materials.9"]["color_gain"][:2]), rtol=1e-3)


def test_a_halo_out_of_reach_gets_the_sharpening_at_its_peak():
    """A target no sharpening reaches (the real halo above anything the probe can show): the fit
    takes the step where the probe's halo peaks, not the strongest step."""
    from specsynth.views.sensor import process

    lin = [_dead_leaves(k, 120, 160, 100) for k in range(3)]  # sharp: its halo peaks before 3 (measured: at 2.25)
    normals = [np.zeros_like(x) for x in lin]
    cam = fit.Camera()
    v = fit._sharpening(fit.Probe(lin, normals), cam, 10.0)

    def halo_at(a: float) -> float:
        return float(np.median([fit._stat("halo", process(x, sharpening=a)) for x in lin]))
    assert 0.0 < v < fit.SHARPENING_STEPS[-1]
    assert halo_at(v) >= halo_at(0.0) and halo_at(v) >= halo_at(v + 0.25)


def test_the_probe_is_rendered_with_a_neutral_sensor_whatever_the_spec_sets():
    """A spec fitted before (its sensor sharpens, blurs, adds noise) gets a probe without any of it:
    the fit develops the probe itself, and would otherwise apply each operation twice."""
    from specsynth.cli import probe_overrides

    spec = load_spec(ROOT / "specs" / "lmo_pbr_h.yaml", []).spec
    assert spec.sensor.sharpening > 0 and spec.sensor.blur  # the shipped spec is a fitted one
    sensor = load_spec(ROOT / "specs" / "lmo_pbr_h.yaml", probe_overrides([], 3, -1.0)).spec.sensor
    assert (sensor.exposure, sensor.contrast, sensor.saturation, sensor.sharpening, sensor.blur,
            sensor.shot_noise, sensor.read_noise, sensor.vignetting) == ((-1.0, -1.0), 1.0, 1.0, 0.0, None, 0.0, 0.0, 0.0)
    assert sensor.auto_exposure and sensor.auto_white_balance  # as the spec asks: the real camera's


def test_a_fitted_spec_is_probed_first_at_its_own_exposure():
    from specsynth.cli import first_probe_stops

    spec = load_spec(ROOT / "specs" / "lmo_pbr_h.yaml", []).spec
    lo, hi = spec.sensor.exposure
    assert lo < hi < 0 and first_probe_stops(spec) == round((lo + hi) / 2, 2)
    assert first_probe_stops(load_spec(ROOT / "specs" / "lmo_pbr_h.yaml", ["sensor.exposure=[0, 0]"]).spec) == 0.0
