"""Messages that stay one line and name what the user probably meant.

A config key, a plugin's setting and a value quoted back all end in a one-line error; the text is
built here, at the bottom, so the domain API (a plugin's own settings) and the config layer say it
in the same words without importing each other.
"""

from __future__ import annotations

import difflib
import typing

from pydantic import BaseModel

MAX_SHOWN = 200  # characters of a value quoted in an error message


def one_line(text: str, limit: int = 3 * MAX_SHOWN) -> str:
    """``text`` on one line (control characters shown escaped), cut to ``limit`` characters."""
    text = "".join(c if c.isprintable() else repr(c)[1:-1] for c in text[: 2 * limit])
    return text if len(text) <= limit else text[:limit] + "..."


def settable_keys(model: type[BaseModel], prefix: str = "") -> list[str]:
    """Every settable dotted key. An optional section (``gridworld.random_layouts: {count, seed} |
    None``) is settable whole and key by key (``gridworld.random_layouts.count=2``)."""
    out: list[str] = []
    for name, field in model.model_fields.items():
        key = f"{prefix}{name}"
        ann = field.annotation
        if isinstance(ann, type) and issubclass(ann, BaseModel):
            out += settable_keys(ann, key + ".")
            continue
        out.append(key)
        for arg in typing.get_args(ann):  # Optional[Model]: its keys too
            if isinstance(arg, type) and issubclass(arg, BaseModel):
                out += settable_keys(arg, key + ".")
    return out


def closest_key(key: str, keys: list[str]) -> str | None:
    """The key of ``keys`` (every valid one) nearest to a misspelt ``key`` (a section name for a misspelt section), or None."""
    depth = key.count(".")
    sections = {k.rsplit(".", k.count(".") - depth)[0] for k in keys if k.count(".") > depth}
    close = difflib.get_close_matches(key, [*keys, *sorted(sections)], n=1, cutoff=0.5)
    if not close:
        return None
    head, tops = key.split(".")[0], {k.split(".")[0] for k in keys}
    if (
        "." in key
        and head not in tops
        and not difflib.get_close_matches(head, tops, n=1, cutoff=0.6)
    ):
        # a section unlike any (another domain's, or an abbreviation like `eval`): only a setting of
        # the same name is a useful guess (`eval.greedy` -> evaluation.greedy, not `corridor.length`
        # -> mario.event)
        name, guess = key.rsplit(".", 1)[1], close[0].rsplit(".", 1)[-1]
        if not difflib.get_close_matches(name, [guess], n=1, cutoff=0.6):
            return None
    return close[0]


def unknown_key_message(key: str, keys: list[str]) -> str:
    """What a config file (or a plugin's section) says of a key that is no setting: the closest of ``keys``
    (every valid key)."""
    close = closest_key(key, keys)
    hint = f"; did you mean {close!r}?" if close else " (check the spelling)"
    if "." not in key:
        return f"unknown top-level key '{key[:120]}' — not a section or setting of a config{hint}"
    return f"unknown key '{key[:120]}' — not a setting of section '{key.rsplit('.', 1)[0][:120]}'{hint}"
