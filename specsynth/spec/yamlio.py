"""Loading specs from YAML with errors located as ``FILE:LINE:COL: field.path: message``.

PyYAML's node graph keeps the source position of every key and value; we keep a map from the
data path (``("cameras", "distance")``) to those positions and translate pydantic's error
locations back through it. Overrides given with ``--set dotted.path=value`` are applied to the
loaded data and located as ``--set dotted.path``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml
from pydantic import ValidationError

from ..plugins import unknown_output
from .models import DatasetSpec

# A spec is small: anything that expands beyond this many nodes is an alias bomb, not a spec.
MAX_EXPANDED_NODES = 100_000
# Specs and scene files nest a few levels; PyYAML's composer recurses once per level (600 nested
# brackets raised RecursionError), and Python converts integers of at most 4300 digits.
MAX_DEPTH = 64
MAX_DIGITS = 4000


def shape_problem(text: str, loader=yaml.SafeLoader) -> tuple[int, int, str] | None:
    """(line, column, what) of the first place a YAML text nests deeper than ``MAX_DEPTH`` or
    writes an integer of more than ``MAX_DIGITS`` digits; None when it does neither. Read from
    PyYAML's event stream, which is parsed without recursion; a syntax error raises YAMLError."""
    depth = 0
    for ev in yaml.parse(text, Loader=loader):
        if isinstance(ev, (yaml.MappingStartEvent, yaml.SequenceStartEvent)):
            depth += 1
            if depth > MAX_DEPTH:
                return ev.start_mark.line + 1, ev.start_mark.column + 1, f"nested deeper than {MAX_DEPTH} levels"
        elif isinstance(ev, (yaml.MappingEndEvent, yaml.SequenceEndEvent)):
            depth -= 1
        elif (isinstance(ev, yaml.ScalarEvent) and ev.style is None and len(ev.value) > MAX_DIGITS
              and ev.value.lstrip("+-").replace("_", "").isdigit()):
            return (ev.start_mark.line + 1, ev.start_mark.column + 1,
                    f"an integer of {len(ev.value):,} characters (at most {MAX_DIGITS:,} digits)")
    return None


@dataclass(frozen=True)
class Problem:
    file: str
    line: int | None  # 1-based
    col: int | None  # 1-based
    path: str  # dotted field path, '' for the document
    message: str

    def __str__(self) -> str:
        where = self.file if self.line is None else f"{self.file}:{self.line}:{self.col}"
        return f"{where}: {self.path}: {self.message}" if self.path else f"{where}: {self.message}"


class SpecError(Exception):
    def __init__(self, problems: list[Problem]):
        self.problems = problems
        super().__init__("\n".join(str(p) for p in problems))


@dataclass
class LoadedSpec:
    spec: DatasetSpec
    path: Path
    data: dict[str, Any]  # the validated input data, overrides applied
    positions: dict[tuple, tuple[int, int]]
    overrides: dict[tuple, Any] = field(default_factory=dict)

    @property
    def directory(self) -> Path:
        return self.path.parent

    def locate(self, dotted: str, message: str) -> Problem:
        """A problem found after schema validation (e.g. a missing asset), located in the file."""
        loc = tuple(int(p) if p.isdigit() else p for p in dotted.split(".")) if dotted else ()
        return _problem(str(self.path), loc, message, self.positions, self.overrides, self.data)


class _Loader(yaml.SafeLoader):
    pass


def _walk(node: yaml.Node, path: tuple, positions: dict, problems: list[Problem], file: str, budget: list[int]):
    """Record positions of every path; reject duplicate keys and alias explosions."""
    budget[0] -= 1
    if budget[0] < 0:
        raise _TooBig()
    mark = node.start_mark
    positions.setdefault(path, (mark.line + 1, mark.column + 1))
    if isinstance(node, yaml.MappingNode):
        seen: dict[Any, yaml.Node] = {}
        for k, v in node.value:
            key = _key_text(k)
            if key in seen:
                problems.append(
                    Problem(file, k.start_mark.line + 1, k.start_mark.column + 1, ".".join(map(str, path + (key,))),
                            f"duplicate key {key!r} (first at line {seen[key].start_mark.line + 1})")
                )
            seen[key] = k
            positions[path + (key, "__key__")] = (k.start_mark.line + 1, k.start_mark.column + 1)
            _walk(v, path + (key,), positions, problems, file, budget)
    elif isinstance(node, yaml.SequenceNode):
        for i, v in enumerate(node.value):
            _walk(v, path + (i,), positions, problems, file, budget)


