"""Example specsynth output plugins: ``instance_map`` (a per-view product) and ``boxes_csv`` (a
dataset writer). Each is one module and one entry point; specsynth itself is not changed."""
