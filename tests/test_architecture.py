"""The package's shape, checked: layers import only downwards, no import loops, modules and
functions of readable size, and no domain named outside ``pcpg_dist/domains/``.

Every import counts, including those inside functions (an import inside a function still ties
two modules together); imports under ``if TYPE_CHECKING:`` are type hints only and do not.
The layers, bottom to top, are in :data:`LAYERS`; docs/architecture.md draws them.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "pcpg_dist"

#: bottom to top: a module may import its own layer (without loops) and the layers below it
LAYERS: list[tuple[str, tuple[str, ...]]] = [
    ("common", ("pcpg_dist.common",)),
    ("dataset", ("pcpg_dist.dataset",)),
    (
        "domain API",
        (
            "pcpg_dist.domains",
            "pcpg_dist.domains.base",
            "pcpg_dist.domains.registry",
            "pcpg_dist.domains.contract",
            "pcpg_dist.domains.sources",
            "pcpg_dist.domains.defaults",
        ),
    ),
    ("config", ("pcpg_dist.config",)),
    ("stages", ("pcpg_dist.stages",)),
    ("domains", ("pcpg_dist.domains.",)),  # the built-in domains, each a folder, like plugins
    ("pipeline", ("pcpg_dist.pipeline",)),
    ("orchestration", ("pcpg_dist.orchestration",)),
    ("tracking and reporting", ("pcpg_dist.tracking", "pcpg_dist.reporting")),
    ("api", ("pcpg_dist.api",)),
    ("face", ("pcpg_dist.cli", "pcpg_dist")),
]
MAX_MODULE_LINES = 400
MAX_FUNCTION_LINES = 80


def module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


MODULES = {module_name(p): p for p in sorted(PACKAGE.rglob("*.py"))}


def layer_of(module: str) -> int:
    """The layer a module belongs to: the most specific prefix wins (a full name, then a folder)."""
    best, best_len = -1, -1
    for i, (_, prefixes) in enumerate(LAYERS):
        for prefix in prefixes:
            whole = module == prefix
            inside = prefix.endswith(".") and module.startswith(prefix)
            below = not prefix.endswith(".") and module.startswith(prefix + ".")
            length = len(prefix) + (1 if whole else 0)
            if (whole or inside or below) and length > best_len:
                best, best_len = i, length
    return best


def _type_checking_lines(tree: ast.AST) -> set[int]:
    lines: set[int] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test):
            for sub in node.body:
                lines.update(range(sub.lineno, (sub.end_lineno or sub.lineno) + 1))
    return lines


def imports_of(module: str) -> dict[str, int]:
    """``{imported pcpg module: line}`` for every runtime import in ``module``."""
    path = MODULES[module]
    tree = ast.parse(path.read_text())
    skip = _type_checking_lines(tree)
    found: dict[str, int] = {}
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    for node in ast.walk(tree):
        if getattr(node, "lineno", 0) in skip:
            continue
        names: list[str] = []
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                up = package.split(".")[: len(package.split(".")) - (node.level - 1)]
                base = ".".join(up + ([node.module] if node.module else []))
            names = [
                f"{base}.{a.name}" if f"{base}.{a.name}" in MODULES else base for a in node.names
            ]
        for name in names:
            while name and name not in MODULES:
                name = name.rpartition(".")[0]
            if name.startswith("pcpg_dist") and name != module:
                found.setdefault(name, node.lineno)
    return found


GRAPH = {m: imports_of(m) for m in MODULES}


def test_every_module_has_a_layer():
    assert [m for m in MODULES if layer_of(m) < 0] == []


def test_no_import_points_up_a_layer():
    upward = [
        f"{MODULES[m].relative_to(ROOT)}:{line} imports {dep} "
        f"({LAYERS[layer_of(m)][0]} -> {LAYERS[layer_of(dep)][0]})"
        for m, deps in GRAPH.items()
        for dep, line in deps.items()
        if layer_of(dep) > layer_of(m) and dep != "pcpg_dist"
    ]
    assert upward == [], "\n".join(upward)


def test_tracking_and_reporting_do_not_import_each_other():
    crossing = [
        f"{m} imports {dep}"
        for m, deps in GRAPH.items()
        for dep in deps
        for a, b in (("pcpg_dist.tracking", "pcpg_dist.reporting"),) * 1
        if (m.startswith(a) and dep.startswith(b)) or (m.startswith(b) and dep.startswith(a))
    ]
    assert crossing == [], "\n".join(crossing)


def _cycles() -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    found: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in GRAPH[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    for v in GRAPH:
        if v not in index:
            visit(v)
    return found


def test_no_import_loops():
    # a package's __init__ importing its own submodules is not a loop of design
    loops = [c for c in _cycles() if not all(c[0] == x or x.startswith(c[0] + ".") for x in c)]
    assert loops == [], "\n".join(map(str, loops))


def test_modules_are_at_most_400_lines():
    long = {
        str(p.relative_to(ROOT)): n
        for p in MODULES.values()
        if (n := len(p.read_text().splitlines())) > MAX_MODULE_LINES
    }
    assert long == {}, "\n".join(f"{k} {v}" for k, v in sorted(long.items()))


def test_functions_are_at_most_80_lines():
    long = []
    for p in MODULES.values():
        for node in ast.walk(ast.parse(p.read_text())):
            if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
                n = node.end_lineno - node.lineno + 1
                if n > MAX_FUNCTION_LINES:
                    long.append(f"{p.relative_to(ROOT)}:{node.lineno} {node.name} ({n} lines)")
    assert long == [], "\n".join(long)


DOMAIN_NAMES = ("gridworld", "minidungeons", "mario", "trajectories")


def domain_mentions(name: str) -> list[str]:
    """Where code outside ``pcpg_dist/domains/`` names a built-in domain: a name or attribute
    holding it, or a string holding it (docstrings and comments may name domains). The
    string "trajectories" is also a plain word (a table column, a manifest key): it counts only
    where it is compared with something, as a domain's name would be."""
    named = []
    for m, p in MODULES.items():
        if m.startswith("pcpg_dist.domains"):
            continue
        tree = ast.parse(p.read_text())
        docstrings = {
            id(n.body[0].value)
            for n in ast.walk(tree)
            if isinstance(n, ast.Module | ast.ClassDef | ast.FunctionDef | ast.AsyncFunctionDef)
            and n.body
            and isinstance(n.body[0], ast.Expr)
            and isinstance(n.body[0].value, ast.Constant)
        }
        compared = {
            id(c) for n in ast.walk(tree) if isinstance(n, ast.Compare) for c in ast.walk(n)
        }
        for node in ast.walk(tree):
            if isinstance(node, ast.Constant) and isinstance(node.value, str):
                if id(node) in docstrings:
                    continue
                text = node.value.lower()
                if name == "trajectories":  # also a plain word: a column, a manifest key
                    hit = text == name and id(node) in compared
                else:
                    hit = name in text
            elif isinstance(node, ast.Name | ast.Attribute | ast.alias | ast.arg):
                ident = {ast.Name: "id", ast.Attribute: "attr", ast.alias: "name", ast.arg: "arg"}
                text = str(getattr(node, ident[type(node)])).lower()
                hit = text == name or (name != "trajectories" and name in text)
            else:
                continue
            if hit:
                named.append(f"{p.relative_to(ROOT)}:{getattr(node, 'lineno', '?')}")
    return named