def _key_text(node: yaml.Node) -> str | None:
    """A mapping key as pydantic names it in an error's location: a string as written, any other
    scalar as Python prints its value (``null:`` is 'None', ``yes:`` 'True', ``0x10:`` '16')."""
    if not isinstance(node, yaml.ScalarNode):
        return None
    if node.tag == "tag:yaml.org,2002:str":
        return node.value
    try:
        return str(yaml.constructor.SafeConstructor().construct_object(node))
    except (yaml.YAMLError, ValueError):
        return node.value


class _TooBig(Exception):
    pass


def _code(character) -> int:
    return character if isinstance(character, int) else ord(str(character)[:1] or "\0")


def _yaml_problem(file: str, e: yaml.YAMLError, text: str = "") -> Problem:
    if isinstance(e, yaml.reader.ReaderError):  # a character YAML refuses (NUL, ...): placed by its offset
        before = text[:e.position]
        return Problem(file, before.count("\n") + 1, len(before) - (before.rfind("\n") + 1) + 1, "",
                       f"YAML syntax error: character U+{_code(e.character):04X} is not allowed in YAML text")
    mark = getattr(e, "problem_mark", None) or getattr(e, "context_mark", None)
    msg = getattr(e, "problem", None) or str(e)
    ctx = getattr(e, "context", None)
    text = f"YAML syntax error: {msg}" + (f" ({ctx})" if ctx else "")
    if mark is None:
        return Problem(file, None, None, "", text)
    return Problem(file, mark.line + 1, mark.column + 1, "", text)


def parse_yaml(text: str, file: str) -> tuple[Any, dict[tuple, tuple[int, int]]]:
    try:
        shape = shape_problem(text, _Loader)
        node = None if shape else yaml.compose(text, Loader=_Loader)
    except yaml.YAMLError as e:
        raise SpecError([_yaml_problem(file, e, text)]) from None
    if shape:
        raise SpecError([Problem(file, shape[0], shape[1], "", shape[2])])
    if node is None:
        raise SpecError([Problem(file, 1, 1, "", "spec is empty: expected a mapping with 'name', 'objects', 'scenes', 'backend'")])
    positions: dict[tuple, tuple[int, int]] = {}
    problems: list[Problem] = []
    try:
        _walk(node, (), positions, problems, file, [MAX_EXPANDED_NODES])
    except _TooBig:
        raise SpecError([Problem(file, 1, 1, "", f"document expands to more than {MAX_EXPANDED_NODES} nodes (alias bomb?)")]) from None
    _refuse_foreign(node, file)
    if problems:
        raise SpecError(problems)
    try:
        data = yaml.load(text, Loader=_Loader)
    except yaml.YAMLError as e:  # constructor errors (bad tags, ...)
        raise SpecError([_yaml_problem(file, e)]) from None
    if not isinstance(data, dict):
        line, col = positions.get((), (1, 1))
        kind = type(data).__name__ if data is not None else "nothing"
        raise SpecError([Problem(file, line, col, "", f"top level must be a mapping, got {kind}")])
    return data, positions


def _refuse_foreign(node: yaml.Node, file: str) -> None:
    """A mapping none of whose keys is a spec field is some other file (``validate /etc/shadow``):
    its keys would come back as "unknown field" errors, quoting it line by line."""
    if not isinstance(node, yaml.MappingNode):
        return
    keys = {k.value for k, _ in node.value if isinstance(k, yaml.ScalarNode)}
    if not keys & set(DatasetSpec.model_fields):
        raise SpecError([Problem(file, None, None, "", "not a dataset spec: none of its top-level keys is a spec field "
                                 "(name, objects, scenes, backend, ...); its contents are not shown")])


