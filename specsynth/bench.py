"""`specsynth bench`: render time against image error, per backend and setting.

For the first N accepted views of a spec, every installed PBR backend renders each quality level
(with/without denoising and adaptive sampling where the backend has them) and a converged
reference (``ref_factor`` x the high preset's samples, independent seed). Error is measured against
the backend's own reference: relMSE on linear radiance, PSNR and SSIM on 8-bit sRGB.
"""

from __future__ import annotations

import csv
import statistics
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .backend_api import PluginNotFound, available_backends, load_backend
from .build import build
from .compiler import JobGraph
from .records import ArrangementRecord, ViewRecord
from .spec import QualityPreset
from .store import Store


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


def settings_for(backend: str, ref_factor: int) -> list[Setting]:
    out = []
    for level in ("low", "medium", "high"):
        out.append(Setting(backend, f"{level}", level, {}))
        if backend == "cycles":
            out.append(Setting(backend, f"{level}+denoise", level, {"denoise": True}))
            out.append(Setting(backend, f"{level}+adaptive", level, {"adaptive_threshold": 0.01}))
        if backend == "mitsuba":
            out.append(Setting(backend, f"{level}+ldsampler", level, {"sampler": "ldsampler"}))
    out.append(Setting(backend, "reference", "high", {"__factor__": ref_factor}, reference=True))
    return out


def rel_mse(x: np.ndarray, ref: np.ndarray) -> float:
    return float(np.mean((x - ref) ** 2 / (ref**2 + 1e-2)))


def psnr8(a: np.ndarray, b: np.ndarray) -> float:
    mse = float(np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2))
    return float("inf") if mse == 0 else 10 * np.log10(255.0**2 / mse)


def ssim8(a: np.ndarray, b: np.ndarray) -> float:
    from skimage.metrics import structural_similarity

    return float(structural_similarity(a, b, channel_axis=2, data_range=255))


def _views(graph: JobGraph, out: Path, n: int):
    """Arrangements and the first n accepted views, built (and cached) in ``out``."""
    build(graph, out, jobs=1, until="view")
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
                return picked
    return picked


