"""Fuzzing the real CLI in-process: a seeded corpus of mutated configs, layouts, Parquet step tables,
pcpg dataset folders and Mario play logs, each fed to ``pcpg_dist.cli.main`` (the `pcpg` entry point).

Every case must exit 0, or exit 2 with exactly one line on stderr (``pcpg: error: ...``): never a
traceback, never a hang (each case has a time limit), never runaway memory. The corpus is built from
one seed, so a failure reproduces; the failing case's kind, mutation and stderr are in the message.

The cases are chosen so that each stops early: most fail at config or file load, and the ones
that pass run `pcpg generate` on tiny settings (tens of trajectories) or `pcpg cluster` with a
k-means clusterer, so 500+ cases fit in a few minutes on 2 cores.
"""

from __future__ import annotations

import contextlib
import io
import json
import random
import resource
import signal
import warnings
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
import yaml

from pcpg_dist.cli import main
from pcpg_dist.dataset import Dataset, write_datasets

ROOT = Path(__file__).resolve().parent.parent
SEED = 18
CASE_SECONDS = 30  # a case that runs longer is a hang
MAX_GROWTH_BYTES = 3 << 29  # 1.5 GiB above what the process held when the corpus started

BASE = {
    "name": "fuzz",
    "domain": "trajectories",
    "seed": 0,
    "seeds": [0],
    "trajectories": {"path": "steps.parquet"},
    "gridworld": {"layout_dir": "layouts", "environments": ["E1"]},
    "pbtg": {"episodes": 30, "trajectories_per_style": 6, "dataset_per_style": 5, "max_steps": 30},
    "minidungeons": {
        "train_levels": ["test"],
        "test_levels": ["holmgard_1"],
        "runs_per_level": 1,
        "max_steps": 20,
    },
    "mario": {"path": "play.log"},
    "clustering": {"method": "summary_kmeans", "k": 2, "kmeans_n_init": 1},
    "bc": {"epochs": 5},
    "evaluation": {"rollouts_per_policy": 2, "max_steps": 20},
}
# Replacement values: hostile or careless, and never a valid value that would make a case slow
# (every count here is either invalid or small).
HOSTILE = [
    -1,
    0,
    -0.5,
    0.5,
    2,
    7,
    1e12,
    2**70,
    -(2**70),
    float("nan"),
    float("inf"),
    float("-inf"),
    "x",
    "",
    "../../evil",
    "/etc/passwd",
    "a" * 3000,
    None,
    True,
    [],
    [1, 2, 3],
    [[1]],
    {"a": 1},
    {},
    "1e9",
    "gridworld",
    "mario",
    "minidungeons",
    "\x00",
    "é\u202e",
]
TEXT_JUNK = [
    b"\xff\xfe",
    b"\x00",
    b"&a [*a]",
    b"[[[[[[[[",
    b": : :",
    b"\t",
    b"!!python/object:os.system",
    b"*x",
    b"{",
    b"\n- ",
    b"\xc3",
    b"---\n",
    b"%YAML 9.9\n",
]


@dataclass
class Case:
    kind: str
    what: str
    argv: list[str]
    must_fail: bool = False  # the input must be refused (a link out of its folder, a FIFO, ...)


@dataclass
class Outcome:
    code: int | str
    err: str


def alias_bomb() -> str:
    lines = ["l0: &l0 [x, x, x, x, x, x, x, x, x]"]
    lines += [f"l{i}: &l{i} [" + ", ".join([f"*l{i - 1}"] * 9) + "]" for i in range(1, 9)]
    return "\n".join([*lines, "name: *l8", ""])


# ------------------------------------------------------------------ base files
def step_table(rng: random.Random) -> pa.Table:
    rows = {
        "trajectory": [],
        "t": [],
        "action": [],
        "s0": [],
        "s1": [],
        "reward": [],
        "env": [],
        "style": [],
    }
    for traj in range(8):
        length = rng.randint(2, 5)
        for t in range(length):
            rows["trajectory"].append(traj)
            rows["t"].append(t)
            rows["action"].append(-1 if t == length - 1 else (traj + t) % 3)
            rows["s0"].append(float(t))
            rows["s1"].append(float(traj % 2))
            rows["reward"].append(1.0)
            rows["env"].append("A" if traj < 4 else "B")
            rows["style"].append(traj % 2)
    return pa.table(rows)


