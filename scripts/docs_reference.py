"""Write the docs site's generated pages: every spec field from the pydantic models, every command
from the CLI parser, and the site's home page and changelog from README.md and CHANGELOG.md (their
links made relative to docs/), so none of them can drift from its source.

    python scripts/docs_reference.py            # writes docs/reference/{spec,cli}.md, docs/index.md, docs/changelog.md
    python scripts/docs_reference.py --check    # exit 1 when any is out of date (a test runs this)
"""

from __future__ import annotations

import argparse
import os
import re
import sys
import typing
from pathlib import Path

from pydantic import BaseModel

from specsynth.cli import parser
from specsynth.plan.compiler import stage_of_field
from specsynth.plugins import installed_backend_plugins
from specsynth.spec.models import DatasetSpec, Outputs, installed_outputs_model

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "docs" / "reference"
RERUNS = {"arrange": "arrange, view, render", "view": "view, render", "render": "render", None: "outputs only"}


def _type(annotation) -> str:
    """A field's type as a reader wants it: `float`, `[lo, hi] of float`, `list of str`, `A | B`."""
    text = getattr(annotation, "__name__", None) if not typing.get_args(annotation) else None
    if text and text not in ("Annotated",):
        return {"NoneType": "null"}.get(text, text)
    origin, args = typing.get_origin(annotation), typing.get_args(annotation)
    if origin is typing.Annotated:
        return _type(args[0])
    if origin is typing.Literal:
        return " \\| ".join(f"`{a!r}`".replace("'", '"') for a in args)
    if origin in (typing.Union, getattr(__import__("types"), "UnionType", None)):
        return " \\| ".join(_type(a) for a in args)
    if origin in (list, tuple) and args:
        if origin is tuple and len(args) == 2 and args[0] == args[1]:
            return f"[lo, hi] of {_type(args[0])}"
        if origin is tuple and args[-1] is not Ellipsis:
            return "[" + ", ".join(_type(a) for a in args) + "]"
        return f"list of {_type(args[0])}"
    if origin is dict and args:
        return f"map of {_type(args[0])} to {_type(args[1])}"
    return str(annotation).replace("typing.", "")


def _default(field) -> str:
    if field.is_required():
        return "required"
    value = field.get_default(call_default_factory=True)
    if isinstance(value, BaseModel):
        return "see below"
    text = repr(value).replace("'", '"')
    return f"`{text}`" if len(text) < 40 else f"`{text[:37]}...`"


def _models(annotation) -> list[type[BaseModel]]:
    """The pydantic models a field holds (directly, in a list/dict/union)."""
    out = []
    stack = [annotation]
    while stack:
        a = stack.pop()
        if a is Outputs:  # with a switch per installed output, as specs are validated
            out.append(installed_outputs_model())
        elif isinstance(a, type) and issubclass(a, BaseModel):
            out.append(a)
        stack += list(typing.get_args(a))
    return out


def _rows(model: type[BaseModel], prefix: str, sections: list) -> list[str]:
    rows = []
    for name, field in model.model_fields.items():
        path = f"{prefix}{name}"
        desc = (field.description or "").replace("|", "\\|").replace("\n", " ")
        rows.append(f"| `{path}` | {_type(field.annotation)} | {_default(field)} | {RERUNS[stage_of_field(path)]} | {desc} |")
        for sub in _models(field.annotation):
            sections.append((f"{path}", sub))
    return rows


def spec_reference() -> str:
    lines = ["# Spec reference", "",
             "Every field of a dataset spec, generated from the pydantic models (`python scripts/docs_reference.py`).",
             "*Re-runs* is what a rebuild re-runs when the field changes: each stage's jobs are keyed by what they",
             "read, and every stage after a re-run one re-runs too; *outputs only* fields rewrite the dataset files",
             "from the store without running a job. Units are in the descriptions (metres, degrees, millimetres",
             "in BOP files).", ""]
    sections: list = [("", DatasetSpec)]
    seen = set()
    while sections:
        prefix, model = sections.pop(0)
        if (prefix, model) in seen:
            continue
        seen.add((prefix, model))
        title = f"`{prefix}`" if prefix else "Top level"
        doc = (model.__doc__ or "").strip().split("\n\n")[0].replace("\n", " ")
        lines += [f"## {title}", "", doc, "", "| field | type | default | re-runs | description |",
                  "|---|---|---|---|---|"]
        found: list = []
        lines += _rows(model, f"{prefix}." if prefix else "", found)
        lines.append("")
        sections += found
    lines += ["## Backend options", "", "`backend:` takes the options every backend shares and those its plugin "
              "declares (`specsynth backends` lists the installed ones). Changing any re-runs the renders.", ""]
    for plugin in sorted(installed_backend_plugins(), key=lambda p: p.name):
        model = plugin.options
        lines += [f"### `{plugin.name}`", "", "| option | type | default | description |", "|---|---|---|---|"]
        for opt, field in model.model_fields.items():
            desc = (field.description or "").replace("|", "\\|").replace("\n", " ")
            lines.append(f"| `{opt}` | {_type(field.annotation)} | {_default(field)} | {desc} |")
        lines.append("")
    return "\n".join(lines).rstrip() + "\n"


def cli_reference() -> str:
    os.environ["COLUMNS"] = "100"  # argparse wraps help to the terminal: fix it so the page is reproducible
    top = parser()
    lines = ["# Command-line reference", "", "Generated from the parser (`python scripts/docs_reference.py`); "
             "`specsynth COMMAND --help` prints the same.", "", "```", top.format_usage().strip(), "```", ""]
    subs = next(a for a in top._actions if isinstance(a, argparse._SubParsersAction))
    for name, sub in subs.choices.items():
        help_text = next((c.help for c in subs._choices_actions if c.dest == name), "") or ""
        lines += [f"## `specsynth {name}`", "", help_text, "", "```", sub.format_help().strip(), "```", ""]
    return "\n".join(lines).rstrip() + "\n"


def from_repository(text: str) -> str:
    """A page of the repository's root re-pointed from docs/: `docs/x.md` -> `x.md`, root files by name."""
    text = re.sub(r"\]\(docs/", "](", text)
    return text.replace("](CHANGELOG.md)", "](changelog.md)")


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--check", action="store_true")
    args = ap.parse_args()
    pages = {OUT / "spec.md": spec_reference(), OUT / "cli.md": cli_reference(),
             ROOT / "docs" / "index.md": from_repository((ROOT / "README.md").read_text()),
             ROOT / "docs" / "changelog.md": from_repository((ROOT / "CHANGELOG.md").read_text())}
    stale = [p for p, text in pages.items() if not p.is_file() or p.read_text() != text]
    if args.check:
        for p in stale:
            print(f"{p} is out of date: run python scripts/docs_reference.py", file=sys.stderr)
        return 1 if stale else 0
    OUT.mkdir(parents=True, exist_ok=True)
    for p, text in pages.items():
        p.write_text(text)
        print(f"wrote {p}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
