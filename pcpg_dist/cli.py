"""The ``pcpg`` command line. Every user mistake prints one line and exits with code 2."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from pcpg_dist.errors import PcpgError


def _cmd_generate(args: argparse.Namespace) -> None:
    from pcpg_dist.config import load_config
    from pcpg_dist.generate import generate_to
    from pcpg_dist.progress import console
    from pcpg_dist.ray_utils import init_ray

    cfg = load_config(args.config)
    init_ray(args.ray_address)
    datasets = generate_to(cfg, Path(args.out), show_progress=not args.quiet)
    for env, ds in datasets.items():
        console.print(f"{env}: {ds.n_trajectories} trajectories, {ds.n_rows} rows, "
                      f"success {ds.success.mean():.3f}, mean length {ds.lengths.mean():.1f}")
    console.print(f"wrote {args.out}/manifest.json")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="pcpg", description="Play-style-centric agents from gameplay data (PCPG) at scale.")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    def common(p: argparse.ArgumentParser) -> None:
        p.add_argument("--ray-address", default=None,
                       help="join this Ray cluster (default: $RAY_ADDRESS, else Ray in-process)")
        p.add_argument("--quiet", action="store_true", help="no progress bars")

    p = sub.add_parser("generate", help="generate the datasets of a config (PBTG on Ray)")
    p.add_argument("config", help="experiment YAML")
    p.add_argument("--out", required=True, help="output folder (Parquet files + manifest.json)")
    common(p)
    p.set_defaults(func=_cmd_generate)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        args.func(args)
    except PcpgError as e:
        print(f"pcpg: error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("pcpg: interrupted; rerun the same command to resume", file=sys.stderr)
        return 130
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
