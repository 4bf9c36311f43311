"""GridWorld: PCPG's synthetic domain (10x10 grids, four reward functions = four play-styles).

Layouts are text files a designer can draw, one character per cell: ``.`` floor, ``#`` wall,
``S`` start, ``G`` goal, ``X`` trap, ``1`` bonus B1, ``2`` bonus B2. Row 0 is the top line;
x = column, y = row. Actions 0..3 = up, right, down, left; moving into a wall or off the grid is
invalid (masked). State = (x, y, b1, b2), b1/b2 = bonus already visited. G and traps are terminal.

The whole model is a table over the 4 * W * H states (:class:`GridTables`): value iteration,
Q-learning, sampling and rollouts all index it, so no Python runs per step of the hot loops.
"""

from __future__ import annotations

import warnings
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

import numpy as np

from pcpg_dist.common.errors import LayoutError
from pcpg_dist.domains.gridworld.settings import layout_size_problem

UP, RIGHT, DOWN, LEFT = 0, 1, 2, 3
MOVES = np.array([(0, -1), (1, 0), (0, 1), (-1, 0)])  # (dx, dy) per action
N_ACTIONS = 4
CHARS = set(".#SGX12")
#: Table 1 of the paper: reward for (G, B1, B2) per reward function R1..R4 (index 0..3).
REWARDS = np.array([[100, 0, 0], [100, 50, 0], [100, 0, 50], [100, 50, 50]], dtype=np.float64)
#: The (b1, b2) signature a style's optimal route must end with.
SIGNATURES = [(0, 0), (1, 0), (0, 1), (1, 1)]
STYLE_NAMES = ["R1 straight to G", "R2 B1 then G", "R3 B2 then G", "R4 B1+B2 then G"]
FEATURES = ("x", "y", "b1", "b2")


@dataclass(frozen=True, eq=False)
class Layout:
    """A validated grid. ``grid[y][x]`` is the character at column x, row y."""

    name: str
    grid: tuple[str, ...]

    @property
    def height(self) -> int:
        return len(self.grid)

    @property
    def width(self) -> int:
        return len(self.grid[0])

    def find(self, ch: str) -> list[tuple[int, int]]:
        return [(x, y) for y, row in enumerate(self.grid) for x, c in enumerate(row) if c == ch]

    @property
    def start(self) -> tuple[int, int]:
        return self.find("S")[0]

    @cached_property
    def tables(self) -> GridTables:
        return GridTables.build(self)

    def text(self) -> str:
        return "\n".join(self.grid) + "\n"


