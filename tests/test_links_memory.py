"""The compiled in-memory link (mav/csrc/memlink.c) against the Python reference
(mav.links.MemoryLink): one random script of sends, receives, counts and closes played on
both, the same answers step by step; and the pair's memory is reclaimed."""

from __future__ import annotations

import gc
import random
import sys

import pytest

from mav import fastpath, reference
from mav.links import MemoryLink, memory_link, memory_pair

C = fastpath.lib.MemoryLink if fastpath.lib is not None else None


def _play(cls, seed: int) -> list:
    rng = random.Random(seed)
    a, b = cls.pair()
    ends = (a, b)
    log = []
    for _ in range(4000):
        end = ends[rng.randrange(2)]
        r = rng.random()
        if r < 0.45:
            n = rng.randrange(0, 300)
            raw = bytes(rng.randrange(256) for _ in range(n))
            kind = rng.randrange(3)
            data = raw if kind == 0 else bytearray(raw) if kind == 1 else memoryview(raw)
            log.append(("send", end.send(data)))
        elif r < 0.85:
            got = end.recv()
            log.append(("recv", got, type(got)))
        elif r < 0.95:
            log.append(("pending", end.pending()))
        elif r < 0.98:
            log.append(("close", end.close()))
        else:
            end.sent_bytes = rng.randrange(1000)
        log.append(("sent", a.sent_bytes, b.sent_bytes))
    while b.pending() or a.pending():           # queues longer than the ring's first size
        log.append((a.recv(), b.recv()))
    return log


@pytest.mark.skipif(C is None, reason="needs the compiled fast path (python -m mav.build)")
@pytest.mark.parametrize("seed", range(4))
def test_compiled_memory_link_answers_as_the_reference(seed):
    assert _play(C, seed) == _play(MemoryLink, seed)


@pytest.mark.skipif(C is None, reason="needs the compiled fast path (python -m mav.build)")
def test_compiled_memory_link_edges_and_memory():
    one = C()
    with pytest.raises(AttributeError):          # no peer: nothing can be sent
        one.send(b"x")
    with pytest.raises(AttributeError):
        MemoryLink().send(b"x")
    with pytest.raises(TypeError):
        C(1)
    a, b = C.pair()
    with pytest.raises(TypeError):
        a.send(5.0)                                  # len() of a float: refused, nothing queued
    assert b.pending() == 0 and a.sent_bytes == 0
    payload = bytes(range(200)) * 3
    before = sys.getrefcount(payload)
    for _ in range(100):
        a.send(payload)
    assert sys.getrefcount(payload) == before + 100
    del a, b                                         # a cycle (each end holds its peer)
    gc.collect()
    assert sys.getrefcount(payload) == before


def test_memory_pair_follows_the_fast_path_switch():
    a, _ = memory_pair()
    assert type(a) is (C if C is not None else MemoryLink)
    with reference.python():
        a, _ = memory_pair()
        assert type(a) is MemoryLink and type(memory_link()) is MemoryLink


@pytest.mark.skipif(C is None, reason="needs the compiled fast path (python -m mav.build)")
def test_compiled_tap_link_logs_as_the_reference(tmp_path):
    from cosim.outputs.tlog import TapLink, Tlog, tap

    out = {}
    for name, make in (("c", tap), ("py", TapLink)):
        rng = random.Random(11)
        log = Tlog(tmp_path / f"{name}.tlog")
        a, b = MemoryLink.pair()
        t = make(a, log)
        assert type(t) is (TapLink if name == "py" else fastpath.lib.TapLink)
        got = []
        for k in range(3000):
            log.t_us = k * 5000 + rng.randrange(5000)
            r = rng.random()
            if r < 0.4:
                t.send(bytes(rng.randrange(256) for _ in range(rng.randrange(1, 80))))
            elif r < 0.7:
                b.send(bytes(rng.randrange(256) for _ in range(rng.randrange(1, 80))))
            else:
                got.append(t.recv())
            if k == 1500:          # a fault wrapper put in place mid-run (cosim.sim.onboard)
                c, d = MemoryLink.pair()
                t.inner, b = c, d
        got.append(b.recv())
        t.close()
        log.close()
        out[name] = (got, log.count, log.read(), t.inner is not None)
    assert out["c"] == out["py"]
    assert out["c"][1] > 2000


@pytest.mark.skipif(C is None, reason="needs the compiled fast path (python -m mav.build)")
def test_compiled_tap_link_without_its_parts_raises_not_crashes(tmp_path):
    from cosim.outputs.tlog import Tlog

    T = fastpath.lib.TapLink
    bare = T.__new__(T)
    for call in (lambda: bare.send(b"x"), bare.recv, bare.close):
        with pytest.raises(AttributeError):
            call()
    log = Tlog(tmp_path / "t.tlog")
    t = T(MemoryLink.pair()[0], log)
    del t.inner
    with pytest.raises(AttributeError):
        t.send(b"x")
    with pytest.raises(TypeError):
        T(1)
    log.close()


def test_compiled_tap_links_in_a_loop_or_changed_while_logging_raise_not_crash(tmp_path):
    """Taps call their inner link directly from C: a loop of taps still ends in Python's
    RecursionError, and a log that takes the inner link away meanwhile gets an error."""
    from cosim.outputs.tlog import Tlog

    T = fastpath.lib.TapLink
    log = Tlog(tmp_path / "t.tlog")
    a = T(MemoryLink.pair()[0], log)
    b = T(a, log)
    a.inner = b                                  # a -> b -> a -> ...
    for call in (lambda: a.send(b"x"), a.recv):
        with pytest.raises(RecursionError):
            call()
    me = T(MemoryLink.pair()[0], log)
    me.inner = me
    with pytest.raises(RecursionError):
        me.send(b"x")

    class Thief:                                 # a log whose write drops the tap's link
        t_us, count = 0, 0

        def _write(self, rec):
            del victim.inner

    victim = T(MemoryLink.pair()[0], Thief())
    with pytest.raises(AttributeError):
        victim.send(b"x")
    log.close()
