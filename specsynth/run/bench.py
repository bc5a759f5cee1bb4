"""`specsynth bench`: render time against image error, per backend and setting.

For the first N accepted views of a spec, every installed PBR backend renders each quality level
(with/without denoising and adaptive sampling where the backend has them) and a converged
reference (``ref_parts`` independent renders of ``ref_factor / 2`` x the high preset's samples each).
Error is measured against the backend's own reference: relMSE on linear radiance, PSNR and SSIM on
8-bit sRGB.
"""

from __future__ import annotations

import csv
import importlib
import math
import statistics
import time
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import Any, Callable

import numpy as np
from pydantic import ValidationError
from threadpoolctl import threadpool_limits

from ..model.colour import linear_to_srgb8
from ..model.error import extrapolated_rel_mse, rel_mse
from ..model.error import taken as taken_by
from ..model.records import ArrangementRecord, ViewRecord
from ..plan.compiler import JobGraph
from ..plugins import BackendPlugin, PluginNotFound, backend_plugin, installed_backend_plugins
from ..spec.models import PAPER_PRESETS, QualityPreset
from .build import build
from .render import draw_to_target, render_at
from .store import Store, write_json
from .worker import Materials, Optics, World


@dataclass(frozen=True)
class Shots:
    """The picked views as a build's renders see them: each arrangement's scene rebuilt from its
    record, each view's camera at the bench's resolution."""

    world: World
    optics: Optics
    materials: Materials  # the spec's objects' (a render input)
    window: tuple[int, int, int, int] | None = None  # (x0, y0, w, h) the reference renders; None: all

    def scene(self, arec: ArrangementRecord):
        return self.world.render_scene(arec, self.materials)

    def camera(self, vrec: ViewRecord):
        return self.optics.camera(vrec.R_w2c, vrec.t_w2c)

    def reference_camera(self, vrec: ViewRecord):
        cam = self.camera(vrec)
        return cam if self.window is None else cam.cropped(*self.window)


def centre_window(width: int, height: int, fraction: float) -> tuple[int, int, int, int] | None:
    """(x0, y0, w, h): the centred window of ``fraction`` of the image's width and height (at
    least one pixel each way), or None for the whole image."""
    if not 0 < fraction <= 1:
        raise ValueError(f"--ref-crop {fraction}: a fraction of the image's width and height, in (0, 1]")
    w, h = max(1, round(width * fraction)), max(1, round(height * fraction))
    if (w, h) == (width, height):
        return None
    return (width - w) // 2, (height - h) // 2, w, h


def in_window(image: np.ndarray, window: tuple[int, int, int, int] | None) -> np.ndarray:
    if window is None:
        return image
    x0, y0, w, h = window
    return image[y0:y0 + h, x0:x0 + w]


@dataclass
class Setting:
    backend: str
    label: str
    level: str
    options: dict  # updates to the backend's spec options
    reference: bool = False


@dataclass
class Row:
    backend: str
    setting: str
    level: str
    seconds: float
    rel_mse: float
    psnr: float
    ssim: float
    samples: int
    phases: dict = None  # mean seconds per backend phase (RenderResult.stats["phases"])
    # per view: relMSE against the reference less the reference's own variance, and under an error
    # target the render's estimated error, the target (the paper preset's estimated error), samples
    views: list = None
    load: float = 0.0  # median seconds of a scene load
    # the whole image's seconds; under --ref-crop ``seconds`` is the window's (None: not measured)
    image_seconds: float | None = None


LEVELS = ("low", "medium", "high")


@dataclass(frozen=True)
class Reference:
    """One view's converged image: the mean of renders with independent seeds (its parts), its
    own relative variance, and what each part rendered and took."""

    linear: np.ndarray
    rgb: np.ndarray  # 8-bit sRGB of ``linear``
    variance: float
    parts: tuple[np.ndarray, ...] | None = None
    preset: QualityPreset | None = None  # each part's
    part_seconds: float = 0.0  # a part's render after the scene's first (which syncs it)
    load: float = 0.0


@dataclass(frozen=True)
class BenchSettings:
    """What `specsynth bench` tries on a backend beyond its quality levels. A backend declares it as
    ``BENCH`` in an optional module ``bench`` of the package that holds its renderer (e.g.
    ``specsynth_cycles.bench``): the bench's business, so not in the plugin record a build reads."""

    # extra settings per quality level: (label suffix, option updates)
    variants: tuple[tuple[str, dict[str, Any]], ...] = ()
    # boolean options whose saving is measured by rendering the same views with and without: (label, option)
    toggles: tuple[tuple[str, str], ...] = ()


