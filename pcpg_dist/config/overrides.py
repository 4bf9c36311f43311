"""``key=value`` overrides on the command line, and the ``sweep:`` section of a config.

``pcpg run CONFIG bc.lr=0.003 clustering.k=5`` changes dotted keys of the YAML before it is
validated, so an override is checked exactly like the file: a value is read as YAML (``0.003``,
``[1, 0.5]``, ``true``, ``1e-3``), an unknown key is one line naming the closest valid key.

A sweep's axes are dotted keys with a list of values: ``AXIS=v1,v2,...`` on the command line, a
range ``start:stop:step`` (stop included), or the YAML section::

    sweep:
      grid:                      # every combination of these axes
        pbtg.noise_max: 0:0.6:0.1
        clustering.k: [2, 4, 8]
      zip:                       # axes that move together (equal lengths), crossed with the grid
        bc.hidden_size: [8, 16, 32]
        bc.epochs: [200, 400, 800]
"""

from __future__ import annotations

import copy
import itertools
import json
import math
import re
import reprlib
from pathlib import Path
from typing import Any

from pcpg_dist.common import messages
from pcpg_dist.common.errors import ConfigError
from pcpg_dist.config.experiment import parse_config, valid_keys
from pcpg_dist.config.yaml_io import load_yaml_text, read_yaml

MAX_POINTS = 10_000  # a sweep of more points is a typo, not an experiment
_NUMBER = re.compile(r"^[+-]?(\d+\.?\d*|\.\d+)([eE][+-]?\d+)?$")
_OPEN_SECTIONS = {"plugin", "gymnasium_kwargs"}  # free-form mappings: any sub-key is allowed


def closest_key(key: str, domain: str | None) -> str | None:
    """The valid key of a config for ``domain`` nearest to a misspelt ``key``, or None."""
    return messages.closest_key(key, valid_keys(domain))


def check_key(key: str, domain: str | None) -> None:
    """Raise a one-line :class:`ConfigError` naming the closest valid key when ``key`` is unknown."""
    if key in valid_keys(domain, other_domains=False):  # the common case, without importing
        return  # the other built-in domains' settings
    keys = valid_keys(domain)
    if key in keys or any(
        key.startswith(f"{k}.") for k in keys if k.split(".")[-1] in _OPEN_SECTIONS
    ):
        return
    if any(k.startswith(key + ".") for k in keys):
        raise ConfigError(
            f"override {key!r} names a whole section; set one of its keys, e.g. "
            f"{next(k for k in keys if k.startswith(key + '.'))}=..."
        )
    close = closest_key(key, domain)
    hint = f"; did you mean {close!r}?" if close else "; `pcpg run --help` shows the sections"
    raise ConfigError(f"unknown config key {key[:120]!r}{hint}")


def parse_value(text: str) -> Any:
    """A command-line value as a config file's YAML reads it: ``1e-3`` a number, ``1:30`` text (YAML
    1.1 would read them as text and as the base-60 integer 90)."""
    text = text.strip()
    if _NUMBER.match(text):
        return int(text) if re.fullmatch(r"[+-]?\d+", text) else float(text)
    if len(text) > 10_000:
        return text
    try:
        return load_yaml_text(text, "command-line value")
    except (
        ConfigError
    ):  # not YAML (or an alias bomb): the text itself, which the key's check judges
        return text


def split_assignment(item: str) -> tuple[str, str]:
    key, sep, value = item.partition("=")
    key = key.strip()
    if not sep or not key or not re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*(\.[A-Za-z0-9_]+)*", key):
        raise ConfigError(f"{item[:120]!r} is not KEY=VALUE with a dotted key, e.g. bc.lr=0.003")
    return key, value


def split_assignments(
    items: list[str], what: str = "override", form: str = "{key}=VALUE"
) -> list[tuple[str, str]]:
    """``KEY=VALUE`` items as (key, value) pairs, a key given twice refused: the last one would win
    without a word. ``what`` and ``form`` say what an item is and how to give it once."""
    first: dict[str, str] = {}
    pairs = []
    for item in items:
        key, value = split_assignment(item)
        if key in first:
            raise ConfigError(
                f"{what} {key!r} is given twice on the command line ({reprlib.repr(first[key])} and "
                f"{reprlib.repr(item)}); give it once as {form.format(key=key)}"
            )
        first[key] = item
        pairs.append((key, value))
    return pairs


