"""MLflow tracking: one experiment per config name, one parent run per config, a child per environment.

Embedded default: ``sqlite:///<cwd>/mlflow.db`` with artifacts in ``<cwd>/mlruns``. For a team:
``MLFLOW_TRACKING_URI=http://host:5000`` (an ``mlflow server`` on PostgreSQL with proxied
artifacts, see ops/README.md). Everything here runs in the driver (threads allowed).

Laid out for review (docs/team-mode.md): the experiment carries ``mlflow.experimentKind`` so the
UI opens on its runs table; the parent run holds at most :data:`MAX_PARENT_METRICS` headline
metrics, curves over p and over the corruption level (one value per step), the summary figures
and a description; children hold each environment's detail. Std over seeds goes in a
``metrics.csv`` table, never as ``/std`` chart sections.

Identities and concurrency: a parent is found by its config's content hash (and its sweep run),
a child by (parent, environment, unit key), a sweep by its key. Every find-or-create runs under a
file lock keyed by that identity, beside a SQLite store or in the user's cache folder for a
server; a run created on another machine in the same instant is merged after the fact (the
earliest wins). Logging is idempotent: a parent's metrics go in one batch together with a digest
tag, so a rerun served from cache logs nothing again and leaves the original end time alone.
"""

from __future__ import annotations

import os

# Progress bars of artifact transfers would interleave with ours in the terminal, and the fluent
# run that logs the agents model would print its URL on stdout, among the results.
os.environ.setdefault("MLFLOW_ENABLE_ARTIFACTS_PROGRESS_BAR", "false")
os.environ.setdefault("MLFLOW_SUPPRESS_PRINTING_URL_TO_STDOUT", "true")
# MLflow retries each HTTP call 7 times with doubling waits (~4 min a call, sized for a hosted
# service's rate limits) and _retry below tries each call 5 times on top, so a tracking server that
# died mid-sweep took 29 min to be reported (53 s now). Two retries a call ride out a restart; a
# value the user set wins.
os.environ.setdefault("MLFLOW_HTTP_REQUEST_MAX_RETRIES", "2")

# The names the runner imports from here (plain re-exports; everything else is imported from
# its module: store, connection, logged, runs, trackers, tags).
from pcpg_dist.tracking.children import log_environment, log_environments  # noqa: E402
from pcpg_dist.tracking.trackers import Tracker  # noqa: E402

__all__ = ["Tracker", "log_environment", "log_environments"]