def parse_override(item: str) -> tuple[tuple, Any]:
    if "=" not in item:
        raise SpecError([Problem("--set", None, None, item, "expected dotted.path=value")])
    dotted, raw = item.split("=", 1)
    dotted = dotted.strip()
    if not dotted or any(not p for p in dotted.split(".")):
        raise SpecError([Problem("--set", None, None, dotted, "empty field name")])
    shape, value = None, ""
    try:
        if raw.strip():
            shape = shape_problem(raw)
            value = None if shape else yaml.safe_load(raw)
    except yaml.YAMLError as e:
        raise SpecError([Problem(f"--set {dotted}", None, None, "", f"cannot parse value {raw!r}: {e}")]) from None
    if shape:
        raise SpecError([Problem(f"--set {dotted}", None, None, "", f"cannot take the value: {shape[2]}")])
    path = tuple(int(p) if p.isdigit() else p for p in dotted.split("."))
    return path, value


def apply_override(data: dict, path: tuple, value: Any) -> None:
    """Set ``path`` in ``data``. A number is a list index only where the node is a list; in a
    mapping it is a key (e.g. ``objects.materials.5``), created as a mapping when missing."""

    def key_in(d: dict, part):
        if part in d:
            return part
        return str(part)

    cur: Any = data
    for i, part in enumerate(path[:-1]):
        if isinstance(cur, list):
            if not isinstance(part, int) or part >= len(cur):
                raise SpecError([Problem(f"--set {_dotted(path)}", None, None, "", f"no list item {part} at {_dotted(path[:i])}")])
            cur = cur[part]
            continue
        if not isinstance(cur, dict):
            raise SpecError([Problem(f"--set {_dotted(path)}", None, None, "", f"{_dotted(path[:i])} is not a mapping")])
        k = key_in(cur, part)
        if k not in cur or cur[k] is None:
            cur[k] = {}
        cur = cur[k]
    last = path[-1]
    if isinstance(cur, list):
        if not isinstance(last, int) or last > len(cur):
            raise SpecError([Problem(f"--set {_dotted(path)}", None, None, "", "list index out of range")])
        if last == len(cur):
            cur.append(value)
        else:
            cur[last] = value
    elif isinstance(cur, dict):
        cur[key_in(cur, last)] = value
    else:
        raise SpecError([Problem(f"--set {_dotted(path)}", None, None, "", f"{_dotted(path[:-1])} is not a mapping")])


def _dotted(path: tuple) -> str:
    return ".".join(str(p) for p in path)


_TYPE_TAGS = {"str", "int", "float", "bool", "list", "dict", "none", "tuple"}


def _is_union_tag(part: str) -> bool:
    """pydantic names union members in error locations (a class, a type, a literal, a tag)."""
    return (
        part in _TYPE_TAGS
        or part[:1].isupper()
        or part.startswith(("function-", "tagged-union", "literal[", "lax-", "json-", "nullable["))
    )


def _lookup(cur: Any, part) -> tuple[bool, Any]:
    """The child ``part`` of a data node; YAML keys like ``5:`` or ``null:`` are ints or None in
    data, strings in paths."""
    if isinstance(cur, dict):
        for k in (part, str(part)) + ((int(part),) if isinstance(part, str) and part.isdigit() else ()):
            if k in cur:
                return True, cur[k]
        for k, v in cur.items():  # a key YAML made None, a bool or a float: pydantic prints it
            if not isinstance(k, str) and str(k) == str(part):
                return True, v
    elif isinstance(cur, list) and isinstance(part, int) and part < len(cur):
        return True, cur[part]
    return False, None


def _problem(file: str, loc: tuple, message: str, positions: dict, overrides: dict, data: Any) -> Problem:
    # Drop the tags pydantic inserts for unions ('BuiltinObject', 'float', "literal['auto']") so
    # the path matches the data the user wrote.
    path: list = []
    cur = data
    for part in loc:
        found, child = _lookup(cur, part)
        if found:
            path.append(str(part) if isinstance(cur, dict) else part)
            cur = child
        elif isinstance(part, str) and _is_union_tag(part):
            continue
        else:
            path.append(part)
            cur = None
    tpath = tuple(path)
    for n in range(len(tpath), -1, -1):
        prefix = tpath[:n]
        if prefix in overrides:
            return Problem(f"--set {_dotted(prefix)}", None, None, _dotted(tpath), message)
    # An error on a parent of an override (a range whose item was --set) belongs to the override.
    for opath in overrides:
        if tuple(str(p) for p in opath[: len(tpath)]) == tuple(str(p) for p in tpath) and len(opath) > len(tpath):
            return Problem(f"--set {_dotted(opath)}", None, None, _dotted(tpath), message)
    pos = positions.get(tpath + ("__key__",)) or None
    n = len(tpath)
    while pos is None and n >= 0:
        pos = positions.get(tpath[:n])
        n -= 1
    line, col = pos if pos else (None, None)
    return Problem(file, line, col, _dotted(tpath), message)


