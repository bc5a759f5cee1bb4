"""Plugins: render backends, executors and outputs, found through entry points (fsspec-style).

A backend is a distribution that registers a :class:`BackendPlugin` in the ``specsynth.backends``
entry-point group. The plugin object is cheap to import (pydantic options and metadata only): the
spec is validated with its options model and the compiler keys renders with its distributions'
versions, all without importing the renderer. The renderer class is imported only where a render
happens, through :meth:`BackendPlugin.load_class`.

The core names no backend: everything it needs to know about one is in its plugin object.

Outputs are plugins too: per-view products (``specsynth.products``: a depth map, masks, another
eye) and dataset writers (``specsynth.writers``: BOP, COCO, ...), each an object of
:mod:`specsynth.output_api`. Their names are the spec's ``outputs.<name>`` switches; this module
only finds them and reports what is missing (``output_switches``).
"""

from __future__ import annotations

import importlib
import math
from dataclasses import dataclass, field
from functools import partial
from importlib import metadata
from typing import Any, Callable

BACKEND_GROUP = "specsynth.backends"
EXECUTOR_GROUP = "specsynth.executors"
PRODUCT_GROUP = "specsynth.products"
WRITER_GROUP = "specsynth.writers"
OUTPUT_GROUPS = {"product": PRODUCT_GROUP, "writer": WRITER_GROUP}


class PluginNotFound(RuntimeError):
    pass


@dataclass(frozen=True)
class Capabilities:
    """What a backend can do; the core and ``validate`` read this instead of backend names."""

    draws_scene: bool = True  # False: draws only the dataset objects (the photo baseline)
    denoise: bool = False  # has a denoiser; False also for renderers without sampling noise
    gpu: bool = False
    # Monte Carlo noise that falls with samples, so that `quality.control: error` applies: the
    # backend renders ``quality``'s samples when its options set none, and independent seeds give
    # independent images of the same view.
    sampling_noise: bool = False
    # ``render(..., sample_offset=k)`` renders the samples k to k + n of the sequence its seed
    # starts: renders of consecutive ranges, averaged with weights by their samples, are one render
    # of all of them. An error target then extends each of an image's two halves instead of
    # averaging independent renders (a quasi-random sampler keeps converging faster than 1 / N).
    continues_samples: bool = False
    depth_of_field: bool = False  # renders CameraIR.aperture / focus_distance (a thin lens)
    motion_blur: bool = False  # renders CameraIR.motion (the camera moving during the exposure)
    material_channels: frozenset[str] = frozenset({"base_color"})
    quality: str = ""  # one line: how the paper's presets map onto this renderer


@dataclass(frozen=True)
class Check:
    """One line of ``specsynth doctor``: a component, whether it works, and the fix when it does not.

    ``ok`` None: information only (a GPU that is not there). ``required`` False: the component
    works less well without the fix (a slower renderer) but nothing fails."""

    component: str
    ok: bool | None
    detail: str
    fix: str = ""
    required: bool = True


PROBE_MARK = "specsynth-doctor: "  # a probe's answer line, told apart from whatever the library prints


def probe_in_child(code: str, timeout: float, env: dict | None = None) -> tuple[str | None, str]:
    """Run ``code`` in a fresh interpreter (what it imports may crash or print on the terminal) and
    return (its last ``PROBE_MARK`` line without the mark, "") or (None, why it gave none)."""
    import subprocess
    import sys

    try:
        r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=timeout, env=env)
    except subprocess.TimeoutExpired:
        return None, f"no answer after {timeout:.0f} s"
    found = [line[len(PROBE_MARK):] for line in r.stdout.splitlines() if line.startswith(PROBE_MARK)]
    if r.returncode != 0 or not found:
        last = (r.stderr or r.stdout).strip().splitlines()[-1:] or [f"exit status {r.returncode}"]
        return None, last[0][:200]
    return found[-1], ""


