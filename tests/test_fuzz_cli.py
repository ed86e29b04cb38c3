"""Issue 31: a seeded, bounded fuzz of the command line's inputs. Mutated scenario and world
files, hostile `--set` / `--vary` values and corrupted visual-path folders go through
`cosim validate`, `cosim run` (each run cut to 0.2 s of simulated time), `cosim montecarlo`
(`--limit 0`: the study is set up, its draws checked, nothing flown) and `cosim teach`.
Every case must end with exit 0, 1 or 2, never a traceback; nothing may be written outside
the case's output folder (the system temporary folder included), and no input deleted or
changed. A failure names the seed and the case, so it replays (`CASES`, `SEED`).
"""

from __future__ import annotations

import contextlib
import gc
import hashlib
import io
import json
import math
import random
import shutil
import tempfile
import tomllib
from pathlib import Path

import pytest

from cosim.cli import main

ROOT = Path(__file__).resolve().parents[1]
SEED = 31
CASES = 100                     # ~20 s of CPU; each a fresh input and output folder
T_RUN = "timing.t_final_s=0.2"

HOSTILE = [-1e308, 1e308, math.nan, math.inf, -math.inf, 0, -1, 1e-300, 2**70, True, "", "x" * 300,
           [], {}, [1, 2], [[1, 2, 3, 4]], {"a": 1}, "../../etc", "nan", 0.5, 1, 3.0, "front",
           "visual_servo", [0.05, 0.06, 0.07]]
DISTS = ["uniform(0,1)", "uniform(-1e308,1e308)", "normal(0,1e300)", "loguniform(1e-300,1e300)",
         "choice(1,2,[3])", "truncnormal(0,1,-1,1)", "choice()", "uniform(1,0)", "nope(1)",
         "choice(" + "[" * 40 + "]" * 40 + ")", "normal(0,-1)", "uniform(0, 1e-300)"]


