"""`pcpg reproduce RUN`: rerun a logged run from its record and say, metric by metric, whether
the numbers come out the same.

RUN is what `pcpg report` takes (a run's output folder, an MLflow run id or an experiment name).
Its ``summary/run.json`` holds the validated config (seeds and every path included), the config
hash, the git commit and package versions; ``summary/metrics.json`` the logged numbers. The
config is validated again and run in a fresh folder with tracking off, so nothing of the original
run (cache, outputs, MLflow runs) is read or touched. Wall-clock timings (``*seconds*``) are not
results and are left out of the comparison.

A metric *matches* when it is equal (``exact``; NaN equals NaN) or, where summation order can
differ (thread counts, BLAS builds), within ``|new - logged| <= atol + rtol * |logged|``
(``within``). The defaults are stated in every output.
"""

from __future__ import annotations

import math
import sys
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import TextIO

from pcpg_dist.common.errors import ConfigError, DataError
from pcpg_dist.reporting.report_data import read_metrics, read_run

RTOL = 1e-6  # default relative tolerance: float32 sums in another order stay well inside it
ATOL = 1e-9


@dataclass(frozen=True)
class Comparison:
    """One metric, logged against recomputed."""

    name: str
    logged: float | None
    new: float | None
    status: str  # "exact", "within", "differs", "missing" (not recomputed), "extra" (new only)

    @property
    def matches(self) -> bool:
        return self.status in ("exact", "within")


@dataclass
class Reproduction:
    """What a reproduction found: the comparisons, where it ran, and what else changed."""

    comparisons: list[Comparison]
    out_dir: Path | None
    rtol: float
    atol: float
    notes: list[str] = field(default_factory=list)
    input_changed: bool = False  # the data the config reads is not what the logged run read

    @property
    def ok(self) -> bool:
        return not self.input_changed and all(c.matches for c in self.comparisons)


def _is_result(name: str) -> bool:
    return "seconds" not in name  # timings differ between any two runs


def _number(v) -> float | None:
    try:
        return float(v)
    except (TypeError, ValueError):
        return None


def compare_metrics(
    logged: dict, new: dict, rtol: float = RTOL, atol: float = ATOL
) -> list[Comparison]:
    """Every result metric of either side, in name order, with its match status."""
    out = []
    for name in sorted(k for k in set(logged) | set(new) if _is_result(k)):
        a, b = _number(logged.get(name)), _number(new.get(name))
        if name not in new:
            status = "missing"
        elif name not in logged:
            status = "extra"
        elif a is None or b is None:
            status = "exact" if logged[name] == new[name] else "differs"
        elif a == b or (math.isnan(a) and math.isnan(b)):
            status = "exact"
        elif math.isfinite(a) and math.isfinite(b) and abs(b - a) <= atol + rtol * abs(a):
            status = "within"
        else:
            status = "differs"
        out.append(Comparison(name, a, b, status))
    return out


def _apart(workdir: Path, run_folder: Path) -> None:
    """The rerun's folder lies outside the run it reproduces (links resolved), checked before
    anything runs: a rerun inside it would leave its cache and outputs in the original run."""
    where, run = workdir.resolve(), run_folder.resolve()
    if where == run or where.is_relative_to(run):
        raise ConfigError(
            f"--workdir {workdir}: inside the run being reproduced ({run_folder}); a "
            "reproduction runs apart from it: choose a folder outside"
        )


def _fresh(workdir: Path | None, name: str) -> Path:
    if workdir is None:
        return Path(tempfile.mkdtemp(prefix=f"pcpg-reproduce-{name}-"))
    workdir = Path(workdir)
    if workdir.exists() and any(workdir.iterdir()):
        raise ConfigError(
            f"--workdir {workdir}: not empty; a reproduction runs in a fresh folder "
            "(give a new or empty folder)"
        )
    workdir.mkdir(parents=True, exist_ok=True)
    return workdir


def recorded_config(run: dict, source: Path):
    """The logged config, validated again by this code (one-line error if it no longer loads)."""
    from pcpg_dist.config import parse_config

    cfg = run.get("config")
    if not isinstance(cfg, dict):
        raise DataError(f"{source}: no 'config' object; is this a pcpg run.json?")
    return parse_config(cfg, source=str(source))


def code_notes(run: dict, cfg) -> list[str]:
    """What differs between the logged run's code and environment and this one."""
    from pcpg_dist.common.provenance import git_commit, versions

    notes = []
    prov = run.get("provenance", {})  # an object: read_run checked it
    logged_commit, now = prov.get("git_commit", "unknown"), git_commit()
    if logged_commit != now:
        notes.append(
            f"code: logged at commit {logged_commit}, reproducing at {now}; differences may "
            "come from the code change"
        )
    logged_versions = prov.get("versions") if isinstance(prov.get("versions"), dict) else {}
    changed = [
        f"{k} {v} -> {versions().get(k)}"
        for k, v in logged_versions.items()
        if versions().get(k, v) != v
    ]
    if changed:
        notes.append("package versions changed: " + ", ".join(changed))
    from pcpg_dist.pipeline.declared import CODE_VERSION

    if str(run.get("code_version", CODE_VERSION)) != str(CODE_VERSION):
        notes.append(
            f"cache code version: logged {run.get('code_version')}, now {CODE_VERSION} (a stage's "
            "numbers were meant to change)"
        )
    if run.get("config_hash") not in (None, cfg.hash()):
        notes.append(
            f"config hash: logged {run.get('config_hash')}, now {cfg.hash()} (a default or "
            "the config schema changed since)"
        )
    return notes


