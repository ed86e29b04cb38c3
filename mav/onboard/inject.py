"""Failure injection from the simulator: battery faults arrive on the HIL link as MAVLink.

The battery model lives in the flight stack (`mav/battery.py`), as PX4's SITL battery
simulator lives in PX4, out of the master's reach; the master's `[faults]` table
(`cosim/faults/battery.py`) reaches it the way every other byte does, as MAVLink on the
HIL link, so MIL (in-memory) and SIL (UDP) carry the same bytes at the same simulated time.

The message: COMMAND_LONG MAV_CMD_INJECT_FAILURE (420), sent by the simulator (system 250,
component MAV_COMP_ID_USER1, its fault injector: `mav.hil.encode_inject_failure`) just before a
tick's ODOMETRY, to target_system 0 or the vehicle's, target_component 0 or the autopilot's:

    param1  FAILURE_UNIT_SYSTEM_BATTERY (100)      other units: ignored
    param2  FAILURE_TYPE_OK (0)     the sag ends (charge lost stays lost)
            FAILURE_TYPE_OFF (1)    the charge drops to param4 of the capacity, and stays lost
                                    (a failed cell; PX4's battery simulator reads "empty" for
                                    OFF: param4 = 0, the default, is that)
            FAILURE_TYPE_WRONG (4)  the voltage sags: internal resistance x param4 (> 0; 0, the
                                    default, means 1) and a further fixed drop of param5 V
            other types: ignored
    param3  instance: 0 (all) or 1 (the one pack); others: ignored
    param4  OFF: state of charge left, 0..1; WRONG: resistance factor, 0..1000
    param5  WRONG: fixed drop, 0..100 V
    param4 and param5 are reserved in MAVLink's definition of 420: their use is this project's
    extension. param6, param7: unused.

Only on the HIL link: the simulator's link is this stack's "specific protection" the MAVLink
definition asks for. On the api and gcs links 420 is DENIED (COMMAND_ACK; PX4 answers so with
SYS_FAILURE_EN = 0, its default) and counted (`inject_denied`). On HIL nothing is answered (the
lockstep carries exactly one HIL_ACTUATOR_CONTROLS per ODOMETRY) and nothing is said on the
other links (a real pack does not announce its failure): an applied command counts
`faults_injected`, an unusable one `hil_ignored`. The battery failsafes react through their
normal path: they compare the charge used (drawn + lost) with BAT_*_THR (`failsafe.py`), so a
drain fires them; a sag changes the voltage reported (SYS_STATUS, BATTERY_STATUS) and the
energy integral, not the charge, so it does not.
"""

from __future__ import annotations

import math

from mav import wire
from mav.hil import MAX_R_SCALE, MAX_V_DROP
from mav.onboard.defs import M
from mav.onboard.status import VehicleStatus


def battery_failure(vs: VehicleStatus, msg, sysid: int, compid: int) -> bool:
    """Apply one COMMAND_LONG received on the HIL link; True if it was a battery failure this
    stack applies (see the module docstring), else False (nothing changed)."""
    if msg.command != M.MAV_CMD_INJECT_FAILURE or msg.target_system not in (0, sysid) \
            or msg.target_component not in (0, compid):
        return False
    p = (msg.param1, msg.param2, msg.param3, msg.param4, msg.param5)
    if not all(math.isfinite(v) for v in p):
        return False
    unit, kind, inst, p4, p5 = p
    if unit != M.FAILURE_UNIT_SYSTEM_BATTERY or inst not in (0.0, 1.0):
        return False
    b = vs.battery
    if kind == M.FAILURE_TYPE_OK:
        b.sag(1.0, 0.0)
    elif kind == M.FAILURE_TYPE_OFF:
        if not 0.0 <= p4 <= 1.0:
            return False
        b.lose_charge(p4)
    elif kind == M.FAILURE_TYPE_WRONG:
        if not (0.0 <= p4 <= MAX_R_SCALE and 0.0 <= p5 <= MAX_V_DROP):
            return False
        b.sag(p4 if p4 > 0.0 else 1.0, p5)
    else:
        return False
    return True


def hil_other(vs: VehicleStatus, hil_mav, data: bytes, sysid: int, compid: int) -> str:
    """A HIL datagram that is not a valid ODOMETRY, handled: a battery fault from the
    simulator (applied now, on the clock of the previous tick: `battery_failure`), another
    message (ignored, e.g. a HEARTBEAT) or garbage. Returns the counter it counts in:
    faults_injected, hil_ignored or dropped_bad_hil."""
    if wire.frame_end(data, 0) == len(data):
        try:
            msg = hil_mav.decode(bytearray(data))
        except Exception:
            msg = None
        if msg is not None and not isinstance(msg, M.MAVLink_unknown):
            if msg.get_msgId() == M.MAVLINK_MSG_ID_COMMAND_LONG and battery_failure(
                    vs, msg, sysid, compid):
                return "faults_injected"
            return "hil_ignored"
    return "dropped_bad_hil"