def bench_settings(plugin: BackendPlugin) -> BenchSettings:
    """The backend's own ``BENCH``, or none beyond the levels when its package has no ``bench`` module."""
    package = plugin.backend.partition(":")[0].rpartition(".")[0]
    if not package:
        return BenchSettings()
    name = f"{package}.bench"
    try:
        module = importlib.import_module(name)
    except ModuleNotFoundError as e:
        if e.name == name:
            return BenchSettings()
        raise
    found = getattr(module, "BENCH", None)
    if not isinstance(found, BenchSettings):
        raise PluginNotFound(f"{name}.BENCH of backend {plugin.name!r} is not a specsynth.run.bench.BenchSettings "
                             f"(got {type(found).__name__})")
    return found


def settings_for(plugin: BackendPlugin, ref_factor: int, levels: tuple[str, ...] = LEVELS,
                 ladder: bool = False, ref_parts: int = 2) -> list[Setting]:
    """Each quality level plain and with each of the backend's BENCH variants, then a reference.
    ``ladder``: also the level's light paths at 1, 2, 4, ... samples (fewer than its own) with
    denoising, where a denoising backend reaches the level's error for less (the calibration)."""
    out = []
    for level in levels:
        out.append(Setting(plugin.name, f"{level}", level, {}))
        if plugin.calibrated.get(level):
            out.append(Setting(plugin.name, f"{level}+calibrated", level, dict(plugin.calibrated[level])))
        for suffix, options in bench_settings(plugin).variants:
            out.append(Setting(plugin.name, f"{level}+{suffix}", level, dict(options)))
        if plugin.capabilities.sampling_noise:  # quality.control: error
            out.append(Setting(plugin.name, f"{level}+targeted", level, {"__control__": "error"}))
        if ladder and plugin.capabilities.denoise:
            own = PAPER_PRESETS[level].samples
            n = 1
            while n < own:
                out.append(rung(plugin.name, level, n))
                n *= 2
    out.append(Setting(plugin.name, "reference", "high", {"__factor__": ref_factor, "__parts__": ref_parts},
                       reference=True))
    return out


def rung(plugin_name: str, level: str, samples: int, supersample: int = 1) -> Setting:
    """The level's light paths at ``samples`` with denoising (at ``supersample`` times the
    resolution: ``<level>+denoise@NxF``): one rung of the ladder, which renders the level's
    calibrated way but for its samples (``calibrated_way``)."""
    label = f"{level}+denoise@{samples}" + (f"x{supersample}" if supersample > 1 else "")
    options = {"denoise": True, "samples": samples, **({"supersample": supersample} if supersample > 1 else {}),
               "__rung__": True}
    return Setting(plugin_name, label, level, options)


SAMPLING = ("samples", "supersample", "denoise")  # what a rung sets itself


def calibrated_way(plugin: BackendPlugin, level: str, spec_backend) -> dict:
    """The options of a level's calibration other than its samples and denoiser (Mitsuba's
    ``emitter_sampling``), where the spec does not set them: a rung renders as the calibrated
    level would at its samples, so the ladder measures the counts a calibration can choose from."""
    mine = spec_backend.model_fields_set if spec_backend.name == plugin.name else set()
    return {k: v for k, v in (plugin.calibrated.get(level) or {}).items() if k not in SAMPLING and k not in mine}


def _rung_of(label: str, level: str) -> tuple[int, int] | None:
    """(N, F) of a label ``<level>+denoise@N`` (F 1) or ``<level>+denoise@NxF`` (N >= 1, F 2-4), else None."""
    head, _, tail = label.partition("+denoise@")
    n, x, f = tail.partition("x")
    if head != level or not n.isdigit() or int(n) < 1 or (x and not (f.isdigit() and 2 <= int(f) <= 4)):
        return None
    return int(n), int(f or 1)


def _rung_samples(label: str, level: str) -> int | None:
    """N of a label ``<level>+denoise@N`` (N >= 1, at the image's own resolution), else None."""
    found = _rung_of(label, level)
    return found[0] if found and found[1] == 1 else None


def pick_settings(settings: list[Setting], only: tuple[str, ...], denoise: bool = False) -> list[Setting]:
    """The settings labelled in ``only`` (all when empty), each once, and always the reference every
    row needs, last. A full ladder at VGA costs hours on a CPU; this benches the rows that answer one
    question. With ``denoise`` (the backend denoises) any rung ``<level>+denoise@N`` may be asked
    for, not only the ladder's powers of two, and ``<level>+denoise@NxF``: N samples per pixel at F
    times the resolution (``backend.supersample``)."""
    if not only:
        return settings
    ref = [st for st in settings if st.reference]
    by_label = {st.label: st for st in settings if not st.reference}
    levels = {st.level for st in by_label.values()}
    for x in only:
        for lv in levels if denoise and x not in by_label else ():
            if found := _rung_of(x, lv):
                by_label[x] = rung(ref[0].backend, lv, *found)
    unknown = [x for x in only if x not in by_label]
    if unknown:
        labels = [st.label for st in settings if not st.reference]
        raise ValueError(f"--only: no setting {', '.join(map(repr, unknown))} for backend "
                         f"{settings[0].backend!r}; it has {', '.join(labels)}")
    picked = {by_label[x].label: by_label[x] for x in only}  # "@020" and "@20" are one rung
    return list(picked.values()) + ref