@pytest.mark.parametrize("name", DOMAIN_NAMES)
def test_no_domain_is_named_outside_domains(name):
    assert domain_mentions(name) == []


if __name__ == "__main__":  # every finding, for whoever is mending them
    import sys

    checks = {
        "upward": test_no_import_points_up_a_layer,
        "crossing": test_tracking_and_reporting_do_not_import_each_other,
        "loops": test_no_import_loops,
        "modules": test_modules_are_at_most_400_lines,
        "functions": test_functions_are_at_most_80_lines,
    }
    for label, check in checks.items():
        if len(sys.argv) > 1 and label not in sys.argv[1:]:
            continue
        try:
            check()
        except AssertionError as e:
            found = e.args[0] if e.args else ""
            print(f"## {label}")
            print(found)
    if len(sys.argv) == 1 or "domains" in sys.argv[1:]:
        for name in DOMAIN_NAMES:
            for where in domain_mentions(name):
                print(f"## domain {name}: {where}")


@pytest.mark.parametrize(
    "command", [["format", "--check"], ["check"]], ids=["ruff format", "ruff check"]
)
def test_ruff_is_clean(command):
    """`ruff format --check` and `ruff check` (with McCabe complexity at most 20) pass on the
    whole repository, so CI's one test command checks formatting and lint too."""
    import subprocess
    import sys

    done = subprocess.run(
        [sys.executable, "-m", "ruff", *command, "."], cwd=ROOT, capture_output=True, text=True
    )
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-1000:]
