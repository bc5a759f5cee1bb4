"""Run ``specsynth build`` in this process and stop it for good at a chosen point, so a test can
kill it there: no timing race decides where the kill lands.

    python tests/paused_build.py STAGE MARKER -- build SPEC --out OUT ...

``STAGE`` is ``arrange``, ``view`` or ``render``: the build stops when its first job of that stage
has finished (its record is in the store; the workers go on with the jobs they hold); ``merge``:
it stops while writing the dataset, after its fifth file is in place; ``swap``: it stops while
swapping the new dataset in, once ``bop/`` is in place (and the entries after it are not). It then writes its pid to ``MARKER``
and sleeps until it is killed. The build's own code runs unchanged up to that point.
"""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path


def _stop_here(marker: Path) -> None:
    marker.write_text(str(os.getpid()))
    while True:
        time.sleep(60)


def main(argv: list[str]) -> int:
    stage, marker = argv[0], Path(argv[1])
    assert argv[2] == "--", argv
    from specsynth.cli import main as cli_main
    from specsynth.run import pipeline

    if stage == "merge":
        from specsynth.outputs import bop

        real_place = bop.place_file
        placed = []

        def place_file(src, dst):
            n = real_place(src, dst)
            placed.append(dst)
            if len(placed) == 5:
                _stop_here(marker)
            return n

        bop.place_file = place_file
    elif stage == "swap":
        from specsynth.run.staging import Staging

        real_swap = Staging._swap

        def swap(self, name, ident):
            real_swap(self, name, ident)
            if name == "bop":
                _stop_here(marker)

        Staging._swap = swap
    else:
        real_done = pipeline.Pipeline.on_done

        def on_done(self, c, res):
            calls = real_done(self, c, res)
            if c.stage == stage:
                _stop_here(marker)
            return calls

        pipeline.Pipeline.on_done = on_done
    return cli_main(argv[3:])


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
