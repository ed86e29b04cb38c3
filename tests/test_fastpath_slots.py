"""The compiled parts read and write the records' __slots__ through a cache of slot offsets
(mav/csrc/slots.c). Whatever the records become, the answer is Python's: a subclass that turns
an attribute into a property, a class changed after the offsets were cached, an instance-dict
attribute, an unset slot. Checked through the compiled controller against its Python
reference, which reads the same attributes."""

from __future__ import annotations

import pytest

from mav import fastpath
from mav.airframe import MAMBO
from mav.control import make_controller
from mav.types import Setpoint, VehicleState

pytestmark = pytest.mark.skipif(fastpath.lib is None, reason="mav/_fastpath not built")


def _both(s, sp):
    out = []
    for fast in (True, False):
        c = make_controller(MAMBO, fast=fast)
        u = [0.0] * 4
        try:
            c.update(s, sp, u)
            out.append(u)
        except Exception as exc:
            out.append((type(exc), str(exc)))
    return out


def _state():
    s = VehicleState()
    s.x, s.y, s.z, s.vx, s.qz, s.qw = 0.3, -0.2, -1.0, 0.1, 0.1, 0.995
    return s


def _setpoint():
    sp = Setpoint()
    sp.x, sp.y, sp.z, sp.armed = 0.5, 0.0, -1.2, True
    return sp


def test_slot_cache_follows_subclasses_and_changed_classes():
    s, sp = _state(), _setpoint()
    a, b = _both(s, sp)
    assert a == b and a != [0.0] * 4

    class Shadowed(VehicleState):            # x becomes a property in a subclass
        __slots__ = ()

        @property
        def x(self):
            return 2.0

        @x.setter
        def x(self, v):
            pass

    s2 = Shadowed()
    for k in VehicleState.__slots__:
        if k != "x":
            setattr(s2, k, getattr(s, k))
    a2, b2 = _both(s2, sp)
    assert a2 == b2 and a2 != a               # the property's 2.0, not the slot

    class Later(VehicleState):               # changed after its offsets were cached
        __slots__ = ()

    s3 = Later()
    for k in VehicleState.__slots__:
        setattr(s3, k, getattr(s, k))
    assert _both(s3, sp)[0] == a
    Later.y = property(lambda self: -3.0)
    a3, b3 = _both(s3, sp)
    assert a3 == b3 and a3 != a

    class WithDict(VehicleState):            # a dict-backed attribute beside the slots
        pass

    s4 = WithDict()
    for k in VehicleState.__slots__:
        setattr(s4, k, getattr(s, k))
    s4.extra = 1
    assert _both(s4, sp)[0] == a

    s5 = VehicleState()                      # an unset slot: Python's AttributeError
    del s5.z
    a5, b5 = _both(s5, sp)
    assert a5 == b5 and a5[0] is AttributeError


def test_a_slot_descriptor_borrowed_by_another_class_is_refused_as_python_does():
    """A class that took VehicleState's member descriptors: Python refuses to read it
    on that class's objects; the compiled reads must not read at VehicleState's offset."""
    class Borrower:
        __slots__ = tuple(f"own{i}" for i in range(len(VehicleState.__slots__)))

    for k in VehicleState.__slots__:
        setattr(Borrower, k, VehicleState.__dict__[k])
    o = Borrower()
    for name in Borrower.__slots__:             # what lies at VehicleState's offsets in o
        setattr(o, name, 0.5)
    a, b = _both(o, _setpoint())
    assert a == b and a[0] is TypeError and "doesn't apply" in a[1]
