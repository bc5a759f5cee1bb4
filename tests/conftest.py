from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest


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

