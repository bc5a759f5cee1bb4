from __future__ import annotations

import functools
import importlib.machinery
import json
import os
import sys
from pathlib import Path

import numpy as np
import pytest

os.environ.setdefault("PYOPENGL_PLATFORM", "egl")

# --------------------------------------------------------------------------- the slow marker
# `slow` means "renders with a PBR backend" (the default suite runs -m "not slow"): a test without
# the mark that renders with Cycles or Mitsuba in this process fails. The backends' classes get a
# counting render() when their modules are imported.
PBR_BACKENDS = {"specsynth_cycles.backend": "CyclesBackend", "specsynth_mitsuba.backend": "MitsubaBackend"}
_PBR_RENDERS: list[str] = []
_WATCHING = [False]


def _count_renders(cls) -> None:
    render = cls.render

    @functools.wraps(render)
    def counted(self, *args, **kwargs):
        if _WATCHING[0]:
            _PBR_RENDERS.append(cls.__name__)
        return render(self, *args, **kwargs)

    cls.render = counted


class _CountPbrRenders:
    """A meta path finder that only adds the counting render() to a PBR backend once it is loaded."""

    def find_spec(self, name, path, target=None):
        if name not in PBR_BACKENDS:
            return None
        spec = importlib.machinery.PathFinder.find_spec(name, path)
        if spec is None or spec.loader is None:
            return None
        exec_module = spec.loader.exec_module

        def exec_and_count(module):
            exec_module(module)
            _count_renders(getattr(module, PBR_BACKENDS[name]))

        spec.loader.exec_module = exec_and_count
        return spec


for _name, _cls in PBR_BACKENDS.items():  # already imported (by a plugin listing, say)
    if _name in sys.modules:
        _count_renders(getattr(sys.modules[_name], _cls))
sys.meta_path.insert(0, _CountPbrRenders())


@pytest.fixture(autouse=True)
def _pbr_renders_are_marked_slow(request):
    slow = request.node.get_closest_marker("slow") is not None
    _PBR_RENDERS.clear()
    _WATCHING[0] = not slow
    yield
    _WATCHING[0] = False
    if _PBR_RENDERS:
        pytest.fail(f"{request.node.nodeid} rendered {len(_PBR_RENDERS)} image(s) with {sorted(set(_PBR_RENDERS))} "
                    "but is not marked slow", pytrace=False)


def write_bop_models(folder: Path, n: int, seed: int = 0) -> Path:
    """A BOP models folder of n coloured boxes (ASCII PLY in millimetres) with models_info.json."""
    folder.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    info = {}
    corners = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], dtype=float)
    faces = [(0, 1, 3), (0, 3, 2), (4, 6, 7), (4, 7, 5), (0, 4, 5), (0, 5, 1),
             (2, 3, 7), (2, 7, 6), (0, 2, 6), (0, 6, 4), (1, 5, 7), (1, 7, 3)]
    for obj in range(1, n + 1):
        half = rng.uniform(20, 60, size=3)  # mm
        v = corners * half
        c = rng.integers(40, 255, size=3)
        lines = ["ply", "format ascii 1.0", f"element vertex {len(v)}", "property float x", "property float y",
                 "property float z", "property uchar red", "property uchar green", "property uchar blue",
                 f"element face {len(faces)}", "property list uchar int vertex_indices", "end_header"]
        lines += [f"{a:.3f} {b:.3f} {d:.3f} {c[0]} {c[1]} {c[2]}" for a, b, d in v]
        lines += [f"3 {i} {j} {k}" for i, j, k in faces]
        (folder / f"obj_{obj:06d}.ply").write_text("\n".join(lines) + "\n")
        info[str(obj)] = {"diameter": float(2 * np.linalg.norm(half)), "min_x": -half[0], "min_y": -half[1],
                          "min_z": -half[2], "size_x": 2 * half[0], "size_y": 2 * half[1], "size_z": 2 * half[2]}
    (folder / "models_info.json").write_text(json.dumps(info, indent=2))
    return folder


@pytest.fixture(scope="session")
def lm_models(tmp_path_factory) -> Path:
    return write_bop_models(tmp_path_factory.mktemp("lm") / "models", 15)


@pytest.fixture(scope="session")
def ruapc_models(tmp_path_factory) -> Path:
    return write_bop_models(tmp_path_factory.mktemp("ruapc") / "models", 14, seed=1)


@pytest.fixture(scope="module")
def mitsuba_backend():
    """One warm Mitsuba backend per test module (variant probe and kernel cache are per process)."""
    pytest.importorskip("mitsuba")
    from specsynth_mitsuba.backend import MitsubaBackend

    b = MitsubaBackend({"variant": "auto"}, threads=2)
    yield b
    b.close()