def psnr8(a: np.ndarray, b: np.ndarray) -> float:
    mse = float(np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2))
    return float("inf") if mse == 0 else 10 * np.log10(255.0**2 / mse)


def ssim8(a: np.ndarray, b: np.ndarray) -> float:
    from skimage.metrics import structural_similarity

    return float(structural_similarity(a, b, channel_axis=2, data_range=255))


def _views(graph: JobGraph, out: Path, n: int):
    """Arrangements and the first n accepted views, built (and cached) in ``out``; and what the
    camera stage and its cache saved (see ``camera_savings``)."""
    first = _timed_view_build(graph, out)
    cached = _timed_view_build(graph, out)  # everything is in the store now: what a rebuild costs
    store = Store(out)
    picked = []
    for arr in range(graph.n_arrangements):
        a, views, _ = graph.arrangement_jobs(arr)
        if not store.has("arrange", a.key):
            continue
        arec = ArrangementRecord.from_json(store.load("arrange", a.key))
        for v in views:
            if store.has("view", v.key):
                vrec = ViewRecord.from_json(store.load("view", v.key))
                if vrec.accepted:
                    picked.append((arec, vrec, v.seed))
            if len(picked) >= n:
                return picked, (first, cached)
    return picked, (first, cached)


def _timed_view_build(graph: JobGraph, out: Path) -> dict:
    """Build arrangements and cameras; the first real run's numbers are kept next to the store, so
    a later bench into the same folder still knows what the cached jobs cost."""
    import json

    t0 = time.perf_counter()
    s = build(graph, out, jobs=1, until="view")
    wall = time.perf_counter() - t0
    ran = s.stages["arrange"].ran + s.stages["view"].ran
    info = {"wall": wall, "jobs": s.stages["arrange"].total + s.stages["view"].total, "ran": ran,
            "worker_seconds": s.stages["arrange"].seconds + s.stages["view"].seconds,
            "cameras": s.stages["view"].total, "rejected": s.cameras_rejected, "rejected_seconds": s.rejected_seconds}
    meta = Path(out) / ".specsynth" / "bench_views.json"
    if ran:
        write_json(meta, info)
    elif meta.exists():
        return {**json.loads(meta.read_text()), "wall": wall, "ran": 0, "cached_wall": wall}
    return info


@dataclass
class Saving:
    backend: str
    what: str
    seconds: float  # saved, per the unit in ``per``
    per: str
    how: str  # what was measured


def camera_savings(backend: str, rows: list[Row], level: str, cams: tuple[dict, dict], load_s: float,
                   per_arrangement: int) -> list[Saving]:
    """Skipping, priced with this bench's own measurements on this backend."""
    first, cached = cams
    out = []
    render = next((r.image_seconds for r in rows if r.backend == backend and r.setting == level), None)
    if render is not None:  # priced only when the spec's level was benched on the whole image (`--only`, `--ref-crop`)
        out.append(Saving(backend, "visibility pre-check", first["rejected"] * render - first["rejected_seconds"],
                          "view build", f"{first['rejected']} sampled cameras rejected for {first['cameras']} view "
                          f"jobs ({first['rejected_seconds']:.2f} s of checks) x {render:.2f} s per '{level}' render"))
    out.append(Saving(backend, "scene loaded once per arrangement", (per_arrangement - 1) * load_s, "arrangement",
                      f"({per_arrangement} cameras - 1) x {load_s:.2f} s scene load (median)"))
    if cached["ran"] == 0 and first.get("worker_seconds", 0) > 0:  # unknown when cached by an older bench
        out.append(Saving(backend, "cache", first["worker_seconds"] - cached["wall"], "rebuild of the views",
                          f"{first['jobs']} arrange/view jobs: {first['worker_seconds']:.2f} s first run, "
                          f"{cached['wall']:.2f} s rebuild (all cached)"))
    return out


