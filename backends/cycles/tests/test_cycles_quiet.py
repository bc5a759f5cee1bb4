"""Cycles says what it means and nothing else on the terminal: Blender's GPU driver probes
('WARNING CUEW initialization failed') stay off it; a machine without a GPU is told so in a
sentence. Each test starts the backend in a fresh process, as a worker does."""

from __future__ import annotations

import subprocess
import sys

import pytest


def test_cycles_without_a_gpu_says_so_in_a_sentence():
    """device: auto enumerates GPUs: Blender's 'WARNING CUEW initialization failed' stays off the
    terminal and the build is told, once, that it renders on the CPU."""
    pytest.importorskip("bpy")
    code = ("import warnings\n"
            "from specsynth_cycles.backend import CyclesBackend\n"
            "with warnings.catch_warnings(record=True) as w:\n"
            "    warnings.simplefilter('always')\n"
            "    b = CyclesBackend({'device': 'auto'}, threads=1)\n"
            "print('device', b.device)\n"
            "print('said', [str(x.message) for x in w])\n")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-2000:]
    assert "CUEW" not in r.stdout + r.stderr and "HIPEW" not in r.stdout + r.stderr
    if "device cpu" in r.stdout:  # a machine with a GPU renders on it and has nothing to say
        assert "cycles: no GPU found on this machine (device: auto); rendering on the CPU" in r.stdout


def test_starting_cycles_on_a_machine_without_a_gpu_driver_prints_nothing():
    """Blender's GPU driver probes ('WARNING CUEW initialization failed') would reach the terminal of
    every Cycles build on a CPU-only machine; starting the backend must print nothing."""
    pytest.importorskip("specsynth_cycles")
    code = ("from specsynth_cycles.backend import CyclesBackend\n"
            "CyclesBackend(None, threads=1)\n")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr[-2000:]
    assert "CUEW" not in r.stdout + r.stderr and "HIPEW" not in r.stdout + r.stderr
    assert r.stdout.strip() == "", r.stdout[-2000:]
