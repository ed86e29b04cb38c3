"""The distance from a sphere to a scene's obstacles (``Scene.clearance``, cosim/world/room.py),
the part of the collision check that runs on every tick: compiled with the tick (cosim's
``COMPILED`` list), and the same arithmetic, bit for bit, when run from source.

A scene hands it its room as ``walls`` (N min, N max, E min, E max, height; None without a
room) and its obstacles as records ``(is_box, name, cn, ce, cos, sin, half_l, half_w, top_d)``
(a box or a square column, turned by its heading) or ``(is_box, name, cn, ce, r, top_d)`` (a
cylinder), from ``Scene.solids``.
"""

from __future__ import annotations

import math

import cython


@cython.locals(best=cython.double, dist=cython.double, x=cython.double, y=cython.double,
               z=cython.double, dn=cython.double, de=cython.double, ox=cython.double,
               oy=cython.double, oz=cython.double, top=cython.double, cu=cython.double,
               su=cython.double, m=cython.double, i=cython.Py_ssize_t)
def sphere_clearance(walls: tuple | None, solids: list, n: float, e: float, d: float,
                     radius: float) -> tuple[float, str]:
    """(distance from a sphere of ``radius`` at (n, e, d) to the nearest obstacle surface,
    m, negative when they overlap; the obstacle's name). Floor excluded."""
    best, what = math.inf, ""
    if walls is not None:
        for dist, name in ((n - walls[0], "south wall"), (walls[1] - n, "north wall"),
                           (e - walls[2], "west wall"), (walls[3] - e, "east wall"),
                           (d + walls[4], "ceiling")):
            if dist < best:
                best, what = dist, name
    for i in range(len(solids)):
        s = solids[i]
        top = s[-1]
        if s[0]:
            dn, de = n - s[2], e - s[3]
            cu, su = s[4], s[5]
            x = abs(dn * cu + de * su) - s[6]
            y = abs(-dn * su + de * cu) - s[7]
        else:
            x = math.hypot(n - s[2], e - s[3]) - s[4]
            y = -math.inf
        z = max(top - d, d)
        # signed distance to an axis-aligned box in the solid's frame
        ox, oy, oz = max(x, 0.0), max(y, 0.0), max(z, 0.0)
        m = max(x, y, z)
        dist = math.sqrt(ox * ox + oy * oy + oz * oz) + min(m, 0.0)
        if dist < best:
            best, what = dist, s[1]
    return best - radius, what