def toggle_saving(plugin: BackendPlugin, label: str, option: str, base_opts: dict, spec, picked, shots: Shots, preset,
                  repeats: int) -> Saving:
    """The same views rendered with a boolean backend option on and off."""
    cls = plugin.load_class()
    times: dict[bool, list[float]] = {True: [], False: []}
    for arec, vrec, seed in picked:
        scene = shots.scene(arec)
        cam = shots.camera(vrec)
        for on in (True, False, False, True) * max(1, repeats):  # alternate: the first render after a load is slower
            backend = cls(plugin.options.model_validate({**base_opts, option: on}), threads=0)
            backend.load(scene)
            backend.render(cam, preset, seed, clamp=spec.quality.clamp)  # warm
            t0 = time.perf_counter()
            backend.render(cam, preset, seed, clamp=spec.quality.clamp)
            times[on].append(time.perf_counter() - t0)
            backend.close()
    on, off = statistics.median(times[True]), statistics.median(times[False])
    return Saving(plugin.name, label, off - on, "render",
                  f"median {on:.2f} s with {option} vs {off:.2f} s without, {len(picked)} view(s)")


def scaled_intrinsics(intr, scale: float):
    """The same camera at another resolution (pixel centres kept: OpenCV's +0.5 convention)."""
    return intr.model_copy(update={
        "width": max(8, round(intr.width * scale)), "height": max(8, round(intr.height * scale)),
        "fx": intr.fx * scale, "fy": intr.fy * scale, "cx": (intr.cx + 0.5) * scale - 0.5, "cy": (intr.cy + 0.5) * scale - 0.5,
    })


def run_bench(graph: JobGraph, out: Path, *, n_views: int = 2, repeats: int = 1, ref_factor: int = 4,
              scale: float = 0.5, backends: list[str] | None = None, console=None, levels: tuple[str, ...] = LEVELS,
              ladder: bool = False, only: tuple[str, ...] = (), ref_parts: int = 2,
              ref_crop: float = 1.0) -> list[Row]:
    """``ref_crop``: the references render the centred window of this fraction of the image's
    width and height. Every other setting renders the whole image, timed (``Row.image_seconds``)
    and scored on that window, and the window alone, timed (``Row.seconds``): the preset's
    time from the parts is its window's, and so speed-ups compare the same pixels."""
    from ..plan.inputs import ArrangeInputs

    if ref_parts < 2:
        raise ValueError(f"--ref-parts {ref_parts}: a reference needs at least 2 parts (its own variance)")
    centre_window(8, 8, ref_crop)  # a wrong fraction fails before anything is built
    out = Path(out)
    spec = graph.spec
    intr = spec.intrinsics
    small = scaled_intrinsics(intr, scale)
    window = centre_window(small.width, small.height, ref_crop)
    names = backends or [p.name for p in installed_backend_plugins() if p.capabilities.draws_scene]
    for name in names:  # a wrong label or option fails before anything is built
        try:
            plugin = backend_plugin(name)
        except PluginNotFound:
            continue  # reported (and skipped) below
        if only:
            pick_settings(settings_for(plugin, ref_factor, levels, ladder, ref_parts), only, plugin.capabilities.denoise)
        base_options(spec.backend, plugin)
    picked, cams = _views(graph, out, n_views)
    if not picked:
        raise RuntimeError("no accepted view to benchmark; widen the camera ranges")
    rows: list[Row] = []
    savings: list[Saving] = []
    for name in names:
        try:
            plugin = backend_plugin(name)
            cls = plugin.load_class()
        except PluginNotFound as e:
            if console:
                console.print(f"[yellow]skipping {name}: {e}[/yellow]")
            continue
        base_opts = base_options(spec.backend, plugin)
        # One BLAS thread, as in a build's workers (tasks.Steps): only the renderer is timed.
        with threadpool_limits(limits=1, user_api="blas"):
            shots = Shots(World(ArrangeInputs.cut(spec), graph.spec_path.parent), Optics(small), spec.objects.materials,
                          window)
            refs: dict[int, Reference] = {}
            settings = pick_settings(settings_for(plugin, ref_factor, levels, ladder, ref_parts), only, plugin.capabilities.denoise)
            settings = [settings[-1]] + settings[:-1]  # reference first: every other row needs it
            counts = (partial(plugin.sample_counts, plugin.options.model_validate(base_opts))
                      if plugin.sample_counts is not None else None)

            def one(st: Setting) -> Row:
                r = bench_setting(plugin, cls, st, base_opts, spec, picked, shots, refs, repeats, out)
                if console:
                    console.print(f"{r.backend:8s} {r.setting:18s} {r.seconds:8.2f} s  PSNR {r.psnr:6.2f} dB  relMSE {r.rel_mse:.2e}")
                return r

            def finer(done: list[Row]) -> list[Setting]:
                return [rung(name, lv, n) for lv in levels for n in [finer_rung(done, name, lv, counts)] if n]

            rows += bench_in_turn(settings, one, finer if ladder and plugin.capabilities.denoise else None)
            level = spec.quality.paper_level
            savings += camera_savings(name, rows, level, cams, statistics.median(r.load for r in rows if r.backend == name), spec.cameras.per_arrangement)
            preset = spec.quality.model_copy(update={"level": f"paper_{spec.quality.paper_level}"}).resolved()
            for label, option in bench_settings(plugin).toggles:
                savings.append(toggle_saving(plugin, label, option, base_opts, spec, picked, shots, preset, repeats))
    write_report(rows, out, graph, savings=savings, n_views=len(picked), scale=scale, ref_factor=ref_factor,
                 ref_parts=ref_parts, ref_crop=ref_crop, window=window)
    return rows, savings


