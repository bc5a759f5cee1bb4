"""Build a dataset on a Slurm cluster through dask-jobqueue (pip install dask-jobqueue).

    python examples/slurm_build.py specs/lmo_pbr_h.yaml /shared/lmo --nodes 25 --cores 16

Each Slurm job is one node running ``--cores`` single-threaded Dask worker processes with
specsynth's Dask settings (DASK_CONFIG); the build itself runs here and talks to the scheduler.
``--out`` must be on a filesystem every node sees. tests/test_scaleout.py checks the job script.
"""

from __future__ import annotations

import argparse
import subprocess

from specsynth.run.executors.dask import CONFIG_DIR


def make_cluster(cores: int = 16, memory: str = "64GB", walltime: str = "04:00:00", **kwargs):
    from dask_jobqueue import SLURMCluster

    return SLURMCluster(
        cores=cores, processes=cores, memory=memory, walltime=walltime,  # one thread per worker process
        job_extra_directives=["--exclusive"],
        job_script_prologue=[f"export DASK_CONFIG={CONFIG_DIR}"],
        **kwargs,
    )


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("spec")
    ap.add_argument("out")
    ap.add_argument("--nodes", type=int, default=2)
    ap.add_argument("--cores", type=int, default=16)
    args = ap.parse_args()
    with make_cluster(args.cores) as cluster:
        cluster.scale(jobs=args.nodes)
        address = cluster.scheduler_address.removeprefix("tcp://")
        subprocess.run(["specsynth", "build", args.spec, "--out", args.out, "--executor", f"dask://{address}"], check=True)


if __name__ == "__main__":
    main()