@dataclass(frozen=True)
class BackendPlugin:
    """What the core reads about a backend to validate, key, schedule and run a build, and no more.
    (What `specsynth bench` tries beyond the quality levels is the bench's: a ``BENCH`` in the
    optional ``bench`` module of the backend's package, read by ``specsynth.run.bench``.)"""

    name: str
    options: type  # a subclass of specsynth.spec.models.BackendOptions with ``name: Literal[<name>]``
    backend: str  # "module:Class" of the renderer, imported only where a render happens
    capabilities: Capabilities = Capabilities()
    distributions: tuple[str, ...] = ()  # whose versions change the pixels (read from metadata)
    revision: int = 1  # bump when the plugin's own code changes pixels for the same inputs
    # Estimated seconds per render, fixed + per sample: `specsynth plan`'s estimate and how many
    # renders a build puts in one task.
    cost: tuple[float, float] = (1.0, 0.1)
    install_hint: str = ""  # what to install when ``backend`` cannot be imported
    # Quality levels low/medium/high: option values that reach (at least) the paper preset's image
    # error for less (measured by `specsynth bench --ladder`), e.g. {"high": {"samples": 16,
    # "denoise": True}}. Applied unless the spec sets the option itself; paper_* levels never.
    calibrated: dict[str, dict[str, Any]] = field(default_factory=dict)
    # Calibrated options that change how a render draws its samples (Mitsuba's emitter_sampling):
    # under an error target the image's own renders measure its target, the paper preset's
    # error, so they keep the spec's value of these, as the preset renders.
    sampling_options: tuple[str, ...] = ()
    # "module:function" -> list[Check]: the plugin's own installation check for `specsynth doctor`
    # (whether its renderer imports, its version, what the machine offers it). Imported only then.
    checks: str = ""
    # `specsynth init` writes the installed backend with the lowest rank into a starter spec.
    default_rank: int = 100
    # (options, n) -> the samples per pixel a render takes when asked for n (at least n, rising
    # with n), when the renderer rounds a count: Mitsuba's stratified sampler renders the next
    # square, so an error target that planned with n carried an image past quality.max_samples
    # (242 against 225). None: every count as asked. Cheap: no renderer is imported.
    sample_counts: Callable[[Any, int], int] | None = None
    # The slowest fall of one render's variance with its samples that an error target assumes
    # when it extrapolates from a few samples to the preset's (``samples^-rate``; a measured rate
    # below it is held at it): a quasi-random sampler whose error falls faster towards the
    # preset's samples than over its first ones, measured against references (``specsynth bench
    # --ref-parts``), says so here. 1: independent samples.
    sampler_rate: float = 1.0

    def __post_init__(self) -> None:
        from .model.error import MAX_RATE

        if not 1.0 <= self.sampler_rate <= MAX_RATE:
            raise ValueError(f"backend plugin {self.name!r}: sampler_rate must be within [1, {MAX_RATE}], "
                             f"got {self.sampler_rate}")

    def options_for(self, options: Any, quality: Any) -> Any:
        """The spec's options with the level's calibration filled in where the spec is silent.

        A calibration's few samples reach the paper's error only through its denoiser: a spec
        that turns denoising off gets the paper preset's own samples instead of a noisy image.
        Under ``quality.control: error`` every render takes the samples the error target asks for
        (the preset's, set per render): no ``samples`` here, the spec's own start the image
        (``error_target``), and no supersampling. A calibrated count and its ``supersample`` are
        one setting (``calibration``)."""
        update = {k: v for k, v in self.calibration(options, quality).items() if k not in options.model_fields_set}
        if getattr(quality, "control", "samples") == "error" and options.samples is not None:
            update["samples"] = None
        return options.model_copy(update=update) if update else options

    def calibration(self, options: Any, quality: Any) -> dict[str, Any]:
        """The level's calibrated option values as they apply to a spec's ``options``: none when the
        spec turns off the denoiser they rely on; under an error target without ``samples``,
        ``supersample`` and the plugin's ``sampling_options``; without ``supersample`` when the
        spec sets its own count (at its own resolution); and with as many samples as the
        calibration traces per pixel of the image when the spec sets its own ``supersample``
        (Cycles' 4 at 2x are 16 at 1x, 2 at 3x)."""
        cal = dict(self.calibrated.get(quality.paper_level) or {}) if quality.calibrated else {}
        mine = options.model_fields_set
        if cal.get("denoise") and "denoise" in mine and not options.denoise:
            return {}
        if getattr(quality, "control", "samples") == "error":
            # an error target renders an image at its own resolution, with the samples its target
            # asks for, drawn as the preset draws them (``sampling_options``)
            drawn = ("samples", "supersample", *self.sampling_options)
            return {k: v for k, v in cal.items() if k not in drawn}
        if "samples" in mine:
            cal.pop("supersample", None)
        elif "supersample" in mine and "samples" in cal:
            traced = traced_samples(cal)
            cal.pop("supersample", None)
            cal["samples"] = max(1, math.ceil(traced / options.supersample**2))
        return cal

    def error_target(self, options: Any, quality: Any):
        """``quality.control: error``: the paper preset's samples (whose error is the target), the
        samples per render of the first pair (the spec's own ``options``' samples, else half,
        rounded up, of the samples a calibrated render traces per pixel of the image, its count
        times the F^2 pixels of its ``supersample``: the first pair costs what one calibrated
        render does, each as the renderer takes it) and the image's budget:
        ``quality.max_samples``, else ``BUDGET_FACTOR`` times the preset's samples, spent past
        those only by an image not at its target within them (``ErrorTarget.soft_samples``).
        ``quality.max_samples`` is a bound, never raised: the first pair is made smaller to fit it,
        and a budget no pair of the renderer's counts fits is a ValueError (``validate`` reports
        it)."""
        from .model.error import BUDGET_FACTOR, ErrorTarget, per_render, taken

        paper = quality.resolved().samples
        cal = self.calibrated.get(quality.paper_level, {}) if quality.calibrated else {}
        counts = partial(self.sample_counts, options) if self.sample_counts is not None else None
        want = options.samples or math.ceil(traced_samples(cal, default=2) / 2)
        budget = quality.max_samples or max(BUDGET_FACTOR * paper, 2 * taken(counts, want))
        soft = None if quality.max_samples else paper  # the default budget: the preset's samples first
        start = per_render(counts, want, budget)
        if start < 1:
            raise ValueError(f"quality.max_samples {budget} fits no pair of renders: backend {self.name!r} renders "
                             f"at least {taken(counts, 1)} samples per pixel per render")
        return ErrorTarget(paper_samples=paper, start_samples=start, max_samples=budget, counts=counts,
                           continues=self.capabilities.continues_samples, soft_samples=soft,
                           min_rate=self.sampler_rate)

    def load_class(self) -> type:
        mod, _, attr = self.backend.partition(":")
        try:
            return getattr(importlib.import_module(mod), attr)
        except ImportError as e:
            hint = self.install_hint or f"install the package that provides the {self.name!r} backend"
            raise PluginNotFound(f"backend {self.name!r} cannot be imported ({e}); {hint}") from e

    def run_checks(self) -> list[Check]:
        """The plugin's installation checks (``checks``); one line when it has none or they fail."""
        if not self.checks:
            return [Check(self.name, None, "installed; the plugin has no self-check")]
        mod, _, attr = self.checks.partition(":")
        try:
            found = getattr(importlib.import_module(mod), attr)()
        except Exception as e:  # noqa: BLE001 - a broken plugin is a doctor's finding, not its crash
            return [Check(self.name, False, f"its check failed: {type(e).__name__}: {e}",
                          self.install_hint or f"reinstall the package that provides {self.name!r}")]
        return list(found)

    def fingerprint(self) -> str:
        """The plugin's name and the versions of what it renders with; part of every render key."""
        dist = _plugin_distribution(BACKEND_GROUP, self.name)
        parts = [f"{d} {dist_version(d)}" for d in (dist, *self.distributions) if d]
        parts.append(f"specsynth {dist_version('specsynth')}")
        if self.revision > 1:
            parts.append(f"backend rev {self.revision}")
        return f"{self.name} ({'; '.join(parts)})"


