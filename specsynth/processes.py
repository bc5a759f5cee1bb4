"""Set-up shared by the worker processes of a pool: how they use memory and threads.

Pure process configuration, no specsynth imports: any layer's workers may call it once when the
process starts.
"""

from __future__ import annotations

import contextlib
import ctypes

_M_TRIM_THRESHOLD = -1
_M_MMAP_THRESHOLD = -3


def steady_malloc(threshold: int = 32 << 20) -> bool:
    """Keep freed memory of this process for reuse instead of returning it to the system after
    every large array. glibc maps each allocation over its mmap threshold freshly and trims the
    heap's top after each free, so a loop over images of a few MB pays page faults on every pass
    (``specsynth compare``'s measuring: 13.0 -> 8.9 s for 1000 VGA images, one process). Both
    thresholds must be set: setting only the trim threshold freezes the mmap threshold at its
    128 KiB default (23.6 s). 32 MiB is glibc's largest mmap threshold on 64-bit systems.
    -> whether glibc took both settings (False elsewhere)."""
    try:
        libc = ctypes.CDLL("libc.so.6")
        return bool(libc.mallopt(_M_MMAP_THRESHOLD, threshold)) and bool(libc.mallopt(_M_TRIM_THRESHOLD, 4 * threshold))
    except (OSError, AttributeError):
        return False


def one_blas_thread() -> None:
    """One BLAS thread in this process: a pool already runs a process per core, and BLAS's own
    threads spin on the cores the other workers need."""
    from threadpoolctl import threadpool_limits

    threadpool_limits(1)


class _Captured:
    text: str = ""


@contextlib.contextmanager
def captured_fd(fd: int):
    """Whatever C code writes to file descriptor ``fd`` (1 or 2) inside the block, kept in the
    yielded object's ``text`` instead of reaching the terminal: for libraries that print banners and
    driver probes straight to the C-level stream, where ``sys.stdout`` / ``sys.stderr`` cannot see
    them. Process-wide for the block's duration: keep the block short."""
    import os
    import sys
    import tempfile

    got = _Captured()
    stream = sys.stdout if fd == 1 else sys.stderr if fd == 2 else None
    try:
        if stream is not None:
            stream.flush()
    except (AttributeError, OSError, ValueError):
        pass
    saved = os.dup(fd)
    with tempfile.TemporaryFile() as tmp:
        os.dup2(tmp.fileno(), fd)
        try:
            yield got
        finally:
            os.dup2(saved, fd)
            os.close(saved)
            tmp.seek(0)
            got.text = tmp.read().decode(errors="replace")


def import_quietly(module: str, banner: str):
    """``importlib.import_module(module)`` without the ``banner`` line its C code prints to stderr
    on first import; anything else printed then is passed on."""
    import importlib
    import os
    import sys

    if module in sys.modules:
        return sys.modules[module]
    with captured_fd(2) as got:
        mod = importlib.import_module(module)
    rest = "".join(line for line in got.text.splitlines(keepends=True) if not line.startswith(banner))
    if rest:
        os.write(2, rest.encode())
    return mod