def small_dataset(env: str) -> Dataset:
    rng = np.random.default_rng(0)
    trajs = [
        {
            "states": rng.random((4, 2)),
            "actions": rng.integers(0, 3, 3),
            "valid": np.ones((4, 3), bool),
            "rewards": np.ones(3),
        }
        for _ in range(6)
    ]
    return Dataset.from_trajectories(
        "trajectories", env, 3, trajs, styles=[0, 1] * 3, success=[True] * 6
    )


def mario_log() -> str:
    lines = (
        (ROOT / "pcpg_dist" / "data" / "mario" / "mario_stli_all_levels.log")
        .read_text()
        .splitlines()
    )
    return "\n".join(lines[:6]) + "\n"


# ------------------------------------------------------------------ mutations
def set_path(data: dict, path: tuple[str, ...], value) -> dict:
    data = json.loads(json.dumps(data))
    node = data
    for key in path[:-1]:
        if not isinstance(node.get(key), dict):
            node[key] = {}
        node = node[key]
    node[path[-1]] = value
    return data


def config_paths() -> list[tuple[str, ...]]:
    """Every setting of every section (top-level keys and section.field)."""
    from pcpg_dist.config.experiment import config_class
    from pcpg_dist.domains import registry

    fields = {}  # the core keys and every built-in domain's sections
    for domain in registry.BUILTIN:
        fields.update(config_class(domain).model_fields)
    paths = []
    for name, field in fields.items():
        paths.append((name,))
        model = field.annotation
        if isinstance(model, type) and hasattr(model, "model_fields"):
            paths += [(name, sub) for sub in model.model_fields]
    return paths


def dump(data) -> bytes:
    return yaml.safe_dump(data, allow_unicode=True).encode()


def mutate_bytes(raw: bytes, rng: random.Random) -> tuple[bytes, str]:
    op = rng.randrange(5)
    if op == 0 and raw:
        cut = rng.randrange(len(raw))
        return raw[:cut], f"truncated at {cut}"
    if op == 1 and raw:
        pos = rng.randrange(len(raw))
        return raw[:pos] + bytes([rng.randrange(256)]) + raw[pos + 1 :], f"byte {pos} replaced"
    if op == 2:
        junk = rng.choice(TEXT_JUNK)
        pos = rng.randrange(len(raw) + 1)
        return raw[:pos] + junk + raw[pos:], f"{junk!r} inserted at {pos}"
    if op == 3 and raw:
        lines = raw.split(b"\n")
        i = rng.randrange(len(lines))
        return b"\n".join(lines[:i] + lines[i + 1 :]), f"line {i} deleted"
    lines = raw.split(b"\n")
    i = rng.randrange(len(lines))
    return b"\n".join(lines[:i] + [lines[i]] * 3 + lines[i + 1 :]), f"line {i} repeated"


def mutate_table(table: pa.Table, rng: random.Random) -> tuple[pa.Table, str]:
    n = table.num_rows
    row = rng.randrange(n)

    def put(col: str, values, typ=None) -> pa.Table:
        i = table.schema.get_field_index(col)
        return table.set_column(i, col, pa.array(values, typ))

    def at(col: str, value) -> list:
        v = table.column(col).to_pylist()
        v[row] = value
        return v

    ops: list[tuple[str, Callable[[], pa.Table]]] = [
        ("action -5 mid-trajectory", lambda: put("action", at("action", -5))),
        ("action 10**12", lambda: put("action", at("action", 10**12))),
        ("action null", lambda: put("action", at("action", None), pa.int64())),
        (
            "action as float 1.5",
            lambda: put("action", [float(a) + 0.5 for a in table.column("action").to_pylist()]),
        ),
        (
            "action as strings",
            lambda: put("action", [str(a) for a in table.column("action").to_pylist()]),
        ),
        ("s0 NaN", lambda: put("s0", at("s0", float("nan")))),
        ("s0 inf", lambda: put("s0", at("s0", float("inf")))),
        ("s0 1e300", lambda: put("s0", at("s0", 1e300))),
        ("s0 strings", lambda: put("s0", [str(x) for x in table.column("s0").to_pylist()])),
        ("t repeated", lambda: put("t", at("t", 0))),
        ("t negative", lambda: put("t", at("t", -(2**62)))),
        ("env ../../evil", lambda: put("env", at("env", "../../evil"))),
        ("env /etc", lambda: put("env", ["/etc"] * n)),
        ("env null", lambda: put("env", at("env", None), pa.string())),
        ("env huge", lambda: put("env", at("env", "e" * 10_000))),
        ("style 7", lambda: put("style", at("style", 7))),
        ("style -5", lambda: put("style", at("style", -5))),
        (
            "trajectory strings",
            lambda: put("trajectory", [f"../t{x}" for x in table.column("trajectory").to_pylist()]),
        ),
        ("trajectory null", lambda: put("trajectory", at("trajectory", None), pa.int64())),
        ("reward nan", lambda: put("reward", at("reward", float("nan")))),
        ("valid wrong width", lambda: table.append_column("valid", pa.array([[True, False]] * n))),
        (
            "valid forbids taken",
            lambda: table.append_column("valid", pa.array([[False, False, False]] * n)),
        ),
        ("valid ints", lambda: table.append_column("valid", pa.array([[1, 1, 1]] * n))),
        ("drop column", lambda: table.drop([rng.choice(table.column_names)])),
        ("s5 gap", lambda: table.append_column("s5", pa.array([0.0] * n))),
        ("no rows", lambda: table.slice(0, 0)),
        (
            "success changes",
            lambda: table.append_column("success", pa.array([i % 2 == 0 for i in range(n)])),
        ),
    ]
    what, fn = rng.choice(ops)
    return fn(), what


