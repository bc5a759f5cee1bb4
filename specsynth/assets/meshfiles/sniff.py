"""Is this file a mesh of the kind its name says? A cheap check of its first bytes, so that
``validate`` refuses a password file named ``floor.ply`` before any conversion. Errors name the
file and what was expected, never what was found in it."""

from __future__ import annotations

from pathlib import Path

from .part import MeshFileError

KNOWN = (".ply", ".obj", ".glb", ".gltf", ".stl", ".off", ".urdf", ".dae")


def _text_head(head: bytes) -> str | None:
    try:
        return head.decode("utf-8")
    except UnicodeDecodeError:
        return None


def check_mesh_file(path: Path, what: str) -> None:
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in KNOWN:
        raise MeshFileError(f"{what}: {path} is not a mesh file by its name (expected one of {', '.join(KNOWN)})")
    try:
        with open(path, "rb") as f:
            head = f.read(4096)
    except OSError as e:
        raise MeshFileError(f"{what}: cannot read {path} ({e.strerror or type(e).__name__})") from None
    text = _text_head(head[:1024].rsplit(b"\n", 1)[0] if len(head) == 4096 else head)
    ok = {
        ".ply": head.startswith(b"ply"),
        ".glb": head.startswith(b"glTF"),
        ".gltf": text is not None and text.lstrip().startswith("{"),
        ".off": text is not None and text.lstrip().upper().startswith(("OFF", "COFF", "NOFF", "#")),
        ".urdf": text is not None and text.lstrip().startswith("<"),
        ".dae": text is not None and text.lstrip().startswith("<"),
        ".stl": head.startswith(b"solid") or (len(head) >= 84 and _binary_stl_size_ok(path, head)),
        ".obj": text is not None and _looks_like_obj(text),
    }[suffix]
    if not ok:
        raise MeshFileError(f"{what}: {path} does not start like a {suffix[1:].upper()} file")


def _binary_stl_size_ok(path: Path, head: bytes) -> bool:
    n = int.from_bytes(head[80:84], "little")
    return path.stat().st_size == 84 + 50 * n


def _looks_like_obj(text: str) -> bool:
    """Every statement line of the head starts with an OBJ keyword (or is a comment)."""
    keys = {"v", "vt", "vn", "vp", "f", "l", "p", "o", "g", "s", "usemtl", "mtllib", "#", "cstype", "deg", "curv",
            "parm", "end", "surf", "mg", "lod", "bevel", "c_interp", "d_interp", "shadow_obj", "trace_obj"}
    lines = [ln.strip() for ln in text.splitlines() if ln.strip()]
    return bool(lines) and all(ln.startswith("#") or ln.split()[0] in keys for ln in lines[:50])
