"""Facts written in two places are derived one from the other here, so a difference fails.

A compiled class's fields are declared for Cython in its .pxd (`cdef public double x, y`) and
for the interpreter in the .py (`__slots__`, or assignments in `__init__` where the class keeps
a `__dict__`). The .pxd is the declaration with the types; the .py must name exactly the same
fields (a field added, renamed or dropped on one side only would run in one build and fail, or
silently differ, in the other)."""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

import cosim  # noqa: F401  (lists its compiled modules)
from onesource import switch as compiled

ROOT = Path(__file__).resolve().parent.parent
_CLASS = re.compile(r"^cdef class (\w+)")
# a field line: `cdef [public|readonly] TYPE name[, name...]` (TYPE may be `long long` or a
# typed memoryview `double[::1]`; a method has a parenthesis), a trailing comment left out
_FIELD = re.compile(r"^\s+cdef\s+(?:public\s+|readonly\s+)?([\w\s.*,:\[\]]+)$")


def pxd_fields(pxd: Path) -> dict[str, set[str]]:
    """{class: its field names} of every `cdef class` in a .pxd."""
    out: dict[str, set[str]] = {}
    cls = None
    for line in pxd.read_text(encoding="utf-8").splitlines():
        m = _CLASS.match(line)
        if m:
            cls = m.group(1)
            out[cls] = set()
            continue
        if cls is None or not line.strip() or line.lstrip().startswith("#"):
            continue
        if not line.startswith(" "):
            cls = None
            continue
        m = _FIELD.match(line.split("#", 1)[0].rstrip())
        if m:
            first, *more = re.sub(r"\[[^]]*\]", "", m.group(1)).split(",")
            out[cls].update(n.strip() for n in [first.split()[-1], *more] if n.strip())
    return out


def py_fields(py: Path, cls: str) -> tuple[set[str] | None, set[str]]:
    """(its `__slots__`, or None; every `self.<name>` assigned in its methods) of a class."""
    tree = ast.parse(py.read_text(encoding="utf-8"))
    node = next(n for n in tree.body if isinstance(n, ast.ClassDef) and n.name == cls)
    slots = None
    assigned: set[str] = set()
    for stmt in node.body:
        if isinstance(stmt, ast.Assign) and any(
                isinstance(t, ast.Name) and t.id == "__slots__" for t in stmt.targets):
            slots = set(ast.literal_eval(stmt.value))
    for n in ast.walk(node):
        targets = n.targets if isinstance(n, ast.Assign) else (
            [n.target] if isinstance(n, ast.AnnAssign | ast.AugAssign) else [])
        for t in targets:
            for e in (t.elts if isinstance(t, ast.Tuple) else [t]):
                if (isinstance(e, ast.Attribute) and isinstance(e.value, ast.Name)
                        and e.value.id == "self"):
                    assigned.add(e.attr)
    return slots, assigned


CLASSES = sorted(
    (name, cls, src, fields)
    for name, (src, _) in compiled.compiled_modules().items()
    if src.suffix == ".py" and src.with_suffix(".pxd").is_file()
    for cls, fields in pxd_fields(src.with_suffix(".pxd")).items())


def test_the_pxd_parser_sees_the_classes():
    """The test below checks something: it finds the records it is about."""
    found = {cls for _, cls, _, _ in CLASSES}
    assert {"VehicleState", "Setpoint", "VehicleStatus", "TemplateEstimator", "SensorSuite",
            "Tick", "FastMsg", "Layout", "Payload"} <= found
    assert len(CLASSES) >= 15
    state = next(f for _, c, _, f in CLASSES if c == "VehicleState")
    assert state == {"t", "x", "y", "z", "vx", "vy", "vz", "qw", "qx", "qy", "qz", "p", "q", "r"}


@pytest.mark.parametrize("name,cls,src,fields", CLASSES, ids=[f"{n}.{c}" for n, c, _, _ in CLASSES])
def test_a_compiled_class_declares_the_same_fields_in_its_pxd_and_its_source(name, cls, src,
                                                                             fields):
    slots, assigned = py_fields(src, cls)
    fields = fields - {"__dict__", "__weakref__"}
    if slots is not None:
        assert slots - {"__weakref__"} == fields, (
            f"{src.name} {cls}: only in __slots__: {sorted(slots - fields)}; only in the .pxd: "
            f"{sorted(fields - slots)}")
    else:     # a class with a __dict__: each C field is one the source sets
        assert fields <= assigned, (f"{src.name} {cls}: C fields the source never sets: "
                                    f"{sorted(fields - assigned)}")


def test_a_renamed_field_would_fail(tmp_path):
    """The derivation catches a one-sided change."""
    pxd = tmp_path / "m.pxd"
    pxd.write_text("cdef class A:\n    cdef public double x, y\n    cdef int code[4]\n"
                   "    cpdef double f(self, double v)\n")
    py = tmp_path / "m.py"
    py.write_text("class A:\n    __slots__ = ('x', 'z', 'code')\n")
    assert pxd_fields(pxd) == {"A": {"x", "y", "code"}}
    slots, _ = py_fields(py, "A")
    assert slots != pxd_fields(pxd)["A"]