def mutate_manifest(directory: Path, rng: random.Random) -> str:
    path = directory / "manifest.json"
    manifest = json.loads(path.read_text())
    name = next(iter(manifest["files"]))
    ops = [
        ("files as a list", lambda m: {**m, "files": list(m["files"])}),
        ("entry ../escape", lambda m: {**m, "files": {"../" + name: m["files"][name]}}),
        ("entry /etc/passwd", lambda m: {**m, "files": {"/etc/passwd": m["files"][name]}}),
        ("entry not a mapping", lambda m: {**m, "files": {name: 5}}),
        ("rows wrong", lambda m: {**m, "files": {name: {**m["files"][name], "rows": 10**30}}}),
        ("sha wrong", lambda m: {**m, "files": {name: {**m["files"][name], "sha256": "0" * 64}}}),
        ("no files", lambda m: {k: v for k, v in m.items() if k != "files"}),
    ]
    if rng.random() < 0.3:
        raw, what = mutate_bytes(path.read_bytes(), rng)
        path.write_bytes(raw)
        return "manifest " + what
    what, fn = rng.choice(ops)
    path.write_text(json.dumps(fn(manifest)))
    return "manifest " + what


def mutate_parquet_meta(directory: Path, rng: random.Random) -> str:
    """Change the Parquet file's pcpg metadata and re-sign it in the manifest (a crafted dataset)."""
    from pcpg_dist.common.files import sha256_file

    file = next(directory.glob("*.parquet"))
    table = pq.read_table(file)
    meta = json.loads(table.schema.metadata[b"pcpg"])
    key, value = rng.choice(
        [
            ("env", "../../evil"),
            ("env", "/tmp/x"),
            ("domain", "a/b"),
            ("n_actions", 1e12),
            ("n_actions", "inf"),
            ("feature_names", 5),
            ("schema_version", 99),
            ("env", "e" * 5000),
            ("n_actions", 2),
        ]
    )
    meta[key] = value
    pq.write_table(table.replace_schema_metadata({"pcpg": json.dumps(meta)}), file)
    manifest = json.loads((directory / "manifest.json").read_text())
    manifest["files"][file.name]["sha256"] = sha256_file(file)
    (directory / "manifest.json").write_text(json.dumps(manifest))
    return f"parquet metadata {key}={str(value)[:20]!r}"