def _message(err: dict) -> str:
    msg = err["msg"]
    loc = tuple(err["loc"])
    if err["type"] == "extra_forbidden" and len(loc) == 2 and loc[0] == "outputs":
        return unknown_output(str(loc[1]))  # outputs.<name>: an output not installed, or none at all
    if err["type"] == "extra_forbidden":
        return "unknown field"
    if msg.startswith("Value error, "):
        msg = msg[len("Value error, ") :]
    return msg


def _plugin_note(err: dict, data: Any) -> str:
    """Errors inside ``backend`` come from the installed plugin's own options model: say which."""
    loc = tuple(err["loc"])
    if len(loc) < 2 or loc[0] != "backend" or not isinstance(data, dict) or not isinstance(data.get("backend"), dict):
        return ""
    name = data["backend"].get("name")
    if not isinstance(name, str):
        return ""
    from ..plugins import PluginNotFound, backend_plugin

    try:
        fields = sorted(backend_plugin(name).options.model_fields)
    except PluginNotFound:
        return ""
    extra = f"; its options: {', '.join(fields)}" if err["type"] == "extra_forbidden" else ""
    return f" (backend plugin {name!r}{extra})"


MAX_SPEC_BYTES = 4 << 20  # a spec is a page of YAML; 4 MiB is far past any real one


def _read_spec_text(p: Path) -> str:
    """The spec's text, read only from a regular file of bounded size (``/dev/zero`` or a 50 MB
    list would otherwise hang or fill memory before any error)."""
    st = p.stat()
    import stat

    if not stat.S_ISREG(st.st_mode):
        raise OSError(0, "not a regular file")
    if st.st_size > MAX_SPEC_BYTES:
        raise OSError(0, f"{st.st_size:,} bytes, over the {MAX_SPEC_BYTES:,}-byte limit for a spec")
    with open(p, "rb") as f:
        data = f.read(MAX_SPEC_BYTES + 1)
    if len(data) > MAX_SPEC_BYTES:
        raise OSError(0, f"over the {MAX_SPEC_BYTES:,}-byte limit for a spec")
    return data.decode("utf-8")


def load_spec(path: str | Path, overrides: list[str] | tuple[str, ...] = ()) -> LoadedSpec:
    """Read, parse and validate a spec file; raises SpecError with every problem located."""
    p = Path(path)
    file = str(path)
    try:
        text = _read_spec_text(p)
    except FileNotFoundError:
        raise SpecError([Problem(file, None, None, "", "no such file")]) from None
    except UnicodeDecodeError as e:
        raise SpecError([Problem(file, None, None, "", f"not UTF-8 text (byte {e.start})")]) from None
    except OSError as e:
        raise SpecError([Problem(file, None, None, "", f"cannot read: {e.strerror or type(e).__name__}")]) from None
    if not text.strip():
        raise SpecError([Problem(file, 1, 1, "", "spec is empty: expected a mapping with 'name', 'objects', 'scenes', 'backend'")])
    data, positions = parse_yaml(text, file)
    over_paths: dict[tuple, Any] = {}
    for item in overrides:
        opath, value = parse_override(item)
        apply_override(data, opath, value)
        over_paths[opath] = value
    try:
        spec = DatasetSpec.model_validate(data)
    except ValidationError as e:
        merged: dict[tuple, Problem] = {}
        for err in e.errors():
            pr = _problem(file, tuple(err["loc"]), _message(err) + _plugin_note(err, data), positions, over_paths, data)
            key = (pr.file, pr.line, pr.col, pr.path)
            if key in merged:  # one mistake, several union members rejecting it: one message
                prev = merged[key]
                if pr.message not in prev.message:
                    merged[key] = Problem(prev.file, prev.line, prev.col, prev.path, f"{prev.message}; or {pr.message}")
            else:
                merged[key] = pr
        problems = sorted(merged.values(), key=lambda pr: (pr.line or 0, pr.col or 0, pr.path))
        raise SpecError(problems) from None
    return LoadedSpec(spec=spec, path=p.resolve(), data=data, positions=positions, overrides=over_paths)
