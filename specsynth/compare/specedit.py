"""Editing a spec file's YAML in place: fields set, comments added, everything else kept as written.

Round-trips through ruamel.yaml, so the user's comments, order and layout survive; a changed field
gets an end-of-line comment (its parent mapping turns to block style when it was a flow mapping,
which cannot hold comments); a range is written as a flow sequence ``[lo, hi]``; ``None`` removes
the field. Relative paths are rewritten when the edited file is written to another folder.
"""

from __future__ import annotations

import io
import os
from pathlib import Path
from typing import Any

# Fields holding paths relative to the spec file (dotted, '*' for every key or item).
PATH_FIELDS = ("objects.path", "objects.meshes.*.path", "objects.materials.*.texture", "scenes.*.file",
               "backend.backgrounds")


class Document:
    """A YAML document and the indentation it was written with (kept when it is dumped)."""

    def __init__(self, text: str):
        self.text = text
        self.root = _yaml().load(text)
        self.indent, self.offset = _indentation(text)

    def dump(self) -> str:
        y = _yaml()
        y.indent(mapping=self.indent, sequence=self.offset + 2, offset=self.offset)
        buf = io.StringIO()
        y.dump(self.root, buf)
        return keep_wrapping(self.text, buf.getvalue())


def _squeezed(lines: list[str]) -> str:
    """Lines joined with every run of whitespace as one space, none inside brackets' edges."""
    import re

    text = re.sub(r"\s+", " ", " ".join(lines)).strip()
    return re.sub(r"([\[{]) | ([\]},])", lambda m: m.group(1) or m.group(2), text)


def keep_wrapping(original: str, dumped: str) -> str:
    """``dumped`` with each run of lines that differs from ``original`` only in where lines break
    (ruamel writes a flow list the user wrapped over several lines on one) put back as the user
    wrote it. Checked: the result must load to the same data as ``dumped``, else ``dumped``."""
    import difflib

    old, new = original.splitlines(keepends=True), dumped.splitlines(keepends=True)
    out: list[str] = []
    for tag, i0, i1, j0, j1 in difflib.SequenceMatcher(None, old, new, autojunk=False).get_opcodes():
        same = tag == "replace" and _squeezed(old[i0:i1]) == _squeezed(new[j0:j1])
        out += old[i0:i1] if tag == "equal" or same else new[j0:j1]
    kept = "".join(out)
    if kept != dumped and not kept.endswith("\n") and dumped.endswith("\n"):
        kept += "\n"
    try:
        return kept if _yaml().load(kept) == _yaml().load(dumped) else dumped
    except Exception:  # noqa: BLE001  (any YAML error: the safe choice is ruamel's own text)
        return dumped


def _yaml():
    """A round-trip YAML that keeps quotes (``"2":`` stays ``"2":``) and never folds long lines."""
    from ruamel.yaml import YAML

    y = YAML()
    y.preserve_quotes = True
    y.width = 4096
    return y


def _indentation(text: str) -> tuple[int, int]:
    """(mapping indent, block sequence dash offset) as the text uses them (2 and 0 if unseen)."""
    import re

    indent = offset = None
    prev_key_col = None
    for line in text.splitlines():
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        col = len(line) - len(line.lstrip(" "))
        body = line.strip()
        if prev_key_col is not None and col > prev_key_col:
            if body.startswith("- ") and offset is None:
                offset = col - prev_key_col
            elif re.match(r"^[^\s-][^:]*:", body) and indent is None:
                indent = col - prev_key_col
        prev_key_col = col if re.match(r"^[^\s-][^:]*:\s*(#.*)?$", body) else None
        if indent is not None and offset is not None:
            break
    return indent or 2, offset if offset is not None else 0


def load(text: str) -> Document:
    return Document(text)


def dump(doc: Document) -> str:
    return doc.dump()


def _node(value: Any):
    """A value as the spec writes it: lists and mappings on one line (flow style)."""
    from ruamel.yaml.comments import CommentedMap, CommentedSeq

    if isinstance(value, (list, tuple)):
        seq = CommentedSeq([int(v) if isinstance(v, float) and v.is_integer() else v for v in value])
        seq.fa.set_flow_style()
        return seq
    if isinstance(value, dict):
        mapping = CommentedMap((k, _node(v)) for k, v in value.items())
        mapping.fa.set_flow_style()
        return mapping
    return value


def _existing_key(mapping, name: str):
    """The key of ``mapping`` that ``name`` means: itself, or the number it spells (``1:`` and
    ``"1":`` both name object 1 in ``objects.materials``)."""
    if name in mapping or not name.isdigit():
        return name
    return int(name) if int(name) in mapping else name


def set_field(doc: Document, dotted: str, value: Any, comment: str | None = None) -> None:
    """Set ``dotted`` (creating mappings on the way) to ``value``; None removes it."""
    from ruamel.yaml.comments import CommentedMap

    parts = dotted.split(".")
    cur = doc.root
    for p in parts[:-1]:
        p = _existing_key(cur, p)
        if p not in cur or cur[p] is None:
            if value is None:
                return
            cur[p] = CommentedMap()
        cur = cur[p]
    key = _existing_key(cur, parts[-1])
    if value is None:
        cur.pop(key, None)
        return
    if hasattr(cur, "fa") and cur.fa.flow_style():
        cur.fa.set_block_style()
    cur[key] = _node(value)
    if comment:
        cur.ca.items.pop(key, None)  # the field's old comment described its old value
        written = f"{key}: {_flow(value)}"
        cur.yaml_add_eol_comment(comment, key, column=doc.indent * (len(parts) - 1) + len(written) + 2)


def _flow(value: Any) -> str:
    """How a value set by ``set_field`` reads in the file (for placing its comment)."""
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_flow(v) for v in value) + "]"
    if isinstance(value, dict):
        return "{" + ", ".join(f"{k}: {_flow(v)}" for k, v in value.items()) + "}"
    if isinstance(value, float) and value.is_integer():
        return str(int(value))
    return str(value)


def _walk(node, parts: list[str], prefix: str = ""):
    """(dotted path, container, key) of every value ``parts`` (with '*') selects."""
    if not parts or node is None:
        return
    head, rest = parts[0], parts[1:]
    if isinstance(node, dict):
        keys = list(node) if head == "*" else ([head] if head in node else [])
    elif isinstance(node, list):
        keys = list(range(len(node))) if head == "*" else []
    else:
        return
    for k in keys:
        path = f"{prefix}.{k}" if prefix else str(k)
        if rest:
            yield from _walk(node[k], rest, path)
        else:
            yield path, node, k


def rebase_paths(doc: Document, src_dir: Path, dst_dir: Path) -> list[str]:
    """Relative path fields re-expressed from ``dst_dir`` (the edited file's new folder)."""
    changed = []
    if Path(src_dir).resolve() == Path(dst_dir).resolve():
        return changed
    for pattern in PATH_FIELDS:
        for path, container, key in _walk(doc.root, pattern.split(".")):
            v = container[key]
            if not isinstance(v, str) or os.path.isabs(v) or v.startswith(("dataset:", "$", "~", "builtin")):
                continue
            container[key] = os.path.relpath(Path(src_dir).resolve() / v, Path(dst_dir).resolve())
            changed.append(path)
    return changed