# ------------------------------------------------------------------ the corpus
def build_corpus(tmp: Path) -> list[Case]:
    rng = random.Random(SEED)
    base_dir = tmp / "base"
    (base_dir / "layouts").mkdir(parents=True)
    layout = (ROOT / "pcpg_dist" / "data" / "gridworld" / "E1.txt").read_bytes()
    (base_dir / "layouts" / "E1.txt").write_bytes(layout)
    pq.write_table(step_table(rng), base_dir / "steps.parquet")
    (base_dir / "play.log").write_text(mario_log())
    paths = config_paths()
    cases: list[Case] = []

    def folder(i: int) -> Path:
        d = tmp / f"c{i}"
        d.mkdir()
        (d / "layouts").mkdir()
        (d / "layouts" / "E1.txt").write_bytes(layout)
        (d / "steps.parquet").write_bytes((base_dir / "steps.parquet").read_bytes())
        (d / "play.log").write_bytes((base_dir / "play.log").read_bytes())
        return d

    def add(kind: str, what: str, d: Path, config: bytes, argv: list[str] | None = None) -> None:
        (d / "exp.yaml").write_bytes(config)
        cases.append(
            Case(
                kind,
                what,
                argv or ["generate", str(d / "exp.yaml"), "--out", str(d / "out"), "--quiet"],
            )
        )

    i = 0
    for _ in range(220):  # one setting replaced by a hostile value
        i += 1
        path = rng.choice(paths)
        value = rng.choice(HOSTILE)
        add(
            "config value",
            f"{'.'.join(path)} = {str(value)[:30]!r}",
            folder(i),
            dump(set_path(BASE, path, value)),
        )
    for _ in range(20):  # two settings at once
        i += 1
        data, what = BASE, []
        for _ in range(2):
            path, value = rng.choice(paths), rng.choice(HOSTILE)
            data = set_path(data, path, value)
            what.append(f"{'.'.join(path)} = {str(value)[:20]!r}")
        add("config values", "; ".join(what), folder(i), dump(data))
    for _ in range(100):  # the YAML text itself damaged
        i += 1
        raw, what = mutate_bytes(dump(BASE), rng)
        add("config text", what, folder(i), raw)
    for special, raw in [
        ("alias bomb", alias_bomb().encode()),
        ("recursive alias", b"a: &a [*a]\nname: x\n"),
        ("2 MB", b"name: x\n" + b"#" * (2 << 20)),
        ("empty", b""),
        ("a list", b"- 1\n- 2\n"),
        ("deep", b"name: " + b"[" * 5000 + b"]" * 5000),
        ("non-UTF-8", b"name: \xff\n"),
    ]:
        i += 1
        add("config text", special, folder(i), raw)
    i += 1
    add(
        "config text",
        "config is /dev/zero",
        folder(i),
        dump(BASE),
        ["generate", "/dev/zero", "--out", str(tmp / "z")],
    )

    for _ in range(80):  # GridWorld layouts
        i += 1
        d = folder(i)
        raw, what = mutate_bytes(layout, rng)
        (d / "layouts" / "E1.txt").write_bytes(raw)
        add("layout", what, d, dump({**BASE, "domain": "gridworld"}))
    for _ in range(80):  # Parquet step tables
        i += 1
        d = folder(i)
        if rng.random() < 0.25:
            raw, what = mutate_bytes((base_dir / "steps.parquet").read_bytes(), rng)
            (d / "steps.parquet").write_bytes(raw)
        else:
            table, what = mutate_table(pq.read_table(base_dir / "steps.parquet"), rng)
            try:
                pq.write_table(table, d / "steps.parquet")
            except (pa.ArrowException, ValueError):
                continue
        add("step table", what, d, dump(BASE))
    for _ in range(80):  # Mario play logs
        i += 1
        d = folder(i)
        raw, what = mutate_bytes(mario_log().encode(), rng)
        if rng.random() < 0.3:
            raw = raw.replace(
                b"0,0,0,0,0,1",
                rng.choice(
                    [
                        b"99999999999999999999999,0,0,0,0,1",
                        b"0,0,0,0,0,-5",
                        b"-1,0,0,0,0,1",
                        b"0,0,0,0,0,39",
                        b"1e3,0,0,0,0,1",
                    ]
                ),
                1,
            )
            what += " + a bad number"
        (d / "play.log").write_bytes(raw)
        strict = rng.random() < 0.5
        add(
            "mario log",
            what + ("" if strict else " (lenient)"),
            d,
            dump(set_path({**BASE, "domain": "mario"}, ("mario", "strict"), strict)),
        )
    i += 1
    add(
        "mario log",
        "mario.path /dev/zero",
        folder(i),
        dump(set_path({**BASE, "domain": "mario"}, ("mario", "path"), "/dev/zero")),
    )

    for _ in range(40):  # pcpg dataset folders given to `pcpg cluster --data`
        i += 1
        d = folder(i)
        write_datasets(d / "data", [small_dataset("A")], {"config": {}})
        what = (mutate_parquet_meta if rng.random() < 0.4 else mutate_manifest)(d / "data", rng)
        add(
            "dataset folder",
            what,
            d,
            dump(BASE),
            cluster_argv(d),
        )
    i = file_kind_cases(cases, tmp, base_dir, folder, add, i)
    minari_cases(cases, tmp, rng)
    return cases