def run_bench(graph: JobGraph, out: Path, *, n_views: int = 2, repeats: int = 1, ref_factor: int = 4,
              scale: float = 0.5, backends: list[str] | None = None, console=None) -> list[Row]:
    from .tasks import BuildContext, Worker
    from .writers.images import write_png

    out = Path(out)
    spec = graph.spec
    intr = spec.intrinsics
    small = intr.model_copy(update={
        "width": max(8, round(intr.width * scale)), "height": max(8, round(intr.height * scale)),
        "fx": intr.fx * scale, "fy": intr.fy * scale, "cx": (intr.cx + 0.5) * scale - 0.5, "cy": (intr.cy + 0.5) * scale - 0.5,
    })
    picked = _views(graph, out, n_views)
    if not picked:
        raise RuntimeError("no accepted view to benchmark; widen the camera ranges")
    names = backends or [b for b in available_backends() if b != "photo"]
    rows: list[Row] = []
    for name in names:
        try:
            cls = load_backend(name)
        except PluginNotFound as e:
            if console:
                console.print(f"[yellow]skipping {name}: {e}[/yellow]")
            continue
        base_opts = spec.backend.model_dump() if spec.backend.name == name else {"name": name}
        base_opts = {k: v for k, v in base_opts.items() if k in {"name", "threads", "variant"}}
        worker = Worker(BuildContext(spec=spec.model_copy(update={"intrinsics": small}), spec_dir=graph.spec_path.parent, out=out))
        refs: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        settings = settings_for(name, ref_factor)
        settings = [settings[-1]] + settings[:-1]  # reference first: every other row needs it
        for st in settings:
            opts = dict(base_opts)
            opts.update({k: v for k, v in st.options.items() if not k.startswith("__")})
            preset = spec.quality.model_copy(update={"level": st.level}).resolved()
            if st.reference:
                f = st.options["__factor__"]  # every ray count: backends take samples from their max
                preset = QualityPreset(**{**preset.model_dump(), "aa": preset.aa * f,
                                          "diffuse_rays": preset.diffuse_rays * f, "specular_rays": preset.specular_rays * f})
            backend = cls(type(spec.backend).model_validate(opts) if spec.backend.name == name else opts, threads=0)
            times, errs = [], []
            samples = 0
            for i, (arec, vrec, seed) in enumerate(picked):
                scene = worker.render_scene(arec)
                backend.load(scene)
                cam = worker.camera(vrec.R_w2c, vrec.t_w2c)
                ts = []
                for r in range(repeats if not st.reference else 1):
                    t0 = time.perf_counter()
                    res = backend.render(cam, preset, seed + (7919 if st.reference else 0), clamp=spec.quality.clamp)
                    ts.append(time.perf_counter() - t0)
                times.append(statistics.median(ts))
                samples = int(res.stats.get("samples", res.stats.get("spp", 0)))
                lin = res.linear if res.linear is not None else res.rgb.astype(np.float32) / 255
                if st.reference:
                    refs[i] = (lin, res.rgb)
                    write_png(out / "bench" / f"{name}_ref_{i}.png", res.rgb)
                    continue
                ref_lin, ref_rgb = refs[i]
                errs.append((rel_mse(lin, ref_lin), psnr8(res.rgb, ref_rgb), ssim8(res.rgb, ref_rgb)))
                if i == 0:
                    write_png(out / "bench" / f"{name}_{st.label}_{i}.png", res.rgb)
            backend.close()
            if st.reference:
                rows.append(Row(name, st.label, st.level, float(np.mean(times)), 0.0, float("inf"), 1.0, samples))
            else:
                e = np.mean(np.asarray(errs), axis=0)
                rows.append(Row(name, st.label, st.level, float(np.mean(times)), float(e[0]), float(e[1]), float(e[2]), samples))
            if console:
                r = rows[-1]
                console.print(f"{name:8s} {r.setting:18s} {r.seconds:8.2f} s  PSNR {r.psnr:6.2f} dB  relMSE {r.rel_mse:.2e}")
        worker.close()
    write_report(rows, out, graph, n_views=len(picked), scale=scale, ref_factor=ref_factor)
    return rows


def equal_error_speedups(rows: list[Row]) -> dict[str, dict]:
    """Per backend: the fastest setting reaching the plain 'high' preset's PSNR, and its speed-up."""
    out = {}
    for b in sorted({r.backend for r in rows}):
        rs = [r for r in rows if r.backend == b and r.setting != "reference"]
        high = next((r for r in rs if r.setting == "high"), None)
        if high is None:
            continue
        ok = [r for r in rs if r.psnr >= high.psnr - 1e-9]
        best = min(ok, key=lambda r: r.seconds)
        out[b] = {"target_psnr": round(high.psnr, 2), "fastest": best.setting, "seconds": round(best.seconds, 2),
                  "speedup_vs_high": round(high.seconds / best.seconds, 2)}
    return out


def write_report(rows: list[Row], out: Path, graph: JobGraph, **meta) -> None:
    import json

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out.mkdir(parents=True, exist_ok=True)
    with open(out / "bench.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["backend", "setting", "level", "seconds", "rel_mse", "psnr_db", "ssim", "samples"])
        for r in rows:
            w.writerow([r.backend, r.setting, r.level, f"{r.seconds:.3f}", f"{r.rel_mse:.4e}", f"{r.psnr:.2f}", f"{r.ssim:.4f}", r.samples])
    (out / "bench.json").write_text(json.dumps({"meta": {**meta, "spec": str(graph.spec_path)},
                                                "equal_error": equal_error_speedups(rows)}, indent=2) + "\n")
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
