"""A pytest plugin for the tests of specsynth and of its backends: ``-p specsynth.testing.pytest_plugin``
(in ``addopts``), so every tests folder of the repository, and a backend's own repository, shares it.

It holds the ``slow`` mark to its meaning, "renders with a path tracer": the backends named by the
ini option ``specsynth_slow_backends`` (entry-point names, e.g. ``cycles mitsuba``) get a counting
``render()`` when their renderer module is imported, and a test not marked ``slow`` that renders
with one of them in the test process fails. The default suite (``-m "not slow"``) stays fast only
if the mark tells the truth. It also selects headless OpenGL (EGL) unless PYOPENGL_PLATFORM is set.
"""

from __future__ import annotations

import functools
import importlib.machinery
import os
import sys

import pytest

os.environ.setdefault("PYOPENGL_PLATFORM", "egl")  # headless OpenGL in every tests folder, before it is imported

_GUARD = pytest.StashKey["SlowRenders"]()


class SlowRenders:
    """A meta path finder that wraps the renderer classes' ``render()`` once their modules load,
    and the renders it counted while a test not marked slow ran."""

    def __init__(self, classes: dict[str, str]):
        self.classes = classes  # renderer module -> class name
        self.renders: list[str] = []
        self.watching = False

    def _count(self, cls) -> None:
        render = cls.render

        @functools.wraps(render)
        def counted(backend, *args, **kwargs):
            if self.watching:
                self.renders.append(cls.__name__)
            return render(backend, *args, **kwargs)

        cls.render = counted

    def find_spec(self, name, path, target=None):
        if name not in self.classes:
            return None
        spec = importlib.machinery.PathFinder.find_spec(name, path)
        if spec is None or spec.loader is None:
            return None
        exec_module = spec.loader.exec_module

        def exec_and_count(module):
            exec_module(module)
            self._count(getattr(module, self.classes[name]))

        spec.loader.exec_module = exec_and_count
        return spec

    def install(self) -> None:
        for module, cls in self.classes.items():  # already imported (by a plugin listing, say)
            if module in sys.modules:
                self._count(getattr(sys.modules[module], cls))
        sys.meta_path.insert(0, self)

    def uninstall(self) -> None:
        if self in sys.meta_path:
            sys.meta_path.remove(self)


def _renderer_classes(names: list[str]) -> dict[str, str]:
    """Renderer module -> class of each named backend that is installed (its plugin says where)."""
    from specsynth.plugins import PluginNotFound, backend_plugin

    out = {}
    for name in names:
        try:
            module, _, cls = backend_plugin(name).backend.partition(":")
        except PluginNotFound:
            continue  # not installed here: nothing of it can render
        out[module] = cls
    return out


def pytest_addoption(parser):
    parser.addini("specsynth_slow_backends", "backends (entry-point names) whose renders a test must be marked "
                  "slow for", type="args", default=[])


def pytest_configure(config):
    classes = _renderer_classes(config.getini("specsynth_slow_backends"))
    if classes:
        guard = SlowRenders(classes)
        guard.install()
        config.stash[_GUARD] = guard


def pytest_unconfigure(config):
    guard = config.stash.get(_GUARD, None)
    if guard is not None:
        guard.uninstall()


@pytest.fixture(autouse=True)
def _path_tracer_renders_are_marked_slow(request):
    guard = request.config.stash.get(_GUARD, None)
    if guard is None:
        yield
        return
    guard.renders.clear()
    guard.watching = request.node.get_closest_marker("slow") is None
    yield
    guard.watching = False
    if guard.renders:
        pytest.fail(f"{request.node.nodeid} rendered {len(guard.renders)} image(s) with {sorted(set(guard.renders))} "
                    "but is not marked slow", pytrace=False)
