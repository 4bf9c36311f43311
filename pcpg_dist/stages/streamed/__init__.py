"""The stages over blocks of a log too large for one process (``ray.data`` runs them).

Every function here is pure and works on one block (a dict of NumPy columns) or on small
reduced statistics, so a fit over millions of trajectories is a sum of per-block results:
:mod:`.features` (per-trajectory summary features from per-block partial sums),
:mod:`.kmeans` (k-means from per-block sufficient statistics), :mod:`.ranking` (the seeded
split and the top-p threshold from per-block histograms) and :mod:`.policy` (the BC cells as
one stacked network trained block by block, and the accuracy counts of the evaluation).
The plumbing that runs them is :mod:`pcpg_dist.orchestration.streaming`.
"""
