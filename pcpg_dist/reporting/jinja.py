"""The Jinja environment every page is rendered with (a run's report, its Markdown twin, a sweep's
page): the templates in ``pcpg_dist/reporting/templates``, autoescaped HTML, undefined names an
error, and the ``md`` filter that escapes a Markdown cell."""

from __future__ import annotations


def _md_escape(value) -> str:
    """Text for a Markdown table cell or line: markup characters escaped, no line breaks."""
    text = str(value).replace("\r", " ").replace("\n", " ")
    for ch in "\\`*_[]<>|#!":
        text = text.replace(ch, "\\" + ch)
    return text


def jinja_environment():
    """The Jinja environment of every page: the package's templates, autoescaped HTML, undefined
    names an error, and the ``md`` filter for Markdown cells."""
    from jinja2 import Environment, PackageLoader, StrictUndefined, select_autoescape

    env = Environment(
        loader=PackageLoader("pcpg_dist.reporting", "templates"),
        undefined=StrictUndefined,
        autoescape=select_autoescape(["html.j2"]),
        trim_blocks=True,
        lstrip_blocks=True,
    )
    env.filters["md"] = _md_escape
    return env