def input_note(run: dict, cfg) -> tuple[str | None, bool]:
    """``(note, changed)``: why the rerun may not read the logged run's data, and whether it
    surely does not. None when the keys agree or the run predates the record. The key holds the
    domain's settings as well as its files' digests, so where the config's hash changed too (a
    setting added to the schema since), a different key is said but not taken for changed data."""
    from pcpg_dist.pipeline.declared import input_key

    logged = run.get("input_key")
    if logged is None:
        return None, False
    now = input_key(cfg)
    if logged == now:
        return None, False
    if run.get("config_hash") not in (None, cfg.hash()):
        return (
            f"input key: logged {logged}, now {now}; the config hash changed too (above), so this "
            "may be the settings' schema rather than the data"
        ), False
    return (
        f"input data changed: the logged run read data of key {logged}, the files and settings "
        f"named by its config give {now} today (a log file edited or replaced since?); the "
        "metrics below compare runs on different data"
    ), True


def reproduce(
    summary: Path,
    workdir: Path | None = None,
    rtol: float = RTOL,
    atol: float = ATOL,
    show_progress: bool = False,
    source: str | None = None,
) -> Reproduction:
    """Rerun the run recorded in ``summary`` (Ray initialised by the caller) and compare;
    ``source``: what the user named (a run id, a folder) for the new run's recorded command."""
    from pcpg_dist.api.run import run_experiment

    summary = Path(summary)
    run = read_run(summary / "run.json")
    logged = read_metrics(summary / "metrics.json")
    cfg = recorded_config(run, summary / "run.json")
    note, changed = input_note(run, cfg)
    notes = code_notes(run, cfg) + ([note] if note else [])
    out = _fresh(workdir, cfg.name)
    result = run_experiment(
        cfg,
        workdir=out,
        track=False,
        show_progress=show_progress,
        command=f"pcpg reproduce {source or summary}",
    )
    return Reproduction(
        compare_metrics(logged, result.metrics, rtol, atol),
        result.out_dir,
        rtol,
        atol,
        notes,
        input_changed=changed,
    )


def _shown(v: float | None) -> str:
    return "—" if v is None else repr(v)


def print_reproduction(rep: Reproduction, file: TextIO | None = None) -> None:
    """One line per metric, then the verdict (results go to stdout)."""
    file = file or sys.stdout
    for note in rep.notes:
        print(f"note: {note}", file=file)
    width = max((len(c.name) for c in rep.comparisons), default=10)
    for c in rep.comparisons:
        line = f"{c.status:<8} {c.name:<{width}}  logged {_shown(c.logged)}  new {_shown(c.new)}"
        if c.status in ("within", "differs") and c.logged is not None and c.new is not None:
            line += f"  (diff {c.new - c.logged:+.3g})"
        print(line, file=file)
    counts = {
        s: sum(c.status == s for c in rep.comparisons)
        for s in ("exact", "within", "differs", "missing", "extra")
    }
    verdict = (
        "REPRODUCED"
        if rep.ok
        else "NOT REPRODUCED" + (" (input data changed)" if rep.input_changed else "")
    )
    print(
        f"{verdict}: {len(rep.comparisons)} metrics, {counts['exact']} exact, {counts['within']} within "
        f"tolerance (|new - logged| <= {rep.atol:g} + {rep.rtol:g} * |logged|), {counts['differs']} differ, "
        f"{counts['missing']} missing, {counts['extra']} new; outputs in {rep.out_dir}",
        file=file,
    )


def cli_reproduce(args) -> int:
    """`pcpg reproduce RUN`: exit 0 when every metric matches, 1 when some differ."""
    from pcpg_dist.api.report import resolve_summary
    from pcpg_dist.orchestration.ray_pool import init_ray

    if (
        args.rtol < 0
        or args.atol < 0
        or not (math.isfinite(args.rtol) and math.isfinite(args.atol))
    ):
        raise ConfigError(
            f"--rtol {args.rtol} / --atol {args.atol}: tolerances must be finite and >= 0"
        )
    # a run's summary fetched from MLflow lands in a private folder removed afterwards (it was a
    # fixed /tmp/pcpg-reproduce-logged shared by every user of the machine, never cleaned)
    with tempfile.TemporaryDirectory(prefix="pcpg-reproduce-") as downloads:
        summary, _ = resolve_summary(args.run, args.tracking_uri, Path(downloads))
        # everything a user can get wrong is checked before Ray and torch start
        run = read_run(summary / "run.json")
        cfg = recorded_config(run, summary / "run.json")
        read_metrics(summary / "metrics.json")
        # the data's digest before any rerun: on other data the numbers cannot be the same
        note, changed = input_note(run, cfg)
        if changed and not args.allow_changed_data:
            print(f"NOT REPRODUCED: {note}; nothing was rerun (--allow-changed-data reruns anyway)")
            return 1
        if args.workdir:
            _apart(Path(args.workdir), summary.parent)
        workdir = _fresh(Path(args.workdir) if args.workdir else None, cfg.name)
        init_ray(args.ray_address)
        rep = reproduce(
            summary, workdir, args.rtol, args.atol, show_progress=not args.quiet, source=args.run
        )
    print_reproduction(rep)
    return 0 if rep.ok else 1