@dataclass(frozen=True, eq=False)
class GridTables:
    """Transition and reward tables over states ``s = ((y * W + x) * 2 + b1) * 2 + b2``."""

    next_state: np.ndarray  # (S, A) int64; invalid actions stay put
    valid: np.ndarray  # (S, A) bool
    reward: np.ndarray  # (4, S, A) float64, one slice per reward function
    terminal: np.ndarray  # (S,) bool: G or trap
    goal: np.ndarray  # (S,) bool: G
    features: np.ndarray  # (S, 4) float32: (x, y, b1, b2)
    start: int

    @staticmethod
    def build(layout: Layout) -> GridTables:
        w, h = layout.width, layout.height
        n = w * h * 4
        idx = np.arange(n)
        b2, b1, cell = idx % 2, (idx // 2) % 2, idx // 4
        x, y = cell % w, cell // w
        chars = np.array([list(r) for r in layout.grid])
        nxt = np.repeat(idx[:, None], N_ACTIONS, axis=1)
        valid = np.zeros((n, N_ACTIONS), bool)
        reward = np.zeros((4, n, N_ACTIONS))
        for a, (dx, dy) in enumerate(MOVES):
            nx, ny = x + dx, y + dy
            inside = (nx >= 0) & (nx < w) & (ny >= 0) & (ny < h)
            tile = np.full(n, "#")
            tile[inside] = chars[ny[inside], nx[inside]]
            ok = inside & (tile != "#")
            nb1 = b1 | (tile == "1")
            nb2 = b2 | (tile == "2")
            target = ((ny * w + nx) * 2 + nb1) * 2 + nb2
            nxt[ok, a] = target[ok]
            valid[:, a] = ok
            for r in range(4):
                gain = (
                    REWARDS[r, 0] * (tile == "G")
                    + REWARDS[r, 1] * ((tile == "1") & (b1 == 0))
                    + REWARDS[r, 2] * ((tile == "2") & (b2 == 0))
                )
                reward[r, ok, a] = gain[ok]
        here = chars[y, x]
        terminal = (here == "G") | (here == "X")
        valid[terminal] = False  # nothing to do after the episode ended
        sx, sy = layout.start
        return GridTables(
            next_state=nxt,
            valid=valid,
            reward=reward,
            terminal=terminal,
            goal=here == "G",
            features=np.stack([x, y, b1, b2], axis=1).astype(np.float32),
            start=int((sy * w + sx) * 4),
        )

    def state_index(self, features: np.ndarray, width: int) -> np.ndarray:
        f = np.asarray(features, np.int64)
        return ((f[..., 1] * width + f[..., 0]) * 2 + f[..., 2]) * 2 + f[..., 3]


# ----------------------------------------------------------------------- layouts
def parse_layout(text: str, name: str = "<layout>", check_styles: bool = True) -> Layout:
    """Parse and validate a layout; every problem raises :class:`LayoutError` naming ``name``."""
    lines = [ln.rstrip("\r") for ln in text.splitlines()]
    while lines and not lines[-1].strip():
        lines.pop()
    if not lines:
        raise LayoutError(f"{name}: empty layout")
    if problem := layout_size_problem(text):
        raise LayoutError(f"{name}: {problem}")
    width = len(lines[0])
    for i, ln in enumerate(lines, 1):
        if len(ln) != width:
            raise LayoutError(
                f"{name}, line {i}: {len(ln)} characters, expected {width} like line 1"
            )
        bad = set(ln) - CHARS
        if bad:
            raise LayoutError(
                f"{name}, line {i}: unknown character {sorted(bad)[0]!r}; allowed: . # S G X 1 2"
            )
    if width < 2 or len(lines) < 2:
        raise LayoutError(f"{name}: a layout needs at least 2 rows and 2 columns")
    layout = Layout(name=name, grid=tuple(lines))
    for ch, what in (("S", "start"), ("G", "goal"), ("1", "bonus B1"), ("2", "bonus B2")):
        found = len(layout.find(ch))
        if found != 1:
            raise LayoutError(f"{name}: needs exactly one {ch!r} ({what}), found {found}")
    _check_reachability(layout)
    if check_styles:
        problem = style_problem(layout)
        if problem:
            warnings.warn(
                f"{name}: {problem}; clustering cannot tell those styles apart", stacklevel=2
            )
    return layout


def load_layout(path: str | Path, check_styles: bool = True) -> Layout:
    path = Path(path)
    try:
        if path.is_file() and path.stat().st_size > 1 << 20:
            raise LayoutError(
                f"{path}: {path.stat().st_size} bytes; a layout file may hold at most {1 << 20}"
            )
        text = path.read_text(encoding="utf-8")
    except OSError as e:
        raise LayoutError(f"{path}: cannot read layout file ({e.strerror})") from None
    except UnicodeDecodeError as e:
        raise LayoutError(
            f"{path}: not UTF-8 text (byte {e.start}); save the layout as UTF-8"
        ) from None
    # Errors name the file; the layout itself is named by its stem (E1, E2, ...).
    layout = parse_layout(text, name=str(path), check_styles=check_styles)
    return Layout(name=path.stem, grid=layout.grid)


def _reach(layout: Layout, source: tuple[int, int]) -> set[tuple[int, int]]:
    """Cells reachable from ``source`` without entering walls or traps or passing through G."""
    seen, queue = {source}, deque([source])
    while queue:
        x, y = queue.popleft()
        if layout.grid[y][x] == "G" and (x, y) != source:
            continue
        for dx, dy in MOVES:
            nx, ny = x + dx, y + dy
            if (
                0 <= nx < layout.width
                and 0 <= ny < layout.height
                and (nx, ny) not in seen
                and layout.grid[ny][nx] not in "#X"
            ):
                seen.add((nx, ny))
                queue.append((nx, ny))
    return seen


def _check_reachability(layout: Layout) -> None:
    start, goal = layout.start, layout.find("G")[0]
    from_start = _reach(layout, start)
    if goal not in from_start:
        raise LayoutError(
            f"{layout.name}: the goal G is not reachable from S without crossing a trap or wall"
        )
    for ch in "12":
        bonus = layout.find(ch)[0]
        if bonus not in from_start:
            raise LayoutError(f"{layout.name}: bonus {ch} is not reachable from S avoiding traps")
        if goal not in _reach(layout, bonus):
            raise LayoutError(f"{layout.name}: G is not reachable after bonus {ch}")


# ----------------------------------------------------------------------- planning
def value_iteration(
    tables: GridTables,
    reward_index: int,
    gamma: float = 0.99,
    tol: float = 1e-10,
    max_iter: int = 10_000,
) -> np.ndarray:
    """Optimal Q (S, A) for reward function ``reward_index``; invalid actions get -inf."""
    r = tables.reward[reward_index]
    cont = ~tables.terminal[tables.next_state]
    v = np.zeros(len(tables.terminal))
    for _ in range(max_iter):
        q = r + gamma * v[tables.next_state] * cont
        q = np.where(tables.valid, q, -np.inf)
        new_v = np.where(tables.terminal, 0.0, q.max(axis=1, initial=-np.inf))
        new_v[~np.isfinite(new_v)] = 0.0
        if np.abs(new_v - v).max() < tol:
            break
        v = new_v
    return q


def greedy_actions(q: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """Argmax over valid actions per state (ties to the lowest action); 0 where none is valid."""
    return np.argmax(np.where(valid, q, -np.inf), axis=1)


def greedy_route(tables: GridTables, actions: np.ndarray, max_steps: int = 100) -> list[int]:
    """States visited by a deterministic policy from the start state."""
    s, route = tables.start, [tables.start]
    for _ in range(max_steps):
        if tables.terminal[s]:
            break
        s = int(tables.next_state[s, actions[s]])
        route.append(s)
    return route


def route_return(tables: GridTables, route: list[int], reward_index: int) -> float:
    r = tables.reward[reward_index]
    return float(
        sum(
            r[s, a]
            for s, s2 in zip(route, route[1:], strict=False)
            for a in np.nonzero(tables.next_state[s] == s2)[0][:1]
        )
    )


def optimal_routes(layout: Layout, gamma: float = 0.99, max_steps: int = 100) -> list[list[int]]:
    t = layout.tables
    return [
        greedy_route(t, greedy_actions(value_iteration(t, r, gamma), t.valid), max_steps)
        for r in range(4)
    ]


def optimal_return(
    layout: Layout, reward_index: int, gamma: float = 0.99, max_steps: int = 100
) -> float:
    """Undiscounted return of the optimal (value-iteration) policy's rollout under R."""
    return route_return(
        layout.tables, optimal_routes(layout, gamma, max_steps)[reward_index], reward_index
    )


def style_problem(layout: Layout, gamma: float = 0.99, max_steps: int = 100) -> str | None:
    """Why the four styles' optimal behaviour is not distinct in this layout, or None if it is."""
    t = layout.tables
    routes = optimal_routes(layout, gamma, max_steps)
    problems = []
    for r, route in enumerate(routes):
        end = route[-1]
        flags = tuple(int(v) for v in t.features[end, 2:])
        if not t.goal[end]:
            problems.append(f"R{r + 1}'s optimal route does not reach G")
        elif flags != SIGNATURES[r]:
            problems.append(
                f"R{r + 1}'s optimal route ends with (b1, b2) = {flags}, not {SIGNATURES[r]}"
            )
    cells = [tuple(int(s) // 4 for s in route) for route in routes]
    shared: set[int] = set()
    for i in range(4):
        for j in range(i + 1, 4):
            if cells[i] == cells[j]:
                problems.append(f"R{i + 1} and R{j + 1} follow the same route")
            n = 0
            while n < min(len(cells[i]), len(cells[j])) and cells[i][n] == cells[j][n]:
                n += 1
            shared.update(cells[i][:n])
    # Before two styles' routes part, a noisy step into a trap ends both the same way: such
    # deaths carry no style, and measured on the first candidate layouts they capped even a
    # supervised classifier at 0.87-0.93 accuracy. So no trap may border a shared route cell.
    for cell in sorted(shared):
        x, y = cell % layout.width, cell // layout.width
        for dx, dy in MOVES:
            nx, ny = x + dx, y + dy
            if 0 <= nx < layout.width and 0 <= ny < layout.height and layout.grid[ny][nx] == "X":
                problems.append(
                    f"trap at ({nx}, {ny}) borders ({x}, {y}), where styles' routes have not "
                    f"yet parted"
                )
    return "; ".join(dict.fromkeys(problems)) or None


def random_layout(
    seed: int | Sequence[int],
    size: int = 10,
    wall_density: float = 0.18,
    n_traps: int = 4,
    max_tries: int = 10_000,
    name: str | None = None,
) -> Layout:
    """A random valid layout whose four styles have distinct optimal routes and signatures.

    Deterministic in ``seed`` (an int, or a sequence of ints = one seed-sequence entropy):
    candidates are drawn from one generator until one passes :func:`parse_layout`'s checks (one S,
    G, B1, B2; G and both bonuses reachable) and :func:`style_problem` finds nothing.
    """
    rng = np.random.default_rng(seed)
    name = name or f"random-{seed}"
    for _ in range(max_tries):
        grid = np.where(rng.random((size, size)) < wall_density, "#", ".")
        free = np.argwhere(grid == ".")
        if len(free) < 6 + n_traps:
            continue
        picks = free[rng.choice(len(free), 4 + n_traps, replace=False)]
        for ch, (y, x) in zip("SG12" + "X" * n_traps, picks, strict=True):
            grid[y, x] = ch
        text = "\n".join("".join(row) for row in grid)
        try:
            layout = parse_layout(text, name=name, check_styles=False)
        except LayoutError:
            continue
        if style_problem(layout) is None:
            return layout
    raise LayoutError(f"random_layout({seed}): no valid layout in {max_tries} tries")


def random_layout_name(index: int) -> str:
    """Unit name of the index-th random layout (safe as a folder and run name)."""
    return f"R{index:04d}"


def random_layouts(count: int, seed: int, start: int = 0) -> list[Layout]:
    """Layouts ``start .. start+count-1`` of the random family ``seed`` (``gridworld.random_layouts``).

    Layout i comes from the seed sequence (seed, i) alone, so it does not depend on ``count``.
    """
    return [
        random_layout((seed, i), name=random_layout_name(i)) for i in range(start, start + count)
    ]
