"""`specsynth bench`: metrics, equal-error speed-ups, savings, and a real tiny run."""

from __future__ import annotations

import csv
import json
import math
import os
import subprocess
import sys
from functools import partial
from pathlib import Path

import numpy as np
import pytest

from specsynth.run.bench import Row, camera_savings, equal_error_speedups, psnr8, rel_mse

ROOT = Path(__file__).resolve().parents[1]


def test_metrics_identity_and_known_values():
    a = np.full((4, 4, 3), 100, np.uint8)
    assert psnr8(a, a) == math.inf
    b = a.copy()
    b[0, 0, 0] = 110  # one channel of one pixel off by 10: MSE = 100 / 48
    assert psnr8(a, b) == pytest.approx(10 * math.log10(255**2 / (100 / 48)))
    x = np.ones((2, 2, 3), np.float32)
    assert rel_mse(x, x) == 0.0


def test_equal_error_speedup_picks_fastest_setting_at_high_error():
    rows = [Row("c", "high", "high", 10.0, 1e-3, 30.0, 0.9, 225),
            Row("c", "medium+denoise", "medium", 2.0, 1e-3, 31.0, 0.9, 36),
            Row("c", "low", "low", 0.5, 1e-1, 20.0, 0.5, 1)]
    e = equal_error_speedups(rows)["c"]
    assert e["fastest"] == "medium+denoise" and e["speedup_vs_high"] == 5.0


def test_camera_savings_are_priced_with_measured_times():
    rows = [Row("c", "low", "low", 2.0, 0, 0, 0, 1, image_seconds=2.0)]
    first = {"rejected": 3, "rejected_seconds": 0.3, "cameras": 10, "jobs": 14, "worker_seconds": 5.0, "ran": 14}
    cached = {**first, "ran": 0, "wall": 0.5}
    s = {x.what: x.seconds for x in camera_savings("c", rows, "low", (first, cached), load_s=1.5, per_arrangement=4)}
    assert s["visibility pre-check"] == pytest.approx(3 * 2.0 - 0.3)
    assert s["scene loaded once per arrangement"] == pytest.approx(3 * 1.5)
    assert s["cache"] == pytest.approx(4.5)
    # The spec's level not benched (`--levels high`): no price for the pre-check, rather than NaN.
    s = {x.what for x in camera_savings("c", rows, "medium", (first, cached), load_s=1.5, per_arrangement=4)}
    assert s == {"scene loaded once per arrangement", "cache"}
    # Under --ref-crop a row's seconds are its window's; the preset's whole image is not measured
    windowed = [Row("c", "low", "low", 0.3, 0, 0, 0, 1, image_seconds=None)]
    s = {x.what for x in camera_savings("c", windowed, "low", (first, cached), load_s=1.5, per_arrangement=4)}
    assert s == {"scene loaded once per arrangement", "cache"}


@pytest.mark.slow
def test_bench_cli_on_the_demo_with_cycles(tmp_path):
    """A real bench run (Cycles, one view, 32x24): table, CSV, plot and measured savings."""
    out = tmp_path / "bench"
    r = subprocess.run([sys.executable, "-m", "specsynth.cli", "bench", str(ROOT / "specs/demo.yaml"), "--out", str(out),
                        "--views", "1", "--scale", "0.05", "--ref-factor", "1", "--backend", "cycles",
                        "--set", "arrangements.count=1"], capture_output=True, text=True, timeout=900,
                       env={**os.environ, "COLUMNS": "250"})
    assert r.returncode == 0, r.stdout + r.stderr
    assert "what skipping saved" in r.stdout and "light-path budget" in r.stdout
    with open(out / "bench.csv") as f:
        rows = list(csv.DictReader(f))
    settings = {row["setting"] for row in rows}
    assert {"low", "low+denoise", "medium", "high", "high+adaptive", "reference"} <= settings
    for row in rows:
        assert float(row["seconds"]) > 0
        if row["setting"] != "reference":
            assert 0 < float(row["psnr_db"]) < 100 and 0 < float(row["ssim"]) <= 1
    # more samples, less error (noise only: same view, same reference)
    psnr = {row["setting"]: float(row["psnr_db"]) for row in rows}
    assert psnr["high"] > psnr["low"]
    meta = json.loads((out / "bench.json").read_text())
    what = {s["what"] for s in meta["savings"]}
    assert what == {"visibility pre-check", "scene loaded once per arrangement", "cache", "light-path budget"}
    assert all(math.isfinite(s["seconds"]) for s in meta["savings"])
    assert (out / "bench.png").stat().st_size > 10_000


