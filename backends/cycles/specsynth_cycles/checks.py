"""``specsynth doctor``'s checks of the Cycles backend: bpy imports, its Blender version, and the
GPU devices Cycles finds.

Run in a child process: importing bpy takes seconds and its device enumeration prints driver
probes ('WARNING CUEW initialization failed' where there is no CUDA) straight to the terminal.
"""

from __future__ import annotations

import json

from specsynth.plugins import PROBE_MARK, Check, dist_version, probe_in_child

_PROBE = f"""
import json
import bpy

out = {{"blender": bpy.app.version_string, "devices": []}}
prefs = bpy.context.preferences.addons["cycles"].preferences
for kind in ("OPTIX", "CUDA", "HIP", "ONEAPI", "METAL"):
    try:
        prefs.compute_device_type = kind
    except TypeError:  # not built into this Blender
        continue
    prefs.get_devices()
    out["devices"] += [[kind, d.name] for d in prefs.devices if d.type == kind]
print({PROBE_MARK!r} + json.dumps(out))
"""

FIX = "pip install bpy==5.0.1 (Python 3.11 only), or pip install --force-reinstall specsynth-cycles"


def checks(timeout: float = 300.0) -> list[Check]:
    answer, why = probe_in_child(_PROBE, timeout)
    if answer is None:
        return [Check("cycles (bpy)", False, f"bpy does not import: {why}", FIX)]
    info = json.loads(answer)
    gpus = [f"{name} ({kind})" for kind, name in info["devices"]]
    return [
        Check("cycles (bpy)", True, f"Blender {info['blender']} (bpy {dist_version('bpy')})"),
        Check("GPU devices", None,
              f"Cycles finds {', '.join(gpus)}; render on it with backend.device: auto" if gpus else
              "none found: Cycles renders on the CPU (backend.device: cpu, the default, gives the same "
              "pixels on every machine)"),
    ]
