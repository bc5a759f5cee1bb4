"""The plugin boundary: backends own their options, the core names none, a third-party plugin works."""

from __future__ import annotations

import ast
import json
import re
import subprocess
import sys
import tokenize
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from specsynth.plan.compiler import compile_spec
from specsynth.plugins import available_backends, backend_plugin
from specsynth.run.build import build
from specsynth.spec.models import BackendOptions, json_schema
from specsynth.spec.yamlio import SpecError, load_spec

ROOT = Path(__file__).resolve().parents[1]
SPEC = """\
name: plug
seed: 3
intrinsics: {width: 80, height: 60, fx: 72.0, fy: 72.0, cx: 39.5, cy: 29.5}
objects:
  builtin: [duck, mug]
scenes:
  - name: room
arrangements: {count: 1}
cameras: {per_arrangement: 2, distance: [0.4, 0.6]}
backend:
  name: cycles
  denoise: true
outputs: {image_format: png, depth_scale: 0.25}
"""


@pytest.fixture
def spec_file(tmp_path):
    f = tmp_path / "plug.yaml"
    f.write_text(SPEC)
    return f


def _flat():
    from importlib import metadata

    try:
        metadata.distribution("specsynth-flat")
    except metadata.PackageNotFoundError:
        pytest.skip("the example plugin is not installed (make install installs it)")
    return backend_plugin("flat")  # installed: it must load


def test_core_names_no_backend():
    """No identifier or non-docstring string in the core names a built-in backend or its renderer.
    (library/hdris.py knows where the bpy wheel keeps its HDRIs: an asset source, not a renderer.)"""
    pat = re.compile(r"\b(cycles|mitsuba|photo|specsynth_(cycles|mitsuba|photo|flat))\b", re.I)
    found = []
    for p in sorted((ROOT / "specsynth").rglob("*.py")):
        if p.parts[-2:] == ("library", "hdris.py"):
            continue
        with open(p) as f:
            toks = [t for t in tokenize.generate_tokens(f.readline)
                    if t.type not in (tokenize.NL, tokenize.NEWLINE, tokenize.INDENT, tokenize.DEDENT, tokenize.COMMENT)]
        for i, t in enumerate(toks):
            docstring = t.type == tokenize.STRING and (i == 0 or toks[i - 1].string == ":")
            if t.type in (tokenize.NAME, tokenize.STRING) and not docstring and pat.search(t.string):
                found.append(f"{p.relative_to(ROOT)}:{t.start[0]}: {t.string[:60]}")
    assert not found, "\n".join(found)


def _backend_packages() -> set[str]:
    """The packages of the backends in backends/ and of every installed backend plugin, but the
    example ``flat``: the core's tests use that one (and the conformance suite) for "a backend"."""
    from importlib import metadata

    found = {p.parent.name for p in ROOT.glob("backends/*/*/__init__.py")}
    found |= {ep.module.split(".")[0] for ep in metadata.entry_points(group="specsynth.backends")}
    return found - {"specsynth_flat"}


def _imported(source: str) -> set[str]:
    """The top-level modules a file imports: its import statements, importorskip/import_module
    calls, and the import lines of its strings (code it runs in a child process)."""
    out: set[str] = set()
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            out |= {a.name.split(".")[0] for a in node.names}
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            out.add(node.module.split(".")[0])
        elif (isinstance(node, ast.Call) and getattr(node.func, "attr", getattr(node.func, "id", None))
              in ("importorskip", "import_module", "__import__") and node.args
              and isinstance(node.args[0], ast.Constant) and isinstance(node.args[0].value, str)):
            out.add(node.args[0].value.split(".")[0])
        elif isinstance(node, ast.Constant) and isinstance(node.value, str):
            for m in re.finditer(r"(?:^|;)\s*(?:from\s+([\w.]+)\s+import\b|import\s+([\w., ]+))", node.value, re.M):
                names = [m[1]] if m[1] else [n.split()[0] for n in m[2].split(",") if n.strip()]
                out |= {n.split(".")[0] for n in names}
    return out


def test_core_tests_import_no_backend():
    """Each backend's tests live in backends/<name>/tests; the core's tests reach a backend only by
    its name (load_backend, a spec's backend.name), the example flat plugin or the conformance suite."""
    backends = _backend_packages()
    assert {"specsynth_cycles", "specsynth_mitsuba", "specsynth_photo"} <= backends
    found = [f"{p.relative_to(ROOT)}: {sorted(_imported(p.read_text()) & backends)}"
             for p in sorted((ROOT / "tests").rglob("*.py")) if _imported(p.read_text()) & backends]
    assert not found, "\n".join(found)


def test_the_import_check_finds_every_form():
    forms = ["import some_backend.backend", "from some_backend.backend import PhotoBackend",
             "import numpy as np, some_backend", "pytest.importorskip('some_backend')",
             "importlib.import_module('some_backend.options')",
             "code = 'import json\\nfrom some_backend import PLUGIN\\n'",
             "subprocess.run([sys.executable, '-c', 'import os; import some_backend'])"]
    for form in forms:
        assert "some_backend" in _imported(form), form
    assert _imported("from specsynth.plugins import load_backend\nload_backend('photo')") == {"specsynth"}