def test_bench_json_has_no_inf_or_nan():
    from specsynth.run.bench import _finite

    doc = {"rows": [{"psnr": float("inf"), "seconds": 1.5}], "savings": [{"seconds": float("nan")}], "n": 3}
    text = json.dumps(_finite(doc), allow_nan=False)
    assert json.loads(text) == {"rows": [{"psnr": None, "seconds": 1.5}], "savings": [{"seconds": None}], "n": 3}


def test_only_picks_the_named_settings_and_always_the_reference():
    from specsynth.plugins import backend_plugin
    from specsynth.run.bench import pick_settings, settings_for

    every = settings_for(backend_plugin("cycles"), 2, ("high",), ladder=True)
    picked = pick_settings(every, ("high+calibrated", "high+denoise@2"))
    assert [s.label for s in picked] == ["high+calibrated", "high+denoise@2", "reference"]
    assert picked[-1].reference and pick_settings(every, ()) == every
    with pytest.raises(ValueError, match=r"no setting 'high\+denoise@3'.*it has high, high\+calibrated"):
        pick_settings(every, ("high+denoise@3",))
    # a backend that denoises takes any rung, not only the ladder's powers of two
    picked = pick_settings(every, ("high", "high+denoise@20"), denoise=True)
    assert [(s.label, s.options) for s in picked[:2]] == [("high", {}), ("high+denoise@20", {"denoise": True, "samples": 20, "__rung__": True})]
    with pytest.raises(ValueError, match=r"no setting 'low\+denoise@20'"):
        pick_settings(every, ("low+denoise@20",), denoise=True)
    # and at a multiple of the resolution: N samples per pixel of the larger image (backend.supersample)
    picked = pick_settings(every, ("high+denoise@8x2",), denoise=True)
    assert (picked[0].label, picked[0].options) == ("high+denoise@8x2", {"denoise": True, "samples": 8, "supersample": 2, "__rung__": True})
    for bad in ("high+denoise@8x5", "high+denoise@8x1", "high+denoise@8x", "high+denoise@x2"):
        with pytest.raises(ValueError, match="no setting"):
            pick_settings(every, (bad,), denoise=True)


def test_a_rung_renders_its_levels_calibrated_way_unless_the_spec_says_otherwise():
    """Mitsuba's calibrated levels pick emitters by power: its rungs do too, so the ladder measures
    the counts the calibration chooses from; a spec's own emitter_sampling is kept, and the plain
    preset renders Mitsuba's own way."""
    from specsynth.plugins import backend_plugin
    from specsynth.run.bench import _setting_options, pick_settings, settings_for
    from specsynth.spec.models import DatasetSpec as Spec

    plugin = backend_plugin("mitsuba")
    assert plugin.calibrated["high"]["emitter_sampling"] == "power"
    import yaml
    from test_error_target import TINY

    tiny = {**yaml.safe_load(TINY.replace("BACKEND", "mitsuba")), "quality": {"level": "high"}}
    spec = Spec.model_validate({**tiny, "backend": {"name": "mitsuba"}})
    every = pick_settings(settings_for(plugin, 2, ("high",)), ("high", "high+denoise@9", "high+calibrated",
                                                               "high+targeted"), denoise=True)
    plain, rung, calibrated, targeted, reference = (_setting_options(plugin, st, spec.backend.model_dump(), spec)[0]
                                                    for st in every)
    assert (plain.emitter_sampling, rung.emitter_sampling, rung.samples, rung.denoise) == ("uniform", "power", 9, True)
    assert calibrated.emitter_sampling == "power"
    # the reference, and an error target's renders, which measure the preset's error: Mitsuba's own
    assert reference.emitter_sampling == targeted.emitter_sampling == "uniform"
    mine = Spec.model_validate({**tiny, "backend": {"name": "mitsuba", "emitter_sampling": "uniform"}})
    rung, _, _ = _setting_options(plugin, every[1], mine.backend.model_dump(), mine)
    assert rung.emitter_sampling == "uniform"