def traced_samples(calibrated: dict[str, Any], default: int = 1) -> int:
    """Samples per pixel of the image one render of a calibration traces: its ``samples`` (else
    ``default``) times the F^2 pixels of a ``supersample`` of F."""
    return int(calibrated.get("samples", default)) * int(calibrated.get("supersample", 1)) ** 2


def dist_version(name: str) -> str:
    """An installed distribution's version, read from its metadata (nothing is imported)."""
    try:
        return metadata.version(name)
    except metadata.PackageNotFoundError:
        return "not-installed"


def _plugin_distribution(group: str, name: str) -> str | None:
    for ep in metadata.entry_points(group=group):
        if ep.name == name and ep.dist is not None:
            return ep.dist.name
    return None


def _kind(group: str) -> str:
    return group.split(".")[-1][:-1]


def _load_entry_point(group: str, name: str) -> Any:
    if ":" in name:
        # "package.module:attribute": a plugin used without installing it (tests, experiments).
        mod, _, attr = name.partition(":")
        try:
            return getattr(importlib.import_module(mod), attr)
        except (ImportError, AttributeError) as e:
            raise PluginNotFound(f"cannot load {name!r}: {e}") from e
    eps = metadata.entry_points(group=group)
    matches = [ep for ep in eps if ep.name == name]
    if not matches:
        known = sorted(ep.name for ep in eps)
        raise PluginNotFound(
            f"no {_kind(group)} named {name!r} is installed (installed: {', '.join(known) or 'none'}); "
            f"install the package that provides it, e.g. pip install specsynth-{name} "
            f"(in this repository: pip install -e backends/{name})"
        )
    try:
        return matches[0].load()
    except ImportError as e:
        dist = matches[0].dist.name if matches[0].dist is not None else f"the package that provides {name!r}"
        raise PluginNotFound(f"{_kind(group)} {name!r} cannot be imported ({e}); reinstall {dist}") from e


