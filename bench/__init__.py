"""``make bench``: sm_bt's performance goals, measured as ratios and bounds in one run.

``python -m bench`` runs the benchmark modules (each ``run(quick) -> list[Figure]``), prints a
table with the goal beside each figure, and writes ``results.json`` and ``scaling.png`` under
``build/bench/``. See docs/performance.md.
"""
