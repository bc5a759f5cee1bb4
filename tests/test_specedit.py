"""Editing a spec's YAML in place (compare/specedit.py): what is not edited stays as the user wrote it."""

from __future__ import annotations

from hypothesis import given, settings
from hypothesis import strategies as st

from specsynth.compare import specedit

SPEC = """\
version: 1
arrangements:
  distractors:        # round the objects
    count: [3, 7]     # a few
    objects: ["catalogue/a", "catalogue/b",
              "catalogue/c", toys/cube,
              toys/prism]
sensor:
  contrast: 1.6  # fit: old note
"""


def _edited(text: str, field: str, value, comment: str | None = "fit: new") -> str:
    doc = specedit.load(text)
    specedit.set_field(doc, field, value, comment)
    return specedit.dump(doc)


def test_a_list_wrapped_over_lines_stays_wrapped_when_another_field_is_set():
    out = _edited(SPEC, "sensor.contrast", 1.7)
    changed = [(a, b) for a, b in zip(SPEC.splitlines(), out.splitlines()) if a != b]
    assert changed == [("  contrast: 1.6  # fit: old note", "  contrast: 1.7  # fit: new")]
    assert len(out.splitlines()) == len(SPEC.splitlines())


def test_the_wrapped_list_itself_set_is_written_with_its_new_value():
    out = _edited(SPEC, "arrangements.distractors.objects", ["toys/cube"])
    assert specedit.load(out).root["arrangements"]["distractors"]["objects"] == ["toys/cube"]
    assert "catalogue/a" not in out and "  contrast: 1.6  # fit: old note" in out


@settings(max_examples=60, deadline=None)
@given(items=st.lists(st.from_regex(r"[a-z][a-z0-9_/]{0,12}", fullmatch=True), min_size=1, max_size=9),
       breaks=st.lists(st.booleans(), min_size=9, max_size=9), value=st.floats(0.1, 5.0))
def test_wrapping_survives_any_edit_elsewhere_and_the_data_is_ruamels(items, breaks, value):
    parts = []
    for k, item in enumerate(items):
        sep = "" if k == len(items) - 1 else (",\n      " if breaks[k] else ", ")
        parts.append(f'"{item}"{sep}')
    text = "a:\n  objects: [" + "".join(parts) + "]\nb:\n  x: 1\n"
    out = _edited(text, "b.x", round(value, 3))
    assert out.split("b:\n")[0] == text.split("b:\n")[0]  # the list as written
    doc = specedit.load(out).root
    assert list(doc["a"]["objects"]) == items and doc["b"]["x"] == round(value, 3)


def test_a_layout_change_that_would_change_the_data_is_not_kept():
    # Whitespace inside a quoted scalar is data: the squeezed comparison must not make two values equal.
    original = 'a: ["x  y"]\nb: 1\n'
    dumped = 'a: ["x y"]\nb: 1\n'
    assert specedit.keep_wrapping(original, dumped) == dumped
