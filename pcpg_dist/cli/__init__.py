"""The ``pcpg`` command line. Every user mistake prints one line and exits with code 2.

:mod:`.parser` builds the argument parser; :mod:`.running` holds the commands that run the
pipeline, :mod:`.reading` those that read what runs left. Each imports what it needs when called,
so `pcpg --help` imports no torch, Ray or MLflow.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import os
import sys

from pcpg_dist.cli.parser import build_parser
from pcpg_dist.cli.running import _print_points, trial_counts
from pcpg_dist.common.disk import disk_full, is_disk_full
from pcpg_dist.common.errors import PcpgError, Terminated, catch_sigterm, shorten

__all__ = [
    "build_parser",
    "main",
    "parse_args",
    "trial_counts",
    "_print_points",
]


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    """The parsed command line; ``quiet`` and ``verbose`` hold whether given before or after the command."""
    parser = build_parser()
    args, extra = parser.parse_known_args(argv)
    # KEY=VALUE items after an option (`pcpg run c.yaml --quiet bc.lr=0.1`) belong to the command
    target = (
        "axes" if hasattr(args, "axes") else "overrides" if hasattr(args, "overrides") else None
    )
    if extra and (target is None or any(e.startswith("-") for e in extra)):
        parser.error(f"unrecognized arguments: {' '.join(extra)}")
    if extra:
        setattr(args, target, [*getattr(args, target), *extra])
    args.quiet = args.global_quiet or getattr(
        args, "quiet", False
    )  # `pcpg -q run` or `pcpg run -q`
    return args


def _parse_shortened(argv: list[str] | None) -> argparse.Namespace:
    """:func:`parse_args`, with argparse's error lines shortened: it echoes a bad argument whole
    (``invalid choice: '<5,000 characters>'``)."""
    said = io.StringIO()
    try:
        with contextlib.redirect_stderr(said):
            return parse_args(argv)
    finally:
        sys.stderr.write(shorten(said.getvalue()))


def _error(line: str) -> None:
    """An error line, any value it echoes cut short (:func:`~pcpg_dist.common.errors.shorten`)."""
    print(shorten(line), file=sys.stderr)


def main(argv: list[str] | None = None) -> int:
    args = _parse_shortened(argv)
    from pcpg_dist.common.progress import setup_output

    setup_output(
        quiet=args.quiet,
        verbose=args.verbose,
        private_ray=not (getattr(args, "ray_address", None) or os.environ.get("RAY_ADDRESS")),
    )
    try:
        catch_sigterm()
        args.func(args)
    except PcpgError as e:
        _error(f"pcpg: error: {e}")
        return 2
    except OSError as e:
        # Disk full, permission denied, missing folder: say which file and why, no traceback.
        if is_disk_full(e):
            _error(f"pcpg: error: {disk_full(e.filename or os.getcwd())}")
            return 2
        where = f" {e.filename}" if getattr(e, "filename", None) else ""
        _error(f"pcpg: error: cannot access{where}: {e.strerror or e}")
        return 2
    except KeyboardInterrupt as e:
        from pcpg_dist.common import errors

        terminated = isinstance(e, Terminated) or errors.sigterm_received
        print(
            f"pcpg: interrupted{' (SIGTERM)' if terminated else ''}; rerun the same command to resume",
            file=sys.stderr,
        )
        return 143 if terminated else 130
    return 0