def bench_in_turn(settings: list[Setting], bench_one: Callable[[Setting], Row],
                  next_settings: Callable[[list[Row]], list[Setting]] | None = None) -> list[Row]:
    """Each setting benched in turn; then, while ``next_settings`` of the rows so far names more
    (the ladder's refinement), those."""
    rows: list[Row] = []
    todo = list(settings)
    while todo:
        rows.append(bench_one(todo.pop(0)))
        if not todo and next_settings is not None:
            todo = next_settings(rows)
    return rows


SHARED_OPTIONS = ("denoise_quality", "denoise_prefilter")  # BackendOptions fields a bench does not vary


def base_options(spec_backend, plugin: BackendPlugin) -> dict:
    """The options a backend is benched with: the spec's own, minus what the bench varies (denoise,
    samples, supersample); for another backend than the spec's, the options every backend takes
    that the spec sets (``--set backend.denoise_prefilter=none`` reaches every benched backend, as a
    spec swapped by ``backend.name`` alone would render). A value the backend does not take is a
    ValueError."""
    if spec_backend.name == plugin.name:
        return spec_backend.model_dump(exclude={"denoise", "samples", "supersample"})
    opts = {"name": plugin.name, **{k: getattr(spec_backend, k) for k in SHARED_OPTIONS if k in spec_backend.model_fields_set}}
    try:
        plugin.options.model_validate(opts)
    except ValidationError as e:
        bad = "; ".join(f"backend.{'.'.join(map(str, err['loc']))}: {err['msg']}" for err in e.errors())
        raise ValueError(f"bench of {plugin.name!r}: the spec's {bad}") from None
    return opts