def set_key(raw: dict, key: str, value: Any) -> None:
    node = raw
    parts = key.split(".")
    for part in parts[:-1]:
        child = node.get(part)
        if child is None:
            child = node[part] = {}
        if not isinstance(child, dict):
            raise ConfigError(f"override {key!r}: {part!r} holds a value, not a section")
        node = child
    node[parts[-1]] = value


def apply_overrides(raw: dict, overrides: dict[str, Any]) -> dict:
    """A copy of the raw config mapping with dotted keys set (each key checked first)."""
    out = copy.deepcopy(raw)
    domain = out.get("domain") if isinstance(out.get("domain"), str) else None
    for key, value in overrides.items():
        check_key(key, domain)
        set_key(out, key, value)
    return out


def parse_overrides(items: list[str]) -> dict[str, Any]:
    return {k: parse_value(v) for k, v in split_assignments(items)}


def read_raw(path: str | Path) -> tuple[dict, dict | None]:
    """The config mapping of a YAML file (bounded read) and its ``sweep:`` section, split off."""
    raw = read_yaml(Path(path))
    if not isinstance(raw, dict):
        raise ConfigError(f"{path}: a config must be a YAML mapping of keys to values")
    raw = dict(raw)
    return raw, raw.pop("sweep", None)


def load_config_with(path: str | Path, overrides: list[str] | None = None):
    """:func:`~pcpg_dist.config.load_config` with ``key=value`` overrides applied before validation
    (a ``sweep:`` section is not part of a single run's config and is left out)."""
    path = Path(path)
    raw, _ = read_raw(path)
    raw = apply_overrides(raw, parse_overrides(overrides or []))
    return parse_config(raw, source=str(path), base_dir=path.parent)


# --------------------------------------------------------------------------- sweep axes
def parse_range(text: str) -> list[float] | None:
    """``start:stop:step`` (stop included, up to float rounding) or ``None`` if ``text`` is not one."""
    parts = text.split(":")
    if len(parts) != 3 or not all(_NUMBER.match(p.strip()) for p in parts):
        return None
    start, stop, step = (float(p) for p in parts)
    if step <= 0 or stop < start:
        raise ConfigError(f"range {text!r}: needs start <= stop and a positive step")
    span = (stop - start) / step  # inf or above 2**63 for 1e308:1e309:1 or 0:1e300:1e-300
    if not span < MAX_POINTS:
        raise ConfigError(
            f"range {text!r} has more than {MAX_POINTS} values; a sweep axis may have at most "
            f"{MAX_POINTS}"
        )
    n = int(round(span)) + 1
    if n > MAX_POINTS:
        raise ConfigError(
            f"range {text!r} has {n} values; a sweep axis may have at most {MAX_POINTS}"
        )
    ints = all(float(p).is_integer() and "." not in p for p in parts)
    values = [
        start + i * step for i in range(n) if start + i * step <= stop + 1e-9 * max(1.0, abs(step))
    ]
    return [int(v) for v in values] if ints else [round(v, 10) for v in values]


def axis_values(key: str, spec: Any) -> list[Any]:
    """An axis' values from YAML (a list, or a range string) or the command line (``v1,v2``)."""
    if isinstance(spec, list):
        values = spec
    elif isinstance(spec, str):
        try:
            values = parse_range(spec.strip())
        except ConfigError as e:
            raise ConfigError(f"sweep axis {key!r}: {e}") from None
        if values is None:
            values = [parse_value(v) for v in _split_commas(spec)]
    else:
        values = [spec]
    if not values:
        raise ConfigError(f"sweep axis {key!r} has no values")
    if len(values) > MAX_POINTS:
        raise ConfigError(f"sweep axis {key!r} has {len(values)} values; at most {MAX_POINTS}")
    seen: set[str] = set()
    for v in values:  # a repeat would run one point twice into one folder
        shown = json.dumps(v, sort_keys=True, default=str)
        if shown in seen:
            raise ConfigError(
                f"sweep axis {key!r} repeats the value {reprlib.repr(v)}; give each value once"
            )
        seen.add(shown)
    return values


