"""The house rules of the code layout, checked on the source: no import circles between
modules (top-level or inside functions), and the flight software (`mav/`) imports nothing
from the simulator (`cosim/`)."""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("cosim", "mav", "fmus", "onesource")


def _module_name(path: Path) -> str:
    parts = path.relative_to(ROOT).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def import_graph() -> dict[str, set[str]]:
    """module -> the project modules it imports (any import statement anywhere in it)."""
    files = {_module_name(p): p for pkg in PACKAGES for p in (ROOT / pkg).rglob("*.py")}
    graph: dict[str, set[str]] = {}
    for mod, path in files.items():
        deps: set[str] = set()
        pkg = mod if path.name == "__init__.py" else mod.rpartition(".")[0]
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:
                    up = pkg.split(".")[: len(pkg.split(".")) - node.level + 1]
                    base = ".".join(up + ([base] if base else []))
                names = [base] + [f"{base}.{a.name}" for a in node.names]
            else:
                continue
            for name in names:
                while name and name not in files:   # 'a.b.C' -> the module 'a.b'
                    name = name.rpartition(".")[0]
                if name and name != mod:
                    deps.add(name)
        graph[mod] = deps
    return graph


def find_cycle(graph: dict[str, set[str]]) -> list[str] | None:
    state: dict[str, int] = {}
    stack: list[str] = []

    def visit(m: str) -> list[str] | None:
        state[m] = 1
        stack.append(m)
        for d in sorted(graph.get(m, ())):
            if state.get(d) == 1:
                return stack[stack.index(d):] + [d]
            if d not in state and (c := visit(d)):
                return c
        stack.pop()
        state[m] = 2
        return None

    for m in sorted(graph):
        if m not in state and (c := visit(m)):
            return c
    return None


def test_no_import_cycles():
    cycle = find_cycle(import_graph())
    assert cycle is None, " -> ".join(cycle)


def test_cycle_finder_finds_a_cycle():
    assert find_cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]
    assert find_cycle({"a": {"b"}, "b": set()}) is None


def test_import_graph_sees_function_level_imports():
    g = import_graph()
    assert "cosim.apps.line_follower" in g["cosim.apps.registry"]   # imported inside make_app


def test_flight_software_stands_alone():
    g = import_graph()
    bad = {m: sorted(d for d in deps if d.startswith("cosim")) for m, deps in g.items()
           if m.startswith("mav")}
    assert not {m: d for m, d in bad.items() if d}, bad


# ---- cosim's packages: each imports only the layers below it -------------------------------
# bottom to top; a package (cosim/<name>/) or a top-level module (cosim/<name>.py) may import
# only from lower layers. scenario is the leaf every part builds from (cosim/load.py hands it
# the other packages' table parsers); nothing but the command line imports studies.
LAYERS = (
    ("errors", "numerics", "cvthreads", "cache", "tempdirs"),
    ("scenario",),
    ("world", "faults"),
    ("plant",),
    ("sensors",),
    ("apps",),
    ("outputs",),
    ("sim",),
    ("load",),
    ("cli_checks", "bench", "cli_render", "cli_teach", "executors"),
    ("studies", "cli_sitl"),
    ("regress",),
    ("cli",),
)


def package_graph() -> dict[str, set[str]]:
    """cosim unit (first part below cosim) -> the cosim units it imports, from import_graph."""
    out: dict[str, set[str]] = {}
    for mod, deps in import_graph().items():
        parts = mod.split(".")
        if parts[0] != "cosim" or len(parts) < 2:
            continue
        unit = parts[1]
        out.setdefault(unit, set()).update(
            d.split(".")[1] for d in deps
            if d.startswith("cosim.") and d.split(".")[1] != unit)
    return out


def test_cosim_packages_import_only_downward():
    rank = {u: i for i, layer in enumerate(LAYERS) for u in layer}
    graph = package_graph()
    assert set(graph) <= set(rank), f"units missing from LAYERS: {set(graph) - set(rank)}"
    upward = sorted(f"{a} -> {b}" for a, deps in graph.items() for b in deps
                    if rank[b] >= rank[a])
    assert not upward, "imports that do not go down a layer: " + ", ".join(upward)
    assert graph["scenario"] <= {"errors", "numerics"}
    assert find_cycle(graph) is None


def test_the_package_check_sees_an_upward_import():
    graph = package_graph()
    assert "sim" in graph["bench"] and "outputs" in graph["sim"]     # real edges are seen
    rank = {u: i for i, layer in enumerate(LAYERS) for u in layer}
    assert rank["outputs"] < rank["sim"]                              # so outputs -> sim fails
