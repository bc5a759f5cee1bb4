"""``specsynth doctor``'s checks of the Mitsuba backend: Mitsuba imports, which variants it was
built with, and which of them run here (each JIT variant tried in a child process, as a build
does: a too-old libLLVM kills the process instead of raising)."""

from __future__ import annotations

import json

from specsynth.plugins import PROBE_MARK, Check, probe_in_child

from .variant import _gpu_plausible, probe

_LIST = f"import json, mitsuba as mi; print({PROBE_MARK!r} + json.dumps([mi.__version__, mi.variants()]))"
FIX = "pip install 'mitsuba>=3.6,<4', or pip install --force-reinstall specsynth-mitsuba"
LLVM_FIX = ("apt-get install libllvm19 (Dr.Jit's LLVM back end; without it Mitsuba renders with "
            "scalar_rgb, many times slower)")


def checks(timeout: float = 300.0) -> list[Check]:
    answer, why = probe_in_child(_LIST, timeout)
    if answer is None:
        return [Check("mitsuba", False, f"mitsuba does not import: {why}", FIX)]
    version, variants = json.loads(answer)
    rgb = [v for v in variants if v.endswith("_rgb")]
    others = f" (and {len(variants) - len(rgb)} spectral, mono or polarised)" if len(variants) > len(rgb) else ""
    out = [Check("mitsuba", True, f"Mitsuba {version}; variants: {', '.join(rgb)}{others}")]
    if "llvm_ad_rgb" in variants:
        ok, why = probe("llvm_ad_rgb", timeout=timeout)
        out.append(Check("mitsuba llvm_ad_rgb", ok, "renders (the CPU variant builds use)" if ok else
                         f"does not run: {why}", "" if ok else LLVM_FIX, required=False))
    else:
        out.append(Check("mitsuba llvm_ad_rgb", False, "not in this Mitsuba build", FIX, required=False))
    if "cuda_ad_rgb" in variants:
        if _gpu_plausible():
            ok, why = probe("cuda_ad_rgb", timeout=timeout)
            out.append(Check("mitsuba cuda_ad_rgb", None, "renders on the GPU" if ok else f"does not run: {why}"))
        else:
            out.append(Check("mitsuba cuda_ad_rgb", None, "no NVIDIA driver: no GPU variant (not needed)"))
    return out
