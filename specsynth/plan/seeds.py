"""Every random number in a build comes from here: a seed per job, keyed by the job's id.

A job's seed depends only on the root seed and its id (``arr=000012/cam=003``), never on
submission order, worker count or the clock, so any subset of jobs can run anywhere, in any
order, and give the same bytes.
"""

from __future__ import annotations

import hashlib

import numpy as np


def seed_sequence(root_seed: int, job_id: str) -> np.random.SeedSequence:
    words = np.frombuffer(hashlib.sha256(job_id.encode("utf-8")).digest(), dtype="<u4")
    return np.random.SeedSequence(entropy=int(root_seed), spawn_key=tuple(int(w) for w in words))


def job_rng(root_seed: int, job_id: str) -> np.random.Generator:
    return np.random.Generator(np.random.PCG64(seed_sequence(root_seed, job_id)))


def job_seed(root_seed: int, job_id: str) -> int:
    """A 31-bit integer seed for renderers that take one (Cycles, Mitsuba, pyrender lights)."""
    return int(seed_sequence(root_seed, job_id).generate_state(1, np.uint32)[0] & 0x7FFFFFFF)


def scene_draw(root_seed: int, job_id: str, weights) -> tuple[int, np.random.Generator]:
    """An arrangement's scene (index into the spec's scenes, by weight) and the job's generator
    after that draw. The compiler calls it to key each arrangement by its own scene only; the
    arrange job calls it to continue drawing (stage, poses) from the same stream."""
    rng = job_rng(root_seed, job_id)
    w = np.asarray(weights, dtype=np.float64)
    return int(rng.choice(len(w), p=w / w.sum())), rng
