"""Reading a config's YAML safely: bounded in size, nodes and depth, numbers read as YAML 1.2.

A config comes from a user's file or a command-line value; either is read here once, checked
before any Python value is built (an alias bomb stops at the node count), so the config model and
the override parser share one reader and one set of messages.
"""

from __future__ import annotations

import re
import reprlib
from pathlib import Path
from typing import Any

import yaml

from pcpg_dist.common.errors import ConfigError
from pcpg_dist.common.messages import MAX_SHOWN, one_line

MAX_CONFIG_BYTES = 1 << 20  # a config is a page of settings; a megabyte is far beyond any real one
MAX_YAML_NODES = 100_000  # values after alias expansion: a 'billion laughs' file stops here
MAX_YAML_DEPTH = 50  # nesting of lists and mappings


class _BoundedLoader(yaml.SafeLoader):
    """PyYAML's safe loader, with the composed node graph measured before any Python value is
    built: aliases are shared nodes there, so a file of a few lines cannot expand into gigabytes.

    Numbers are read as YAML 1.2 reads them: ``2:8:1`` is text (a sweep range), not YAML 1.1's
    base-60 integer 7681, and ``1e-3`` is a number, not text.

    A key given twice in one mapping is refused (PyYAML keeps the last one without a word, so a
    second ``bc:`` section would drop every key of the first); a key that overrides one brought in
    by a ``<<: *alias`` merge is YAML's way of extending a mapping and stays allowed."""

    source = "<yaml>"  # names the text in a ConfigError

    def construct_mapping(self, node: yaml.MappingNode, deep: bool = False) -> dict:
        first_line: dict[Any, int] = {}
        for (
            key_node,
            _,
        ) in node.value:  # before SafeConstructor flattens the merge keys into the list
            if (
                not isinstance(key_node, yaml.ScalarNode)
                or key_node.tag == "tag:yaml.org,2002:merge"
            ):
                continue
            key = self.construct_object(key_node)
            line = key_node.start_mark.line + 1
            try:
                first = first_line.get(key)
            except TypeError:  # an unhashable key: SafeConstructor's own message names it
                continue
            if first is not None:
                raise ConfigError(
                    f"{self.source}, line {line}: key {reprlib.repr(key)} appears twice "
                    f"(first on line {first}); give each key once"
                )
            first_line[key] = line
        return super().construct_mapping(node, deep=deep)


_INT, _FLOAT = "tag:yaml.org,2002:int", "tag:yaml.org,2002:float"
_BoundedLoader.yaml_implicit_resolvers = {
    first: [(tag, rx) for tag, rx in items if tag not in (_INT, _FLOAT)]
    for first, items in yaml.SafeLoader.yaml_implicit_resolvers.items()
}
_BoundedLoader.add_implicit_resolver(
    _INT,
    re.compile(r"^(?:[-+]?0b[0-1_]+|[-+]?0x[0-9a-fA-F_]+|[-+]?(?:0|[1-9][0-9_]*))$"),
    list("-+0123456789"),
)
_BoundedLoader.add_implicit_resolver(
    _FLOAT,
    re.compile(
        r"""^(?:[-+]?(?:[0-9][0-9_]*\.[0-9_]*(?:[eE][-+]?[0-9]+)?
                        |[0-9][0-9_]*[eE][-+]?[0-9]+
                        |\.[0-9_]+(?:[eE][-+]?[0-9]+)?)
                        |[-+]?\.(?:inf|Inf|INF)|\.(?:nan|NaN|NAN))$""",
        re.X,
    ),
    list("-+0123456789."),
)


def _expanded_size(node: yaml.Node, path: str) -> int:
    """Number of values ``node`` expands to (aliases counted every time they are used)."""
    memo: dict[int, int] = {}
    active: set[int] = set()

    def size(n: yaml.Node, depth: int) -> int:
        if id(n) in memo:
            return memo[id(n)]
        if id(n) in active:
            raise ConfigError(
                f"{path}, line {n.start_mark.line + 1}: a YAML alias refers to a value that "
                f"contains it (a recursive structure); write the values out"
            )
        if depth > MAX_YAML_DEPTH:
            raise ConfigError(
                f"{path}, line {n.start_mark.line + 1}: nested more than {MAX_YAML_DEPTH} "
                f"levels deep; a config needs a few"
            )
        active.add(id(n))
        if isinstance(n, yaml.SequenceNode):
            total = 1 + sum(size(c, depth + 1) for c in n.value)
        elif isinstance(n, yaml.MappingNode):
            total = 1 + sum(size(k, depth + 1) + size(v, depth + 1) for k, v in n.value)
        else:
            total = 1
        active.discard(id(n))
        if total > MAX_YAML_NODES:
            raise ConfigError(
                f"{path}, line {n.start_mark.line + 1}: expands to more than {MAX_YAML_NODES} "
                f"values (YAML aliases repeat what they refer to); a config needs far fewer"
            )
        memo[id(n)] = total
        return total

    return size(node, 0)


def read_yaml(path: Path, what: str = "config") -> Any:
    """A bounded YAML read: a regular file of at most MAX_CONFIG_BYTES, UTF-8, at most
    MAX_YAML_NODES values after alias expansion, at most MAX_YAML_DEPTH levels deep."""
    try:
        if not path.is_file():
            reason = "not found" if not path.exists() else "not a regular file"
            raise ConfigError(f"{path}: cannot read {what} ({reason})")
        size = path.stat().st_size
        if size > MAX_CONFIG_BYTES:
            raise ConfigError(
                f"{path}: {size} bytes; a {what} file may hold at most {MAX_CONFIG_BYTES} bytes "
                f"(is this the right file?)"
            )
        with open(path, "rb") as f:
            raw = f.read(MAX_CONFIG_BYTES + 1)
    except OSError as e:
        raise ConfigError(f"{path}: cannot read {what} ({e.strerror or e})") from None
    if len(raw) > MAX_CONFIG_BYTES:  # the file grew while we looked
        raise ConfigError(f"{path}: a {what} file may hold at most {MAX_CONFIG_BYTES} bytes")
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as e:
        line = raw[: e.start].count(b"\n") + 1
        raise ConfigError(
            f"{path}, line {line}: not UTF-8 text (byte {e.start}); save the file as UTF-8"
        ) from None
    if "\x00" in text:
        raise ConfigError(f"{path}: contains a NUL character; a {what} is a text file")
    return load_yaml_text(text, str(path))


def load_yaml_text(text: str, path: str) -> Any:
    """YAML text as a config file's is read (YAML 1.2 numbers, bounded expansion and depth);
    ``path`` names the text in a ConfigError."""
    try:
        loader = _BoundedLoader(text)  # its reader rejects control characters at once
        loader.source = path
    except yaml.YAMLError as e:
        raise ConfigError(one_line(f"{path}: not valid YAML ({e})".split("\n")[0])) from None
    try:
        node = loader.get_single_node()
        if node is None:
            return None
        _expanded_size(node, path)
        return loader.construct_document(node)
    except yaml.YAMLError as e:
        mark = getattr(e, "problem_mark", None)
        where = f", line {mark.line + 1}" if mark else ""
        problem = str(getattr(e, "problem", None) or e).replace("\n", " ")[:MAX_SHOWN]
        raise ConfigError(f"{path}{where}: not valid YAML ({problem})") from None
    except RecursionError:
        raise ConfigError(
            f"{path}: nested too deeply to read; a config needs a few levels"
        ) from None
    finally:
        loader.dispose()