# ------------------------------------------------------------------ a small TOML writer
def _val(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        return "nan" if v != v else ("inf" if v > 0 else "-inf") if math.isinf(v) else repr(v)
    if isinstance(v, str):
        return json.dumps(v)
    if isinstance(v, list):
        return "[" + ", ".join(_val(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{" + ", ".join(f"{json.dumps(k)} = {_val(x)}" for k, x in v.items()) + "}"
    raise TypeError(v)


def dump_toml(d: dict, prefix: str = "") -> str:
    lines = [f"{json.dumps(k)} = {_val(v)}" for k, v in d.items() if not isinstance(v, dict)]
    for k, v in d.items():
        if isinstance(v, dict):
            name = f"{prefix}.{json.dumps(k)}" if prefix else json.dumps(k)
            lines.append(f"\n[{name}]")
            lines.append(dump_toml(v, name))
    return "\n".join(lines)


# ------------------------------------------------------------------ mutations
def _leaves(d: dict, path=()):
    for k, v in d.items():
        yield (*path, k)
        if isinstance(v, dict):
            yield from _leaves(v, (*path, k))


def _hostile(rng: random.Random):
    r = rng.random()
    if r < 0.05:
        depth = rng.choice([40, 400, 3000])
        return "[" * depth + "]" * depth                  # raw TOML text, inserted as is
    return rng.choice(HOSTILE)


def mutate_table(rng: random.Random, raw: dict) -> str:
    """The TOML text of `raw` with 1-3 hostile edits (a value replaced, a key dropped or
    added, a table made a scalar), or its text cut or flipped."""
    raw = json.loads(json.dumps(raw, default=str))  # a deep copy (NaN-free inputs)
    deep = None
    for _ in range(rng.randint(1, 3)):
        paths = list(_leaves(raw))
        if not paths:
            break
        path = rng.choice(paths)
        node = raw
        for k in path[:-1]:
            node = node[k]
        op = rng.random()
        if op < 0.15:
            node.pop(path[-1], None)
        elif op < 0.25:
            node[f"unknown_{rng.randrange(99)}"] = 1
        else:
            v = _hostile(rng)
            if isinstance(v, str) and v.startswith("[["):
                deep, v = v, "@@DEEP@@"
            node[path[-1]] = v
    text = dump_toml(raw)
    if deep is not None:
        text = text.replace('"@@DEEP@@"', deep)
    r = rng.random()
    if r < 0.08:
        text = text[: rng.randrange(len(text) + 1)]
    elif r < 0.12:
        b = bytearray(text.encode())
        for _ in range(3):
            if b:
                b[rng.randrange(len(b))] = rng.randrange(256)
        return b.decode("latin-1")
    return text


# ------------------------------------------------------------------ the inputs
def _tree(root: Path) -> dict[str, str]:
    return {str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(root.rglob("*")) if p.is_file()}


@pytest.fixture(scope="module")
def inputs(tmp_path_factory):
    """Copies of the scenarios and worlds, and a small taught path (428 x 240, ORB)."""
    from cosim.apps.vs import visual_path as VP
    from cosim.load import load_scenario, with_set

    d = tmp_path_factory.mktemp("fuzz-inputs")
    shutil.copytree(ROOT / "scenarios", d / "scenarios")
    sc = with_set(load_scenario(d / "scenarios" / "bebop2_vs_e1.toml"),
                  {"camera.width": 428, "camera.height": 240})
    VP.teach_by_render(sc, [(1.5, 0.0, -0.5, 0.0), (1.2, 0.1, -0.7, 5.0)], d / "vp", "orb", 200)
    return d


def _case(rng: random.Random, i: int, inp: Path, work: Path) -> list[str]:
    """The command line of case i: its input files are written into `work/in`."""
    src = work / "in"
    shutil.copytree(inp / "scenarios", src / "scenarios")
    scen = sorted((src / "scenarios").glob("*.toml"))
    out = work / "out"
    kind = rng.random()
    if kind < 0.12:                                    # a mutated world file
        worlds = sorted((src / "scenarios" / "worlds").glob("*.toml"))
        w = rng.choice(worlds)
        w.write_text(mutate_table(rng, tomllib.loads(w.read_text())), encoding="latin-1")
    if kind < 0.5:                                     # a mutated scenario file
        s = rng.choice(scen)
        s.write_text(mutate_table(rng, tomllib.loads(s.read_text())), encoding="latin-1")
    else:
        s = rng.choice(scen)
    raw = tomllib.loads(s.read_text(encoding="latin-1")) if kind >= 0.5 else {}
    sets: list[str] = []
    if kind >= 0.5 and rng.random() < 0.8:            # hostile --set values
        for _ in range(rng.randint(1, 2)):
            path = ".".join(rng.choice(list(_leaves(raw)) or [("seed",)]))
            v = _hostile(rng)
            sets += ["--set", f"{path}={v if isinstance(v, str) else _val(v)}"]
    if 0.8 <= kind:                                    # a visual servo run with a taught path
        s = src / "scenarios" / "bebop2_vs_e1.toml"
        vp = src / "vp"
        shutil.copytree(inp / "vp", vp)
        _corrupt_path(rng, vp)
        where = rng.choice([vp, out / "visual_path"])
        if where != vp:
            shutil.copytree(vp, where)
        sets = ["--set", "camera.width=428", "--set", "camera.height=240",
                "--set", f"app.params.visual_path={where}"]
    cmd = rng.random()
    if cmd < 0.45:
        return ["validate", str(s)]
    if cmd < 0.8:
        return ["run", str(s), *sets, "--set", T_RUN, "--out", str(out), "--quiet",
                "--no-plots"]
    if cmd < 0.95:
        key = ".".join(rng.choice(list(_leaves(raw)) or [("wind", "n_mps")]))
        return ["montecarlo", str(s), "-n", str(rng.choice([1, 3, 10**9])), "--vary",
                f"{key}={rng.choice(DISTS)}", "--limit", "0", "--executor", "serial",
                "--out", str(out), "--quiet", *sets]
    return ["teach", str(s), "--out", str(out / "vp"), *sets]


def _corrupt_path(rng: random.Random, vp: Path) -> None:
    r = rng.random()
    if r < 0.2:
        return                                          # a good path
    if r < 0.6:
        meta = json.loads((vp / "path.json").read_text())
        target = rng.choice([meta["camera"], meta, rng.choice(meta["keys"])])
        key = rng.choice(list(target))
        target[key] = rng.choice(HOSTILE[:20])
        (vp / "path.json").write_text(json.dumps(meta))
    elif r < 0.75:
        (vp / rng.choice(["000.png", "001.png", "features.npz"])).write_bytes(
            bytes(rng.randrange(256) for _ in range(rng.randrange(64))))
    elif r < 0.85:
        (vp / rng.choice(["000.png", "path.json", "features.npz"])).unlink()
    else:
        shutil.copyfile(vp / "000.png", vp / "001.png")


def _inputs(work: Path, placed: bool) -> dict[str, str]:
    """The case's input files: its copies of the scenarios (and taught path), and the taught
    path it `placed` in the output folder (a run must refuse to clear it)."""
    vp = work / "out" / "visual_path"
    return {**_tree(work / "in"),
            **({f"out/{k}": v for k, v in _tree(vp).items()} if placed else {})}


@pytest.mark.flight
def test_fuzz_command_line_inputs(inputs, tmp_path, monkeypatch):
    rng = random.Random(SEED)
    systmp = tmp_path / "systmp"
    systmp.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(systmp))   # what the runs put in /tmp
    monkeypatch.chdir(tmp_path)                              # default outputs would land here
    repo = _tree(ROOT / "scenarios")
    codes: dict[int, int] = {}
    for i in range(CASES):
        work = tmp_path / f"case{i:03d}"
        argv = _case(rng, i, inputs, work)
        placed = (work / "out" / "visual_path").is_dir()
        before = _inputs(work, placed)
        err = io.StringIO()
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
            try:
                rc = main(argv)
            except SystemExit as exc:                    # argparse: a malformed option
                rc = exc.code
            except BaseException as exc:
                pytest.fail(f"seed {SEED} case {i}: {argv!r:.400} raised {exc!r:.300}")
        assert rc in (0, 1, 2), (i, argv, rc, err.getvalue()[-500:])
        assert "Traceback" not in err.getvalue(), (i, argv, err.getvalue()[-2000:])
        after = _inputs(work, placed)
        assert after == before, (i, argv, "an input was deleted or changed",
                                 set(before) ^ set(after))
        stray = [p for p in tmp_path.iterdir()
                 if p.name not in ("systmp",) and not p.name.startswith("case")]
        assert not stray, (i, argv, stray)
        assert sorted(q.name for q in work.iterdir()) in (["in"], ["in", "out"]), (i, argv)
        codes[rc] = codes.get(rc, 0) + 1
        gc.collect()                                     # a run's temporary folders go
        assert not list(systmp.iterdir()), (i, argv, list(systmp.iterdir()))
        shutil.rmtree(work)
    assert _tree(ROOT / "scenarios") == repo
    print(f"fuzz: exit codes {codes}")
    assert codes.get(2, 0) > CASES // 4 and codes.get(0, 0) > 5, codes   # both kinds seen