def _rows(psnr_by_samples: dict[int, float], taken=None) -> list:
    rows = [Row("c", "high", "high", 70.0, 7e-3, 31.7, 0.0, 225)]
    return rows + [Row("c", f"high+denoise@{n}", "high", n / 3, 0.0, p, 0.9, (taken or {}).get(n, n))
                   for n, p in psnr_by_samples.items()]


def test_the_ladder_is_refined_between_its_last_rung_short_of_the_presets_error_and_its_first_reaching_it():
    from specsynth.run.bench import finer_rung

    assert finer_rung(_rows({16: 30.6, 32: 31.8}), "c", "high") == 23  # geometric mean of the bracket
    assert finer_rung(_rows({16: 30.6, 23: 31.2, 32: 31.8}), "c", "high") == 27
    assert finer_rung(_rows({16: 30.6, 23: 31.2, 27: 31.75, 32: 31.8}), "c", "high") is None  # 23 -> 27: narrow
    assert finer_rung(_rows({8: 29.0, 16: 31.9, 32: 32.5}), "c", "high") == 11
    assert finer_rung(_rows({16: 30.6, 32: 31.2}), "c", "high") is None  # none reaches it
    assert finer_rung(_rows({16: 31.9, 32: 32.5}), "c", "high") is None  # the first rung reaches it
    assert finer_rung(_rows({16: 30.6, 32: 31.8}), "m", "high") is None  # another backend's rows


def test_the_ladder_is_refined_by_the_samples_a_rounding_backend_takes():
    """Mitsuba's stratified sampler renders the next square: its whole ladder (1, 2, 4, ... asked;
    1, 4, 4, 9, 16, 36 taken) is refined at a square between the bracket's counts taken, asked as
    itself, and not at all when no square lies between them."""
    from specsynth.plugins import backend_plugin
    from specsynth.run.bench import finer_rung

    mitsuba = backend_plugin("mitsuba")
    square = partial(mitsuba.sample_counts, mitsuba.options.model_validate({"name": "mitsuba"}))  # the next square
    ladder = {1: 20.0, 2: 24.0, 4: 24.0, 8: 27.0, 16: 30.6, 32: 31.8}
    taken = {n: square(n) for n in ladder}
    assert [taken[n] for n in ladder] == [1, 4, 4, 9, 16, 36]
    assert finer_rung(_rows(ladder, taken), "c", "high", square) == 25
    assert finer_rung(_rows({**ladder, 25: 31.5}, {**taken, 25: 25}), "c", "high", square) is None  # 25 -> 36: none
    # a backend that rounds without saying so: each asked count is tried once, then the refining ends
    rows, asked = _rows(ladder, taken), []
    while (n := finer_rung(rows, "c", "high")) is not None:
        asked.append(n)
        rows += _rows({n: 31.5}, {n: square(n)})[1:]
    assert asked and len(asked) == len(set(asked)) and len(asked) < 20


def test_the_refined_rungs_are_benched_after_the_ladder_each_once_until_the_bracket_is_narrow():
    """run_bench's loop (bench_in_turn with finer_rung) on a renderer whose PSNR rises with log samples."""
    from specsynth.run.bench import Setting, bench_in_turn, finer_rung, rung

    def bench_one(st: Setting) -> Row:
        if st.label == "high":
            return Row("c", "high", "high", 70.0, 0.0, 31.7, 0.0, 225)
        n = st.options["samples"]
        return Row("c", st.label, "high", n / 3, 0.0, 28.0 + math.log2(n) * 0.7, 0.9, n)

    ladder = [Setting("c", "high", "high", {})] + [rung("c", "high", n) for n in (1, 2, 4, 8, 16, 32, 64, 128)]
    rows = bench_in_turn(ladder, bench_one, lambda done: [rung("c", "high", n) for n in [finer_rung(done, "c", "high")] if n])
    labels = [r.setting for r in rows]
    assert len(labels) == len(set(labels)) and labels[: len(ladder)] == [s.label for s in ladder]
    refined = [r.samples for r in rows[len(ladder):]]
    assert refined  # 28 + 0.7 log2(n) reaches 31.7 at n = 39: between 32 and 64
    reach = min(r.samples for r in rows if r.setting != "high" and r.psnr >= 31.7)
    short = max(r.samples for r in rows if r.setting != "high" and r.psnr < 31.7)
    assert short < 39 <= reach <= short * 1.25