#: what an input file is replaced by, and whether pcpg must refuse it wherever it sits
FILE_KINDS = {
    "a link within its folder": False,
    "a link out of its folder": None,  # refused inside a folder pcpg lists; a named file may link
    "a FIFO": True,
    "a device (a copy of /dev/null)": True,
    "a dangling link": True,
}


def plant(path: Path, kind: str, outside: Path) -> None:
    """Replace ``path`` by ``kind`` (its content kept beside it or outside, for the links)."""
    import os

    content = path.read_bytes()
    path.unlink()
    if kind == "a link within its folder":
        (path.parent / f"real-{path.name}.bak").write_bytes(content)
        path.symlink_to(path.parent / f"real-{path.name}.bak")
    elif kind == "a link out of its folder":
        outside.mkdir(parents=True, exist_ok=True)
        (outside / path.name).write_bytes(content)
        path.symlink_to(outside / path.name)
    elif kind == "a FIFO":
        os.mkfifo(path)
    elif kind == "a device (a copy of /dev/null)":
        os.mknod(path, 0o20666, os.makedev(1, 3))
    else:
        path.symlink_to(path.parent / "gone")


def cluster_argv(d: Path) -> list[str]:
    """`pcpg cluster` of a case folder's config on its dataset folder ``data``."""
    return [
        "cluster",
        str(d / "exp.yaml"),
        "--data",
        str(d / "data"),
        "--out",
        str(d / "out"),
        "--quiet",
    ]


def file_kind_cases(cases, tmp: Path, base_dir: Path, folder, add, i: int) -> int:
    """Every input that is a file, replaced by a link within or out of its folder, a FIFO, a
    device or a dangling link: a named file may be a link anywhere; a file pcpg finds in a folder
    (a layout, a step table of a folder, a dataset's file) must stay inside it; a special file or
    a link to nothing is always one line (the input policy, pcpg_dist/common/inputs.py)."""
    steps_folder = {**BASE, "trajectories": {"path": "steps"}}
    inputs = [  # (input, file in the case folder, config, listed in a folder by pcpg, argv)
        ("layout", "layouts/E1.txt", {**BASE, "domain": "gridworld"}, True, None),
        ("step table file", "steps.parquet", BASE, False, None),
        ("step table folder", "steps/b.parquet", steps_folder, True, None),
        ("mario log", "play.log", {**BASE, "domain": "mario"}, False, None),
        ("dataset file", "data/trajectories-A.parquet", BASE, True, "cluster"),
    ]
    for name, rel, config, listed, command in inputs:
        for kind, refused in FILE_KINDS.items():
            i += 1
            d = folder(i)
            (d / "steps").mkdir()
            (d / "steps" / "b.parquet").write_bytes((base_dir / "steps.parquet").read_bytes())
            write_datasets(d / "data", [small_dataset("A")], {"config": {}})
            plant(d / rel, kind, tmp / f"outside{i}")
            argv = None
            if command == "cluster":
                argv = cluster_argv(d)
            add(f"file kind: {name}", kind, d, dump(config), argv)
            cases[-1].must_fail = refused if refused is not None else listed
    return i


def minari_cases(cases, tmp: Path, rng: random.Random) -> None:
    """A real Minari dataset (6 episodes, pcpg's export), its metadata or one episode file
    damaged, read by `pcpg generate` as `minari:ID`; the datasets live under one
    MINARI_DATASETS_PATH (set by the test)."""
    from pcpg_dist.domains.trajectories.minari_io import write_minari

    root = tmp / "minari"
    values = [-1, 0, 10**12, "6", None, [], {}, 1e308, "x" * 10_000, [[[[[]]]]]]
    for j in range(24):
        dataset_id = f"fuzz/m{j}-v0"
        write_minari({"lvl": small_dataset("lvl")}, root, dataset_id)
        data = root / dataset_id / "data"
        if j < 12:
            meta = json.loads((data / "metadata.json").read_text())
            key = rng.choice(sorted(meta))
            meta[key] = rng.choice(values)
            what = f"metadata {key} = {str(meta[key])[:20]!r}"
            (data / "metadata.json").write_text(json.dumps(meta))
        elif j < 18:
            episode = data / str(rng.randrange(6))
            (f,) = (p for p in episode.iterdir() if p.name != "metadata.json")
            kind = rng.choice([k for k in FILE_KINDS if k != "a link within its folder"])
            plant(f, kind, tmp / f"minari-outside{j}")
            what = f"episode file: {kind}"
        else:
            episode = data / str(rng.randrange(6))
            (f,) = (p for p in episode.iterdir() if p.name != "metadata.json")
            raw, what = mutate_bytes(f.read_bytes(), rng)
            f.write_bytes(raw)
            what = f"episode bytes: {what}"
        config = tmp / f"minari{j}.yaml"
        config.write_bytes(dump({**BASE, "trajectories": {"path": f"minari:{dataset_id}"}}))
        out = tmp / f"minari-out{j}"
        cases.append(
            Case(
                "minari folder",
                what,
                ["generate", str(config), "--out", str(out), "--quiet"],
                must_fail=j >= 12 and j < 18,
            )
        )


