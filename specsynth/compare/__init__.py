"""Comparing a synthetic dataset with a real one, and fitting a spec to the real one.

``split`` reads BOP splits (real test sets, or the ``bop/`` folder of a build) with located
errors; ``gtinfo`` completes a split that has no masks or ``scene_gt_info.json`` with the
annotation engine; ``geometry`` and ``imagestats`` are the statistics (pure functions);
``distance`` the distances, coverage and verdicts between two samples; ``collect`` streams a split
through them; ``report`` writes the table, ``compare.json`` and the picture sheet; ``fit`` turns
the real statistics into spec edits. Every statistic is defined in ``docs/compare.md``.
"""