def _split_commas(text: str) -> list[str]:
    """``a,b,[1,2]``: commas inside brackets belong to a value."""
    out, depth, cur = [], 0, ""
    for ch in text:
        if ch in "[{":
            depth += 1
        elif ch in "]}":
            depth -= 1
        if ch == "," and depth == 0:
            out.append(cur)
            cur = ""
        else:
            cur += ch
    out.append(cur)
    return [v for v in (s.strip() for s in out) if v]


def split_sweep_items(items: list[str]) -> tuple[list[str], list[str]]:
    """``pcpg sweep``'s ``KEY=...`` items as (axes, fixed overrides). An axis has two or more values
    (``v1,v2``: commas inside brackets belong to a value) or is a ``start:stop:step`` range; any other
    item is one value, a fixed override, so ``ranking.ps=[1.0,0.5]`` sets one list as ``pcpg run``
    would."""
    axes, fixed = [], []
    for item in items:
        value = item.partition("=")[2]
        try:
            is_range = parse_range(value.strip()) is not None
        except ConfigError:  # a malformed range: an axis, whose check names the mistake
            is_range = True
        (axes if is_range or len(_split_commas(value)) > 1 else fixed).append(item)
    return axes, fixed


def sweep_points(
    section: Any, cli_axes: list[str], domain: str | None
) -> tuple[dict[str, list], list[dict[str, Any]]]:
    """The axes (key -> values) and the points (one override mapping each) of a sweep."""
    grid: dict[str, list] = {}
    zipped: dict[str, list] = {}
    if section is not None:
        if not isinstance(section, dict) or set(section) - {"grid", "zip"}:
            raise ConfigError(
                "sweep: must be a mapping with 'grid:' and/or 'zip:' (each a mapping of "
                "dotted keys to lists of values or start:stop:step ranges)"
            )
        for name, target in (("grid", grid), ("zip", zipped)):
            axes = section.get(name) or {}
            if not isinstance(axes, dict):
                raise ConfigError(
                    f"sweep.{name}: must map dotted keys to values, e.g. bc.lr: [0.001, 0.01]"
                )
            for key, spec in axes.items():
                target[str(key)] = axis_values(str(key), spec)
    if both := sorted(set(grid) & set(zipped)):
        raise ConfigError(
            f"sweep: {both[0]!r} is under both 'grid:' and 'zip:'; an axis goes under one of them"
        )
    for key, value in split_assignments(cli_axes, "sweep axis", "{key}=v1,v2,..."):
        zipped.pop(key, None)  # an axis on the command line replaces the file's
        grid[key] = axis_values(key, value)
    for key in [*grid, *zipped]:
        check_key(key, domain)
    if zipped and len({len(v) for v in zipped.values()}) > 1:
        shown = ", ".join(f"{k} ({len(v)})" for k, v in zipped.items())
        raise ConfigError(
            f"sweep.zip: axes that move together need equally many values; got {shown}"
        )
    if not grid and not zipped:
        raise ConfigError(
            "a sweep needs at least one axis: AXIS=v1,v2 on the command line or a sweep: section"
        )
    n_zip = len(next(iter(zipped.values()))) if zipped else 1
    n_points = math.prod(len(v) for v in grid.values()) * n_zip  # counted before any is built
    if n_points > MAX_POINTS:
        raise ConfigError(f"the sweep has {n_points} points; at most {MAX_POINTS}")
    combos: list[dict[str, Any]] = [
        dict(zip(grid, vals, strict=True)) for vals in itertools.product(*grid.values())
    ]
    if zipped:
        rows = [{k: v[i] for k, v in zipped.items()} for i in range(n_zip)]
        combos = [{**c, **r} for c in combos for r in rows]
    return {**grid, **zipped}, combos