# ------------------------------------------------------------------ running a case
class Hang(Exception):
    pass


def _alarm(signum, frame):
    raise Hang


def run_case(case: Case) -> Outcome:
    err = io.StringIO()
    old = signal.signal(signal.SIGALRM, _alarm)
    signal.alarm(CASE_SECONDS)
    try:
        with (
            contextlib.redirect_stderr(err),
            contextlib.redirect_stdout(io.StringIO()),
            warnings.catch_warnings(),
        ):
            warnings.simplefilter("ignore")  # warnings are advice, not the error line checked here
            try:
                code: int | str = main(case.argv)
            except SystemExit as e:
                code = e.code if isinstance(e.code, int) else 2
    except Hang:
        code = "hang"
    except BaseException as e:  # noqa: BLE001 - the point: any escape is a finding
        import traceback

        code = "traceback"
        err.write("".join(traceback.format_exception(e))[-1500:])
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, old)
    return Outcome(code, err.getvalue())


def problem(case: Case, out: Outcome) -> str | None:
    if out.code == 0 and case.must_fail:
        return "exit 0: the input was read or skipped in silence"
    if out.code == 0:
        return None if "Traceback" not in out.err else "exit 0 with a traceback"
    if out.code != 2:
        return f"exit {out.code}"
    lines = out.err.strip().splitlines()
    if len(lines) != 1 or not lines[0].startswith("pcpg: error: ") or len(lines[0]) > 1200:
        return f"exit 2 with {len(lines)} lines / {len(out.err)} characters"
    return None


def _status_kb(field: str) -> int:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith(field + ":"):
            return int(line.split()[1])
    raise KeyError(field)


def _reset_peak_rss() -> int:
    """Reset this process's peak RSS to its current RSS (Linux) and return that RSS in bytes:
    the peak the corpus reaches is then its own, not that of the tests run before it in the same
    process. Elsewhere, the lifetime peak so far."""
    try:
        Path("/proc/self/clear_refs").write_text("5")
        return _status_kb("VmRSS") * 1024
    except OSError:
        return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024


def _peak_rss() -> int:
    try:
        return _status_kb("VmHWM") * 1024
    except OSError:
        return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024


@pytest.mark.slow
def test_fuzzed_inputs_exit_0_or_one_line_exit_2(tmp_path, ray_session, monkeypatch):
    monkeypatch.setenv("MLFLOW_TRACKING_URI", f"sqlite:///{tmp_path}/never.db")
    monkeypatch.setenv("MINARI_DATASETS_PATH", str(tmp_path / "minari"))
    cases = build_corpus(tmp_path)
    assert len(cases) >= 500
    findings, outcomes = [], Counter()
    start = _reset_peak_rss()
    for case in cases:
        out = run_case(case)
        outcomes[(case.kind, out.code)] += 1
        why = problem(case, out)
        if why:
            findings.append(f"[{case.kind}] {case.what}: {why}: {out.err.strip()[-600:]!r}")
    growth = _peak_rss() - start
    summary = ", ".join(f"{k[0]} -> {k[1]}: {v}" for k, v in sorted(outcomes.items(), key=str))
    assert not findings, (
        f"{len(findings)} of {len(cases)} cases misbehaved ({summary}):\n"
        + "\n".join(findings[:20])
    )
    assert growth < MAX_GROWTH_BYTES, f"peak memory {growth / 2**30:.2f} GB above the start"
    # the corpus reaches past config loading: some cases of every kind pass, most fail
    for kind in ("config value", "layout", "step table", "mario log", "minari folder"):
        assert outcomes[(kind, 0)] > 0 and outcomes[(kind, 2)] > 0, summary
    print(f"\n{len(cases)} cases: {summary}; peak RSS {growth / 2**20:.0f} MB above the start")