def _setting_options(plugin: BackendPlugin, st: Setting, base_opts: dict, spec):
    """(the backend's options, the preset it renders, the error target of a ``+targeted`` setting
    or None) of one setting; a reference renders every ray count of the preset times its factor,
    each of its parts half that (backends take samples from their max)."""
    way = calibrated_way(plugin, st.level, spec.backend) if st.options.get("__rung__") else {}
    opts = {**base_opts, **way, **{k: v for k, v in st.options.items() if not k.startswith("__")}}
    preset = spec.quality.model_copy(update={"level": f"paper_{st.level}"}).resolved()
    if st.reference:
        f = st.options["__factor__"]
        preset = QualityPreset(**{**preset.model_dump(), "aa": max(1, preset.aa * f // 2),
                                  "diffuse_rays": max(1, preset.diffuse_rays * f // 2),
                                  "specular_rays": max(1, preset.specular_rays * f // 2)})
    options, target = plugin.options.model_validate(opts), None
    if st.options.get("__control__") == "error":
        quality = spec.quality.model_copy(update={"level": st.level, "control": "error"})
        target = plugin.error_target(options, quality)  # the setting's own samples start it
        options = plugin.options_for(options, quality)
    return options, preset, target


REF_SEED = 7919  # the reference's part j renders with seed + REF_SEED + j: seeds no setting renders with


def bench_setting(plugin: BackendPlugin, cls, st: Setting, base_opts: dict, spec, picked, shots: Shots, refs: dict,
                  repeats: int, out: Path) -> Row:
    """Every picked view rendered with one setting, timed; its error against the reference (which
    the reference setting, benched first, puts into ``refs``). A setting that is what each part of
    the reference rendered is measured from the parts instead of being rendered again."""
    from ..outputs.images import write_png

    options, preset, target = _setting_options(plugin, st, base_opts, spec)
    if is_a_reference_part(st, preset, target, refs):
        return row_from_parts(plugin.name, st, refs, whole=shots.window is None)
    backend = cls(options, threads=0)
    draw = _drawer(backend, preset, target, spec.quality.clamp, options.supersample)
    times, image_times, errs, loads, phase_sums, views = [], [], [], [], {}, []
    samples = 0
    for i, (arec, vrec, seed) in enumerate(picked):
        t0 = time.perf_counter()
        backend.load(shots.scene(arec))
        loads.append(time.perf_counter() - t0)
        cam = shots.camera(vrec)
        if st.reference:
            refs[i] = reference(backend, options, shots.reference_camera(vrec), preset, seed, spec.quality.clamp, arec,
                                out, load=loads[-1], revision=plugin.revision, parts=st.options.get("__parts__", 2))
            write_png(out / "bench" / f"{plugin.name}_ref_{i}.png", refs[i].rgb)
            times.append(refs[i].part_seconds * len(refs[i].parts))
            continue
        seconds, res = _timed(draw, cam, seed, repeats, warm=i == 0)
        image_times.append(seconds)
        # under --ref-crop the setting's time is its window's, as the preset's from the parts is
        times.append(seconds if shots.window is None else
                     _timed(draw, shots.reference_camera(vrec), seed, repeats, warm=i == 0)[0])
        # per pixel of the image: a supersampled render traces F^2 times its count
        samples = int(res.stats.get("samples", res.stats.get("spp", 0))) * int(res.stats.get("supersample", 1)) ** 2
        for k, v in (res.stats.get("phases") or {}).items():
            phase_sums[k] = phase_sums.get(k, 0.0) + v / len(picked)
        lin = in_window(res.linear if res.linear is not None else res.rgb.astype(np.float32) / 255, shots.window)
        rgb = in_window(res.rgb, shots.window)
        ref = refs[i]
        errs.append((rel_mse(lin, ref.linear) - ref.variance, psnr8(rgb, ref.rgb), ssim8(rgb, ref.rgb)))
        views.append({"rel_mse": errs[-1][0], "samples": samples,
                      **{k: res.stats[k] for k in ("error_estimate", "error_se", "error_target")
                         if k in res.stats}})
        if i == 0:
            write_png(out / "bench" / f"{plugin.name}_{st.label}_{i}.png", res.rgb)
    backend.close()
    phases = {k: round(v, 4) for k, v in phase_sums.items()}
    if st.reference:
        return Row(plugin.name, st.label, st.level, float(np.mean(times)), 0.0, float("inf"), 1.0, samples, phases,
                   load=statistics.median(loads))
    e = np.mean(np.asarray(errs), axis=0)
    # per view, as the seconds and errors: under an error target each view takes its own samples
    mean_samples = round(float(np.mean([v["samples"] for v in views])))
    return Row(plugin.name, st.label, st.level, float(np.mean(times)), float(e[0]), float(e[1]), float(e[2]),
               mean_samples, phases, views, statistics.median(loads), float(np.mean(image_times)))


def _timed(draw, cam, seed: int, repeats: int, warm: bool):
    """(median seconds of ``repeats`` renders, the last render); ``warm``: one untimed render
    first, as the first render of a setting or a camera size compiles kernels (Dr.Jit, per
    sampler, spp and film) or syncs the scene (Cycles), and a dataset renders thousands after it."""
    if warm:
        draw(cam, seed)
    ts = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        res = draw(cam, seed)
        ts.append(time.perf_counter() - t0)
    return statistics.median(ts), res


def is_a_reference_part(st: Setting, preset: QualityPreset, target, refs: dict) -> bool:
    """A plain level (the spec's options, no error target) whose preset each part of every view's
    reference rendered: with ``--ref-factor 2`` the paper's ``high``."""
    return (not st.reference and not st.options and target is None and bool(refs)
            and all(r.parts is not None and r.preset == preset for r in refs.values()))


def part_variance(parts, norm: np.ndarray) -> float:
    """One part's relative variance (its relMSE as a render), estimated from independent parts:
    the mean over every pair ``i, j`` of ``(x_i - x_j)² / 2`` over ``norm² + ε``. Where rare bright
    samples make most of an image's error, one pair's estimate varies severalfold between pairs
    (Cycles, a demo view, 225 samples: 3.5e-3 to 9.2e-3 over the 10 pairs of 5 renders), hence
    ``--ref-parts``."""
    pairs = [(i, j) for i in range(len(parts)) for j in range(i + 1, len(parts))]
    return float(np.mean([extrapolated_rel_mse(parts[i], parts[j], 1, 1, norm=norm) for i, j in pairs]))


def row_from_parts(backend: str, st: Setting, refs: dict, whole: bool = True) -> Row:
    """The row of a setting each part of the reference rendered, from the K parts: its relMSE is
    one render's (``part_variance``); its PSNR that of an independent render against the parts'
    mean, whose 8-bit MSE is ``(1 + 1/K) / 2`` of a pair's ``(x_i8 - x_j8)^2`` (one render's
    noise plus the mean's K-th of it); its time a part's render. No SSIM: it has no such
    relation. At VGA this saves the preset's two renders (a warm-up and the timed one) of
    minutes each. Under ``--ref-crop`` its time is a part's of the window, the whole image's not
    measured."""
    views, psnrs = [], []
    for ref in refs.values():
        k = len(ref.parts)
        views.append({"rel_mse": part_variance(ref.parts, ref.linear), "samples": ref.preset.samples})
        eight = [linear_to_srgb8(x).astype(np.float64) for x in ref.parts]
        pair_mse8 = np.mean([np.mean((eight[i] - eight[j]) ** 2) for i in range(k) for j in range(i + 1, k)])
        mse8 = (1 + 1 / k) / 2 * float(pair_mse8)
        psnrs.append(float("inf") if mse8 == 0 else 10 * np.log10(255.0**2 / mse8))
    rs = list(refs.values())
    seconds = float(np.mean([r.part_seconds for r in rs]))
    return Row(backend, st.label, st.level, seconds,
               float(np.mean([v["rel_mse"] for v in views])), float(np.mean(psnrs)), float("nan"),
               rs[0].preset.samples, {}, views, statistics.median(r.load for r in rs),
               seconds if whole else None)


REFERENCE_FORMAT = 3  # 3: one file per part, with its render time and whether it was the scene's first


def reference(backend, options, cam, preset: QualityPreset, seed: int, clamp, arec, out: Path,
              load: float = 0.0, revision: int = 0, parts: int = 2) -> Reference:
    """A converged image of one view as ``parts`` independent renders of ``preset``. Each part is
    cached under ``out/bench/references`` by everything that makes its pixels (renderer, its
    plugin's revision and options, arrangement, camera, samples, seed): at VGA a part costs
    minutes, and a bench run again into the same folder renders none it has (with more parts,
    only the new ones)."""
    if parts < 2:
        raise ValueError(f"a bench reference needs at least 2 parts (its own variance), got {parts}")
    # A reference is never denoised and renders its own samples: the options that set those do not
    # change its pixels, so benches of denoiser settings share it.
    if options.denoise or options.samples is not None or options.supersample != 1:
        raise ValueError("a bench reference renders its own samples at its own resolution, undenoised")
    images, warm, cold = [], [], []
    first = True  # the scene's first render syncs it (Cycles) or compiles kernels (Dr.Jit): not a part's time
    for j in range(parts):
        path = _part_path(backend, options, cam, preset, seed + REF_SEED + j, clamp, arec, out, revision)
        if not path.is_file():
            _render_part(backend, cam, preset, seed + REF_SEED + j, clamp, path, first)
            first = False
        with np.load(path) as z:
            images.append(z["linear"])
            (cold if bool(z["first"]) else warm).append(float(z["seconds"]))
    lin = np.mean(images, axis=0)
    return Reference(lin, linear_to_srgb8(lin), part_variance(images, lin) / parts, tuple(images), preset,
                     statistics.median(warm or cold), load)


def _part_path(backend, options, cam, preset: QualityPreset, seed: int, clamp, arec, out: Path, revision: int) -> Path:
    """Where one part of a reference is cached: named by everything that makes its pixels."""
    import hashlib
    import json

    drawn = options.model_dump(mode="json", exclude={"denoise", "denoise_quality", "denoise_prefilter", "samples",
                                                     "supersample"})
    key = hashlib.sha256(json.dumps([REFERENCE_FORMAT, backend.version(), revision, drawn, arec.to_json(), repr(cam),
                                     preset.model_dump(), seed, clamp],
                                    sort_keys=True, default=str).encode()).hexdigest()[:32]
    return out / "bench" / "references" / f"{key}.npz"


def _render_part(backend, cam, preset: QualityPreset, seed: int, clamp, path: Path, first: bool) -> None:
    """One part rendered, with its time and whether it was the scene's first render, written atomically."""
    t0 = time.perf_counter()
    image = backend.render(cam, preset, seed, clamp=clamp).linear
    seconds = time.perf_counter() - t0
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp.npz")
    np.savez(tmp, linear=image, seconds=seconds, first=first)
    tmp.replace(path)


def _drawer(backend, preset: QualityPreset, target, clamp, supersample: int = 1):
    """(camera, seed) -> RenderResult: one render of ``preset`` (at ``supersample`` times the
    resolution, brought back to it), or renders up to an error target as a build makes them (the
    same seeds)."""
    if target is None:
        return lambda cam, seed: render_at(backend, cam, preset, seed, clamp, supersample)
    return lambda cam, seed: draw_to_target(backend, [cam], preset, seed, target, clamp)[0][0]


REFINE_RATIO = 1.25  # the ladder is refined until its bracket of the level's error is this narrow in samples


def finer_rung(rows: list[Row], backend: str, level: str, counts: Callable[[int], int] | None = None) -> int | None:
    """The samples to ask for in the next rung: between the ladder's last rung short of the plain
    ``level``'s PSNR and its first one reaching it, by the samples they took, the count nearest
    their geometric mean that the backend renders as a count no rung took yet (``counts``: the
    samples a render takes when asked for n, as ``BackendPlugin.sample_counts``; Mitsuba's
    stratified sampler takes the next square). None when the two are within REFINE_RATIO of each
    other, when there is no such bracket, or when no new count lies between them."""
    plain = next((r for r in rows if r.backend == backend and r.setting == level), None)
    rungs = [r for r in rows if r.backend == backend and _rung_samples(r.setting, level)]
    if plain is None:
        return None
    reach = [r.samples for r in rungs if r.psnr >= plain.psnr - 1e-9]
    short = [r.samples for r in rungs if r.psnr < plain.psnr - 1e-9 and (not reach or r.samples < min(reach))]
    if not reach or not short or min(reach) <= max(short) * REFINE_RATIO:
        return None
    lo, hi, taken = max(short), min(reach), {r.samples for r in rungs}
    asked = {_rung_samples(r.setting, level) for r in rungs}  # a renderer that rounds unannounced ends too
    # by the count taken, the largest asked for it (the count itself where the backend renders it)
    new = {t: n for n in range(lo + 1, hi) if n not in asked
           for t in [taken_by(counts, n)] if lo < t < hi and t not in taken}
    if not new:
        return None
    middle = math.sqrt(lo * hi)
    return new[min(new, key=lambda t: abs(math.log(t / middle)))]


def equal_error_speedups(rows: list[Row], level: str = "high") -> dict[str, dict]:
    """Per backend: the fastest setting reaching the plain ``level`` preset's PSNR, and its speed-up."""
    out = {}
    for b in sorted({r.backend for r in rows}):
        rs = [r for r in rows if r.backend == b and r.setting != "reference"]
        plain = next((r for r in rs if r.setting == level), None)
        if plain is None:
            continue
        ok = [r for r in rs if r.psnr >= plain.psnr - 1e-9]
        best = min(ok, key=lambda r: r.seconds)
        out[b] = {"target_psnr": round(plain.psnr, 2), "fastest": best.setting, "seconds": round(best.seconds, 2),
                  "speedup_vs_high" if level == "high" else "speedup": round(plain.seconds / best.seconds, 2)}
    return out


def _finite(x):
    """JSON has no inf/NaN (a reference's PSNR, a saving not measured in this run): null instead."""
    if isinstance(x, float):
        return x if np.isfinite(x) else None
    if isinstance(x, dict):
        return {k: _finite(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_finite(v) for v in x]
    return x


def write_report(rows: list[Row], out: Path, graph: JobGraph, savings: list[Saving] = (), **meta) -> None:
    import json

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out.mkdir(parents=True, exist_ok=True)
    with open(out / "bench.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["backend", "setting", "level", "seconds", "rel_mse", "psnr_db", "ssim", "samples", "image_seconds"])
        for r in rows:
            w.writerow([r.backend, r.setting, r.level, f"{r.seconds:.3f}", f"{r.rel_mse:.4e}", f"{r.psnr:.2f}", f"{r.ssim:.4f}", r.samples,
                        "" if r.image_seconds is None else f"{r.image_seconds:.3f}"])
    equal = equal_error_speedups(rows)
    (out / "bench.json").write_text(json.dumps(_finite({
        "meta": {**meta, "spec": str(graph.spec_path)},
        # per backend: plain 'high' seconds / seconds of the cheapest setting reaching its PSNR
        "equal_error_speedup": {b: e["speedup_vs_high"] for b, e in equal.items()},
        "equal_error": equal,
        # per backend and paper level: the cheapest setting reaching that level's error
        "calibration": {lv: equal_error_speedups(rows, lv) for lv in LEVELS if any(r.setting == lv for r in rows)},
        "rows": [vars(r) for r in rows],
        "savings": [vars(x) for x in savings]}), indent=2, allow_nan=False) + "\n")
    fig, ax = plt.subplots(figsize=(8, 5))
    for b, colour in zip(sorted({r.backend for r in rows}), ("tab:blue", "tab:orange", "tab:green")):
        rs = [r for r in rows if r.backend == b and r.setting != "reference"]
        ax.scatter([r.seconds for r in rs], [r.psnr for r in rs], color=colour, label=b)
        for r in rs:
            ax.annotate(r.setting, (r.seconds, r.psnr), fontsize=7, xytext=(3, 3), textcoords="offset points")
    ax.set_xscale("log")
    ax.set_xlabel("seconds per image (median)")
    ax.set_ylabel("PSNR vs converged reference [dB]")
    ax.set_title(f"time vs error, {meta.get('n_views')} view(s) at scale {meta.get('scale')}")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(out / "bench.png", dpi=90)
    plt.close(fig)