def test_every_installed_plugin_owns_its_options():
    names = available_backends()
    assert {"cycles", "mitsuba", "photo"} <= set(names)
    for name in names:
        p = backend_plugin(name)
        assert issubclass(p.options, BackendOptions) and p.options.model_validate({"name": name}).name == name
    # Reading every plugin and validating a spec with each imports no renderer (a fresh process:
    # this one may have rendered already).
    code = ("import sys\nfrom specsynth.plugins import available_backends, backend_plugin\n"
            "for n in available_backends(): backend_plugin(n).options.model_validate({'name': n})\n"
            "print(sorted({'bpy', 'mitsuba', 'drjit', 'pyrender', 'OpenGL'} & set(sys.modules)))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"


def test_schema_has_every_installed_plugin():
    schema = json_schema()
    refs = {r["$ref"].rsplit("/", 1)[-1] for r in schema["properties"]["backend"]["oneOf"]}
    assert refs == {backend_plugin(n).options.__name__ for n in available_backends()}
    assert "light_path_budget" in schema["$defs"]["CyclesOptions"]["properties"]
    committed = json.loads((ROOT / "schemas" / "dataset-spec.schema.json").read_text())
    assert {"CyclesOptions", "MitsubaOptions", "PhotoOptions"} <= set(committed["$defs"])


@pytest.mark.parametrize("name", ["cycles", "mitsuba", "photo", "flat"])
def test_swapping_only_the_name_validates(spec_file, name):
    """The demo's ``denoise: true`` is a shared option: ``--set backend.name=X`` works for every backend."""
    if name == "flat":
        _flat()
    loaded = load_spec(spec_file, [f"backend.name={name}"])
    assert loaded.spec.backend.name == name and loaded.spec.backend.denoise is True
    assert type(loaded.spec.backend) is backend_plugin(name).options


def test_unknown_option_is_located_and_names_the_plugin(spec_file):
    spec_file.write_text(SPEC.replace("  denoise: true\n", "  denoise: true\n  sampler: stratified\n"))
    with pytest.raises(SpecError) as e:
        load_spec(spec_file)
    (pr,) = e.value.problems
    assert (pr.file, pr.line, pr.path) == (str(spec_file), 13, "backend.sampler")
    assert "unknown field" in pr.message and "backend plugin 'cycles'" in pr.message and "light_path_budget" in pr.message


def test_missing_plugin_says_what_to_install(spec_file):
    with pytest.raises(SpecError) as e:
        load_spec(spec_file, ["backend.name=nosuch"])
    msg = str(e.value)
    assert "no backend named 'nosuch' is installed" in msg and "pip install" in msg


def test_example_flat_plugin_builds_and_validates_its_option(spec_file, tmp_path):
    _flat()
    bad = tmp_path / "bad.yaml"
    bad.write_text(SPEC.replace("  name: cycles\n  denoise: true\n", "  name: flat\n  background: [0.2, 2.0, 0.2]\n"))
    with pytest.raises(SpecError) as e:
        load_spec(bad)
    (pr,) = e.value.problems
    assert (pr.line, pr.path) == (12, "backend.background") and "[0, 1]" in pr.message
    g = compile_spec(load_spec(spec_file, ["backend={name: flat, background: [0.0, 0.0, 1.0]}"]))
    s = build(g, tmp_path / "out", jobs=1)
    assert not s.failures and s.images >= 1
    rgbs = sorted((tmp_path / "out" / "bop" / "train_pbr" / "000000" / "rgb").glob("*.png"))
    assert len(rgbs) == s.images
    for p in rgbs:
        img = np.asarray(Image.open(p))
        assert img.std() > 5  # the room, its floor texture and the objects, not one colour
    gt = json.loads((tmp_path / "out" / "bop" / "train_pbr" / "000000" / "scene_gt_info.json").read_text())
    assert sum(i["px_count_visib"] > 0 for v in gt.values() for i in v) > 0


def test_a_calibrated_level_without_its_denoiser_renders_the_paper_samples():
    """Calibrated 'high' is a few samples *with* denoising; a spec that turns denoising off must not
    get those few samples raw (4 spp of noise), but the paper preset's own."""
    from specsynth.plugins import BackendPlugin
    from specsynth.spec.models import BackendOptions, Quality

    plugin = BackendPlugin(name="x", options=BackendOptions, backend="nowhere:X",
                           calibrated={"high": {"samples": 4, "denoise": True}})
    high = Quality(level="high")
    filled = plugin.options_for(BackendOptions(name="x"), high)
    assert (filled.samples, filled.denoise) == (4, True)
    off = plugin.options_for(BackendOptions(name="x", denoise=False), high)
    assert (off.samples, off.denoise) == (None, False)  # None: the preset's max(AA, diffuse, specular) rays
    assert plugin.options_for(BackendOptions(name="x", samples=16), high).denoise is True
    assert plugin.options_for(BackendOptions(name="x"), Quality(level="paper_high")).samples is None