def test_bench_settings_are_the_backend_packages_own_not_the_plugin_records(tmp_path, monkeypatch):
    """A backend says what the bench tries beyond the levels in its package's optional ``bench``
    module (``BENCH``); the plugin record a build reads has no bench field."""
    import dataclasses

    from specsynth.plugins import BackendPlugin, PluginNotFound, backend_plugin
    from specsynth.run.bench import BenchSettings, bench_settings, settings_for

    assert not {f.name for f in dataclasses.fields(BackendPlugin)} & {"bench_variants", "bench_toggles"}
    pkg = tmp_path / "benched"
    pkg.mkdir()
    (pkg / "__init__.py").write_text("")
    (pkg / "bench.py").write_text("from specsynth.run.bench import BenchSettings\n"
                                  "BENCH = BenchSettings(variants=(('fast', {'samples': 2}),), toggles=(('budget', 'budget'),))\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    plugin = BackendPlugin(name="benched", options=object, backend="benched.renderer:Renderer")
    assert bench_settings(plugin) == BenchSettings(variants=(("fast", {"samples": 2}),), toggles=(("budget", "budget"),))
    assert [s.label for s in settings_for(plugin, 2, ("high",))] == ["high", "high+fast", "reference"]
    (pkg / "bench.py").write_text("BENCH = {'variants': ()}\n")
    monkeypatch.delitem(sys.modules, "benched.bench")
    with pytest.raises(PluginNotFound, match=r"benched\.bench\.BENCH of backend 'benched' is not a"):
        bench_settings(plugin)
    assert bench_settings(backend_plugin("flat")) == BenchSettings()  # no bench module: the levels alone
    assert bench_settings(backend_plugin("cycles")).toggles == (("light-path budget", "light_path_budget"),)


def test_bench_refuses_an_unknown_setting_before_building_anything(tmp_path):
    out = tmp_path / "bench"
    r = subprocess.run([sys.executable, "-m", "specsynth.cli", "bench", str(ROOT / "specs/demo.yaml"), "--out", str(out),
                        "--backend", "cycles", "--levels", "high", "--only", "hgh"], capture_output=True, text=True,
                       timeout=300)
    assert r.returncode != 0 and "--only: no setting 'hgh'" in r.stdout + r.stderr
    assert not out.exists()


def test_the_specs_shared_backend_options_reach_every_benched_backend():
    """`--set backend.denoise_prefilter=none` on a Cycles spec benched with Mitsuba too: Mitsuba
    renders with it (it was dropped: Mitsuba's rows ran its default), options the spec leaves at
    their default stay the other backend's own, and a value the other backend does not take
    fails, naming the option."""
    from specsynth.plugins import backend_plugin
    from specsynth.run.bench import base_options

    cycles, mitsuba = backend_plugin("cycles"), backend_plugin("mitsuba")
    spec_backend = cycles.options.model_validate({"name": "cycles", "denoise_prefilter": "none", "denoise": True,
                                                  "adaptive_threshold": 0.01})
    assert base_options(spec_backend, mitsuba) == {"name": "mitsuba", "denoise_prefilter": "none"}
    own = base_options(spec_backend, cycles)
    assert own["adaptive_threshold"] == 0.01 and "denoise" not in own and "samples" not in own
    assert base_options(cycles.options.model_validate({"name": "cycles"}), mitsuba) == {"name": "mitsuba"}
    with pytest.raises(ValueError, match="backend.denoise_prefilter"):
        base_options(cycles.options.model_validate({"name": "cycles", "denoise_prefilter": "accurate"}), mitsuba)


def test_bench_refuses_a_shared_option_another_backend_does_not_take_before_building_anything(tmp_path):
    out = tmp_path / "bench"
    r = subprocess.run([sys.executable, "-m", "specsynth.cli", "bench", str(ROOT / "specs/demo.yaml"), "--out", str(out),
                        "--backend", "mitsuba", "--levels", "high", "--set", "backend.denoise_prefilter=accurate"],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode != 0 and "backend.denoise_prefilter" in r.stdout + r.stderr
    assert "Traceback" not in r.stderr and not out.exists()


def test_a_targeted_row_reports_the_samples_of_its_views_not_of_its_last(tmp_path):
    """Under an error target each view takes its own samples: the row's samples are their mean,
    as its seconds and errors are (the row reported the last view's). A stand-in renderer whose
    views differ in noise, through the bench's own setting and drawing."""
    from types import SimpleNamespace

    from scipy.ndimage import uniform_filter

    from specsynth.model.colour import linear_to_srgb8
    from specsynth.model.ir import RenderResult
    from specsynth.plugins import BackendPlugin
    from specsynth.run.bench import Reference, Setting, bench_setting
    from specsynth.spec.models import BackendOptions, Quality

    mu = np.full((24, 32, 3), 0.4)

    class Noisy:  # view k's noise: sigma_k / sqrt(samples), denoised by a box filter
        def __init__(self, options, threads=0):
            pass

        def load(self, scene):
            pass

        def render(self, cam, quality, seed, clamp=None):
            n = quality.samples
            x = (mu + [0.05, 2.0][cam] * mu / np.sqrt(n) * np.random.default_rng(seed).standard_normal(mu.shape))
            x = x.astype(np.float32)
            d = uniform_filter(x, size=(5, 5, 1), mode="nearest")  # its denoiser
            return RenderResult(rgb=linear_to_srgb8(d), linear=d, stats={"samples": n}, noisy=x)

        def close(self):
            pass

    plugin = BackendPlugin(name="x", options=BackendOptions, backend="nowhere:X")
    spec = SimpleNamespace(quality=Quality(level="high"))
    shots = SimpleNamespace(scene=lambda arec: None, camera=lambda vrec: vrec, reference_camera=lambda vrec: vrec,
                            window=None)
    refs = {k: Reference(mu.astype(np.float32), linear_to_srgb8(mu.astype(np.float32)), 0.0) for k in (0, 1)}
    (tmp_path / "bench").mkdir()
    row = bench_setting(plugin, Noisy, Setting("x", "high+targeted", "high", {"__control__": "error"}), {"name": "x"},
                        spec, [(None, 0, 11), (None, 1, 12)], shots, refs, 1, tmp_path)
    per_view = [v["samples"] for v in row.views]
    assert per_view[0] != per_view[1]
    assert row.samples == round(np.mean(per_view))


def _stand_in(image, renders: list):
    """A renderer class for ``bench_setting`` whose render of ``n`` samples, ``seed`` and camera
    is ``image(n, seed, cam)`` (linear), each render's samples appended to ``renders``."""
    from specsynth.model.colour import linear_to_srgb8
    from specsynth.model.ir import RenderResult

    class StandIn:
        def __init__(self, options, threads=0):
            pass

        def version(self):
            return "stand-in 1"

        def load(self, scene):
            pass

        def render(self, cam, quality, seed, clamp=None):
            n = quality.samples
            renders.append(n)
            x = image(n, seed, cam)
            return RenderResult(rgb=linear_to_srgb8(x), linear=x, stats={"samples": n})

        def close(self):
            pass

    return StandIn


def _bench_of_one_view(tmp_path):
    """(a backend plugin, a spec at `high`, the shots and the one picked view) for ``bench_setting``."""
    from types import SimpleNamespace

    from specsynth.plugins import BackendPlugin
    from specsynth.spec.models import BackendOptions, Quality

    (tmp_path / "bench").mkdir()
    return (BackendPlugin(name="x", options=BackendOptions, backend="nowhere:X"),
            SimpleNamespace(quality=Quality(level="high")),
            SimpleNamespace(scene=lambda arec: None, camera=lambda vrec: vrec, reference_camera=lambda vrec: vrec,
                            window=None),
            [(SimpleNamespace(to_json=lambda: {"arrangement": 0}), 0, 11)])


@pytest.mark.parametrize("parts", [2, 3])
def test_a_level_each_reference_part_rendered_is_measured_from_the_parts_as_if_rendered(tmp_path, parts):
    """With --ref-factor 2 each part of the reference is the paper's high preset: its row comes
    from the parts, with the relMSE and PSNR an independent render of it has against the
    reference's mean, and nothing rendered again. A stand-in renderer of known noise."""
    import dataclasses

    from specsynth.run.bench import Setting, bench_setting

    mu = np.linspace(0.02, 0.9, 160 * 240 * 3).reshape(160, 240, 3)
    renders = []
    Noisy = _stand_in(lambda n, seed, cam: np.clip(mu * (1 + 1.0 / np.sqrt(n) * np.random.default_rng(seed).standard_normal(
        mu.shape)), 0, None).astype(np.float32), renders)
    plugin, spec, shots, picked = _bench_of_one_view(tmp_path)
    refs = {}
    args = ({"name": "x"}, spec, picked, shots, refs, 1, tmp_path)
    reference = Setting("x", "reference", "high", {"__factor__": 2, "__parts__": parts}, reference=True)
    bench_setting(plugin, Noisy, reference, *args)
    assert renders == [225] * parts
    from_parts = bench_setting(plugin, Noisy, Setting("x", "high", "high", {}), *args)
    assert renders == [225] * parts and from_parts.samples == 225 and math.isnan(from_parts.ssim)
    refs[0] = dataclasses.replace(refs[0], parts=None)  # as with another factor: rendered
    rendered = bench_setting(plugin, Noisy, Setting("x", "high", "high", {}), *args)
    assert renders == [225] * (parts + 2)  # a warm-up and the timed render
    assert from_parts.psnr == pytest.approx(rendered.psnr, abs=0.1)
    assert from_parts.rel_mse == pytest.approx(rendered.rel_mse, rel=0.05)
    assert from_parts.rel_mse == pytest.approx(np.mean(1 / 225 * mu**2 / (mu**2 + 0.01)), rel=0.05)
    # another level's preset is not a part
    assert bench_setting(plugin, Noisy, Setting("x", "medium", "medium", {}), *args).samples == 36


def test_a_reference_of_fewer_than_two_parts_is_refused_before_anything_is_built(tmp_path):
    from specsynth.run.bench import run_bench

    with pytest.raises(ValueError, match="--ref-parts 1"):
        run_bench(None, tmp_path, ref_parts=1)  # before the graph is read: nothing is built


def test_a_parts_time_is_a_render_after_the_scenes_first(tmp_path):
    """The first render after a scene's load syncs it (Cycles) or compiles kernels (Dr.Jit): a
    reference's part time leaves it out, also when more parts are added to cached ones in a later
    run (the first new part is that run's first render)."""
    from specsynth.run.bench import Setting, bench_setting

    renders = []
    Flat = _stand_in(lambda n, seed, cam: np.full((8, 8, 3), 0.5, np.float32), renders)
    plugin, spec, shots, picked = _bench_of_one_view(tmp_path)

    def reference(parts):
        refs = {}
        ref = Setting("x", "reference", "high", {"__factor__": 2, "__parts__": parts}, reference=True)
        bench_setting(plugin, Flat, ref, {"name": "x"}, spec, picked, shots, refs, 1, tmp_path)
        return refs[0]

    def flags():
        out = {}
        for f in (tmp_path / "bench" / "references").glob("*.npz"):
            with np.load(f) as z:
                out[f.name] = (bool(z["first"]), float(z["seconds"]))
        return out

    two = reference(2)
    first_run = flags()
    assert sorted(first for first, _ in first_run.values()) == [False, True]
    assert two.part_seconds == next(s for first, s in first_run.values() if not first)
    three = reference(3)
    added = {k: v for k, v in flags().items() if k not in first_run}
    assert len(renders) == 3 and [first for first, _ in added.values()] == [True]
    assert three.part_seconds == two.part_seconds  # the one warm part still


def test_references_are_shared_by_denoiser_settings_and_redrawn_for_a_new_renderer_revision(tmp_path):
    """A reference is never denoised: benches of OIDN settings (another quality or prefilter in the
    spec's backend block) read the references a first bench cached, a reference of more parts
    renders only the parts not cached, and a backend plugin of a new revision (which renders
    differently) draws its own."""
    import dataclasses

    from specsynth.run.bench import Setting, bench_setting

    renders = []
    Flat = _stand_in(lambda n, seed, cam: np.full((8, 8, 3), 0.5, np.float32), renders)
    plugin, spec, shots, picked = _bench_of_one_view(tmp_path)

    def bench_reference(p, parts=2, **options):
        ref = Setting("x", "reference", "high", {"__factor__": 2, "__parts__": parts}, reference=True)
        bench_setting(p, Flat, ref, {"name": "x", **options}, spec, picked, shots, {}, 1, tmp_path)

    bench_reference(plugin, denoise_quality="fast")
    assert len(renders) == 2
    bench_reference(plugin, denoise_quality="balanced", denoise_prefilter="fast")
    assert len(renders) == 2
    bench_reference(plugin, parts=3)
    assert len(renders) == 3
    bench_reference(dataclasses.replace(plugin, revision=plugin.revision + 1))
    assert len(renders) == 5


@pytest.mark.slow
def test_bench_targeted_row_and_cached_references(tmp_path):
    """`high+targeted` (quality.control: error) has per-view estimates and targets; a second run
    into the same folder renders no reference (they are cached by content) and measures the same
    reference-based errors; at --ref-factor 2 the plain `high` comes from the reference's parts."""
    out = tmp_path / "bench"
    cmd = [sys.executable, "-m", "specsynth.cli", "bench", str(ROOT / "specs/demo.yaml"), "--out", str(out),
           "--views", "1", "--scale", "0.05", "--ref-factor", "2", "--backend", "cycles", "--levels", "high",
           "--only", "high+targeted,high", "--set", "arrangements.count=1"]
    runs = []
    for _ in range(2):
        r = subprocess.run(cmd, capture_output=True, text=True, timeout=900, env={**os.environ, "COLUMNS": "250"})
        assert r.returncode == 0, r.stdout + r.stderr
        runs.append(json.loads((out / "bench.json").read_text())["rows"])
    assert len(list((out / "bench" / "references").glob("*.npz"))) == 2  # its two parts
    for rows in runs:
        row = next(r for r in rows if r["setting"] == "high+targeted")
        view = row["views"][0]
        assert view["error_target"] > 0 and math.isfinite(view["error_estimate"]) and view["samples"] >= 2  # an estimate may be below 0
    ref = [next(r for r in rows if r["setting"] == "reference") for rows in runs]
    assert ref[0]["seconds"] == ref[1]["seconds"]  # the cached reference's own render time
    high = [next(r for r in rows if r["setting"] == "high") for rows in runs]  # from the reference's parts
    same = ("seconds", "rel_mse", "psnr", "ssim", "samples", "views")  # a scene load is timed again
    assert [high[0][k] for k in same] == [high[1][k] for k in same] and high[0]["samples"] == 225 and high[0]["ssim"] is None
    assert 0 < high[0]["rel_mse"] and 0 < high[0]["psnr"] < 100


def test_under_ref_crop_every_row_is_timed_and_scored_on_the_window_and_the_whole_image_is_timed_beside(tmp_path):
    """--ref-crop: the reference's parts render a cropped camera; every other setting renders the
    whole image, scored on the window (here against the known noise of the window's pixels) and
    timed, and the window alone, timed: the row's seconds, as the preset's from the parts are its
    window's. A stand-in renderer whose image is a function of the ray's direction (so a cropped
    camera sees the same pixels) and whose render takes a time in proportion to its pixels."""
    import time
    from types import SimpleNamespace

    from specsynth.model.ir import CameraIR, as_tuple
    from specsynth.plugins import BackendPlugin
    from specsynth.run.bench import Setting, bench_setting, centre_window
    from specsynth.spec.models import BackendOptions, Quality

    full = CameraIR(K=((50.0, 0.0, 39.5), (0.0, 50.0, 29.5), (0.0, 0.0, 1.0)), width=80, height=60,
                    R_w2c=as_tuple(np.eye(3)), t_w2c=(0.0, 0.0, 0.0))
    window = centre_window(80, 60, 0.5)
    x0, y0, w, h = window

    def mean_of(cam):  # bright on the left, dark on the right, by direction
        u = np.arange(cam.width) - cam.K[0][2]
        v = np.arange(cam.height)[:, None] - cam.K[1][2]
        return np.repeat((0.5 - 0.01 * u + 0.002 * v)[..., None], 3, axis=-1).clip(0.05, None)

    drawn = []

    def image(n, seed, cam):
        drawn.append((n, cam.width, cam.height))
        time.sleep(cam.width * cam.height * 1e-5)  # 48 ms for the whole image, 12 ms for the window
        mu = mean_of(cam)
        return (mu * (1 + np.random.default_rng(seed).standard_normal(mu.shape) / np.sqrt(n))).astype(np.float32)

    Windowed = _stand_in(image, [])

    (tmp_path / "bench").mkdir()
    plugin = BackendPlugin(name="x", options=BackendOptions, backend="nowhere:X")
    spec = SimpleNamespace(quality=Quality(level="high"))
    shots = SimpleNamespace(scene=lambda arec: None, camera=lambda vrec: full, window=window,
                            reference_camera=lambda vrec: full.cropped(*window))
    picked = [(SimpleNamespace(to_json=lambda: {"arrangement": 0}), 0, 11)]
    refs = {}
    args = ({"name": "x"}, spec, picked, shots, refs, 1, tmp_path)
    bench_setting(plugin, Windowed, Setting("x", "reference", "high", {"__factor__": 2, "__parts__": 2}, reference=True),
                  *args)
    assert drawn == [(225, w, h)] * 2 and refs[0].linear.shape == (h, w, 3)
    preset = bench_setting(plugin, Windowed, Setting("x", "high", "high", {}), *args)
    assert preset.seconds == refs[0].part_seconds and preset.image_seconds is None  # not measured
    medium = bench_setting(plugin, Windowed, Setting("x", "medium", "medium", {}), *args)
    assert drawn[2:] == [(36, 80, 60)] * 2 + [(36, w, h)] * 2  # each a warm-up and the timed render
    assert 0.012 <= medium.seconds < 0.048 <= medium.image_seconds
    mu = mean_of(full)[y0:y0 + h, x0:x0 + w]
    assert np.allclose(refs[0].linear, mu, rtol=0.25)  # the window's pixels, not another part of the image
    expected = np.mean(mu**2 / 36 / (mu**2 + 0.01))  # rel_mse's normaliser: the reference's square + 0.01
    assert medium.rel_mse == pytest.approx(expected, rel=0.1)


@pytest.mark.slow
def test_bench_on_a_window_with_cycles(tmp_path):
    """--ref-crop on a real renderer: the reference is the window's size, every rung has the
    whole image's time beside its window's, the preset from the parts has only the window's, and
    the table says which is which."""
    from PIL import Image

    out = tmp_path / "bench"
    r = subprocess.run([sys.executable, "-m", "specsynth.cli", "bench", str(ROOT / "specs/demo.yaml"), "--out", str(out),
                        "--views", "1", "--scale", "0.1", "--ref-factor", "2", "--ref-crop", "0.5", "--backend", "cycles",
                        "--levels", "high", "--only", "high,high+denoise@4", "--set", "arrangements.count=1"],
                       capture_output=True, text=True, timeout=900, env={**os.environ, "COLUMNS": "250"})
    assert r.returncode == 0, r.stdout + r.stderr
    assert "s / window" in r.stdout and "s / image" in r.stdout
    assert Image.open(out / "bench" / "cycles_ref_0.png").size == (32, 24)  # the 64 x 48 image's centre
    with open(out / "bench.csv") as f:
        rows = {row["setting"]: row for row in csv.DictReader(f)}
    assert rows["high"]["image_seconds"] == "" and float(rows["high"]["seconds"]) > 0
    rung = rows["high+denoise@4"]
    assert 0 < float(rung["seconds"]) < float(rung["image_seconds"]) and 0 < float(rung["psnr_db"]) < 100
    meta = json.loads((out / "bench.json").read_text())["meta"]
    assert meta["ref_crop"] == 0.5 and meta["window"] == [16, 12, 32, 24]