def backend_plugin(name: str) -> BackendPlugin:
    found = _load_entry_point(BACKEND_GROUP, name)
    if not isinstance(found, BackendPlugin):
        raise PluginNotFound(f"{name!r} is not a specsynth BackendPlugin (got {type(found).__name__})")
    return found


def load_backend(name: str) -> type:
    """The renderer class of backend ``name`` (imports the renderer)."""
    return backend_plugin(name).load_class()


def load_executor(name: str) -> type:
    return _load_entry_point(EXECUTOR_GROUP, name)


def available_backends() -> list[str]:
    return sorted(ep.name for ep in metadata.entry_points(group=BACKEND_GROUP))


def installed_backend_plugins() -> list[BackendPlugin]:
    """Every installed plugin that loads (a broken one is skipped, not fatal to listing)."""
    out = []
    for name in available_backends():
        try:
            out.append(backend_plugin(name))
        except PluginNotFound:
            continue
    return out


# ---------------------------------------------------------------------- outputs


@dataclass(frozen=True)
class OutputSwitch:
    """What the spec needs to know of one installed output: its ``outputs.<name>`` switch."""

    name: str
    kind: str  # "product" (written by every render job) or "writer" (a dataset format, by the merge)
    default: bool
    description: str
    needs: tuple[str, ...] = ()  # outputs that must be on with it (a writer reading another's files)
    switch: bool = True  # False: no switch; the product decides from the render's inputs (``active``)


def output_plugins(kind: str) -> tuple[dict[str, Any], dict[str, str]]:
    """The installed outputs of ``kind`` by name, and those whose entry point does not load (name
    -> why, with what to reinstall): a broken plugin is reported where it is named, never fatal
    to the others."""
    group = OUTPUT_GROUPS[kind]
    found: dict[str, Any] = {}
    broken: dict[str, str] = {}
    for ep in sorted(metadata.entry_points(group=group), key=lambda e: e.name):
        if ep.name in found or ep.name in broken:
            continue  # the first distribution on the path wins, as for imports
        try:
            obj = ep.load()
        except (ImportError, AttributeError) as e:
            dist = ep.dist.name if ep.dist is not None else f"the package that provides {ep.name!r}"
            broken[ep.name] = f"{_kind(group)} {ep.name!r} cannot be imported ({e}); reinstall {dist}"
            continue
        if getattr(obj, "name", None) != ep.name:
            broken[ep.name] = f"entry point {ep.name!r} of {group} gives an object named {getattr(obj, 'name', None)!r}"
            continue
        found[ep.name] = obj
    return found, broken


def output_switches() -> tuple[OutputSwitch, ...]:
    """Every installed output, products then writers, each sorted by name."""
    out = []
    for kind in OUTPUT_GROUPS:
        for name, obj in output_plugins(kind)[0].items():
            out.append(OutputSwitch(name, kind, bool(obj.default), " ".join(str(obj.description).split()),
                                    tuple(getattr(obj, "needs", ())), bool(getattr(obj, "switch", True))))
    return tuple(out)


def unknown_output(name: str) -> str:
    """Why ``outputs.<name>`` is not a switch: a broken plugin (what to reinstall), or no such
    output (the known ones, a close name, and what to install for a third-party one)."""
    import difflib

    for kind in OUTPUT_GROUPS:
        broken = output_plugins(kind)[1]
        if name in broken:
            return broken[name]
    known = sorted(s.name for s in output_switches() if s.switch)
    if not known:
        return ("no outputs are installed: specsynth's own entry points are missing (reinstall it: "
                "pip install -e . in its repository)")
    close = difflib.get_close_matches(name, known, n=1)
    hint = f"did you mean {close[0]!r}? " if close else ""
    return (f"unknown output {name!r}: {hint}known are {', '.join(known)}; an output from another package "
            f"needs that package installed (its entry point in {PRODUCT_GROUP} or {WRITER_GROUP})")


def output_fingerprint(obj: Any, kind: str) -> str:
    """An output's name, its distribution's version and revision: part of the keys it changes."""
    dist = _plugin_distribution(OUTPUT_GROUPS[kind], obj.name)
    parts = [f"{dist} {dist_version(dist)}"] if dist else []
    revision = int(getattr(obj, "revision", 1))
    if revision > 1:
        parts.append(f"rev {revision}")
    return f"{obj.name} ({'; '.join(parts)})" if parts else obj.name
