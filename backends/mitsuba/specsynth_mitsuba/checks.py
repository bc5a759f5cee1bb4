"""``specsynth doctor``'s checks of the Mitsuba backend: Mitsuba imports, which variants it was
built with, and which of them run here (each JIT variant tried in a child process, as a build
does: a too-old libLLVM kills the process instead of raising)."""

from __future__ import annotations

import json
import subprocess
import sys

from specsynth.plugins import Check

from .variant import _gpu_plausible, probe

MARK = "specsynth-doctor: "
_LIST = f"import json, mitsuba as mi; print({MARK!r} + json.dumps([mi.__version__, mi.variants()]))"
FIX = "pip install 'mitsuba>=3.6,<4', or pip install --force-reinstall specsynth-mitsuba"
LLVM_FIX = ("apt-get install libllvm19 (Dr.Jit's LLVM back end; without it Mitsuba renders with "
            "scalar_rgb, many times slower)")


def checks(timeout: float = 300.0) -> list[Check]:
    try:
        r = subprocess.run([sys.executable, "-c", _LIST], capture_output=True, text=True, timeout=timeout)
    except subprocess.TimeoutExpired:
        return [Check("mitsuba", False, f"importing mitsuba took over {timeout:.0f} s", FIX)]
    found = [line[len(MARK):] for line in r.stdout.splitlines() if line.startswith(MARK)]
    if r.returncode != 0 or not found:
        last = (r.stderr or r.stdout).strip().splitlines()[-1:] or [f"exit status {r.returncode}"]
        return [Check("mitsuba", False, f"mitsuba does not import: {last[0][:200]}", FIX)]
    version, variants = json.loads(found[-1])
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
