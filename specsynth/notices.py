"""What libraries and specsynth's own loaders say while a command runs, collected instead of printed.

Python warnings (``warnings.warn``: specsynth's asset readers, numpy's RuntimeWarnings) and the
warnings libraries log (trimesh, pyrender) are caught by a :class:`Collector` while a command or a
build job runs, travel back from pool workers with the job's result, and are printed once at the
end of the command by :func:`summarise`: a count and what it means for the user, not a library's raw
line per occurrence. ``--verbose`` also prints each message as it was raised.

No specsynth imports: every layer may collect, and the command line reports.
"""

from __future__ import annotations

import logging
import re
import warnings
from dataclasses import dataclass
from typing import Callable, Iterable

# Loggers of libraries whose warnings would otherwise reach the terminal through logging's
# last-resort handler (trimesh logs a warning for every mesh it repairs or cannot parse fully).
LIBRARY_LOGGERS = ("trimesh", "pyrender", "PIL", "matplotlib")


@dataclass(frozen=True)
class Notice:
    """One message: ``source`` is the warning category's name (``UserWarning``, ``RuntimeWarning``)
    or ``log:<logger>`` for a library's log record."""

    source: str
    text: str


class Collector:
    """While active (``with Collector() as c:``), Python warnings and library log warnings are kept
    in ``c.notices`` instead of being printed. Nested collectors each keep what happens inside them.

    Warning filters are left as they are (a warning Python would hide stays hidden); only where a
    shown warning goes changes. Like ``warnings.catch_warnings`` this is process state: a Dask
    worker running several tasks in threads at once may attribute a warning to the wrong task,
    which only moves it between two jobs of the same build.
    """

    def __init__(self) -> None:
        self.notices: list[Notice] = []
        self._catch: warnings.catch_warnings | None = None
        self._handler: logging.Handler | None = None
        self._saved: list[tuple[logging.Logger, bool]] = []

    def add(self, notice: Notice) -> None:
        self.notices.append(notice)

    def __enter__(self) -> "Collector":
        self._catch = warnings.catch_warnings()
        self._catch.__enter__()

        def show(message, category, filename, lineno, file=None, line=None):  # noqa: ARG001
            self.add(Notice(category.__name__, str(message)))

        warnings.showwarning = show
        handler = _ListHandler(self)
        self._handler = handler
        for name in LIBRARY_LOGGERS:
            lg = logging.getLogger(name)
            self._saved.append((lg, lg.propagate))
            lg.addHandler(handler)
            lg.propagate = False
        _active.append(self)
        return self

    def __exit__(self, *exc) -> None:
        if _active and _active[-1] is self:
            _active.pop()
        for lg, propagate in self._saved:
            lg.removeHandler(self._handler)
            lg.propagate = propagate
        self._saved.clear()
        if self._catch is not None:
            self._catch.__exit__(*exc)
            self._catch = None


class _ListHandler(logging.Handler):
    def __init__(self, collector: Collector) -> None:
        super().__init__(level=logging.WARNING)
        self.collector = collector

    def emit(self, record: logging.LogRecord) -> None:
        try:
            text = record.getMessage()
        except Exception:  # noqa: BLE001 - a malformed log call must not break a build
            text = str(record.msg)
        self.collector.add(Notice(f"log:{record.name}", text))


_active: list[Collector] = []


def record(notices: Iterable[Notice]) -> None:
    """Hand notices raised elsewhere (a pool worker's) to the active collector; without one, show
    them as warnings, as they would have been shown where they were raised."""
    import builtins

    for n in notices:
        if _active:
            _active[-1].add(n)
            continue
        category = getattr(builtins, n.source, None)
        if not (isinstance(category, type) and issubclass(category, Warning)):
            category = UserWarning  # a library's own category, or a log record
        warnings.warn(n.text, category, stacklevel=2)


# ------------------------------------------------------------------------- summary


@dataclass(frozen=True)
class Kind:
    """A family of messages and the one line that says what they mean: ``line(n)`` for n distinct
    messages of the family."""

    pattern: re.Pattern
    line: Callable[[int], str]
    source: str | None = None  # only messages of this source (category or log:<logger>)


def _plural(n: int, one: str, many: str) -> str:
    return f"{n} {one if n == 1 else many}"


# Library furniture (the Sweet Home 3D models, unpacked under the cache's library/ folder) was made
# by many hands: some of its material files name textures of their authors' own disks. The
# readers warn per material; the user learns what it means for the images.
_LIBRARY = r"[/\\]library[/\\]"
KINDS = (
    Kind(re.compile(_LIBRARY + r".*: (?:base colour|emission|roughness|metallic|normal|bump|opacity) texture .* is missing"),
         lambda n: f"{_plural(n, 'library furniture texture is', 'library furniture textures are')} missing; "
                   "their materials use their base colour"),
    Kind(re.compile(_LIBRARY + r".*has textures but its (?:faces|primitives) have no UVs"),
         lambda n: f"{_plural(n, 'library furniture material has', 'library furniture materials have')} "
                   "textures but no texture coordinates; they use their plain colour"),
    Kind(re.compile(_LIBRARY + r".*material library .* is missing"),
         lambda n: f"{_plural(n, 'library furniture model has', 'library furniture models have')} no material "
                   "file; their parts render grey"),
    Kind(re.compile(r"collision hull of .* vertices computed from"),
         lambda n: f"{_plural(n, 'large mesh gets', 'large meshes get')} a collision hull from a sample of its "
                   "vertices (physics only; images are unaffected)"),
    Kind(re.compile(r"occlusionTexture is ignored"),
         lambda n: f"{_plural(n, 'glTF material has', 'glTF materials have')} an occlusion texture, which is not "
                   "used (path tracers compute occlusion themselves)"),
    Kind(re.compile(r"^[\w-]+: no GPU"), lambda n: "no GPU found on this machine; rendered on the CPU"),
    Kind(re.compile(r"."), lambda n: f"{_plural(n, 'numerical warning', 'numerical warnings')} from a library "
                                      "(e.g. a statistic over no values); run with --verbose to see them",
         source="RuntimeWarning"),
)


def summarise(notices: Iterable[Notice]) -> list[str]:
    """One line per family of messages (distinct messages counted once each); messages of no known
    family are given as they are (once each): they name the user's own files and what was done."""
    seen: dict[str, Notice] = {}
    for n in notices:
        seen.setdefault(n.text, n)
    counts: dict[int, int] = {}
    rest: list[Notice] = []
    for n in seen.values():
        for i, k in enumerate(KINDS):
            if (k.source is None or k.source == n.source) and k.pattern.search(n.text):
                counts[i] = counts.get(i, 0) + 1
                break
        else:
            rest.append(n)
    lines = [KINDS[i].line(c) for i, c in sorted(counts.items())]
    logged = [n for n in rest if n.source.startswith("log:")]
    lines += [n.text for n in rest if not n.source.startswith("log:")]
    if logged:
        libs = sorted({n.source[4:] for n in logged})
        lines.append(f"{_plural(len(logged), 'warning', 'warnings')} logged by {', '.join(libs)} while reading "
                     "files; run with --verbose to see them")
    return lines
