"""`Onboard.rebooted()`: the hook `cosim sitl` respawns a crashed vehicle with (issue 13,
item 9). A vehicle force-disarmed in the air still reports IN_AIR; after the reboot, on the
same links, it is disarmed and on the ground, flies again, and keeps what a PX4 reboot keeps."""

from __future__ import annotations

from test_onboard_rig import Rig

from mav.onboard import IN_AIR, ON_GROUND

M = Rig.__init__.__globals__["M"]
FORCE = 21196


def test_a_rebooted_vehicle_is_disarmed_on_the_ground_on_the_same_links():
    rig = Rig(sysid=3)
    rig.tick(5)
    rig.send("gcs", M.MAVLink_param_set_message(3, 1, b"TPL_LAND_SPEED", 0.5,
                                                M.MAV_PARAM_TYPE_REAL32))
    rig.cmd(M.MAV_CMD_COMPONENT_ARM_DISARM, 1, target=3)
    rig.cmd(M.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, float("nan"), float("nan"), float("nan"),
            float("nan"), target=3)
    rig.tick(2)
    rig.odo[2] = -1.0                        # "climbed" to 1 m
    rig.run_until(lambda r: r.ob.landed_state == IN_AIR, 10.0)
    rig.cmd(M.MAV_CMD_COMPONENT_ARM_DISARM, 0, FORCE, target=3)
    rig.tick(2)
    old = rig.ob
    assert not old.armed and old.landed_state == IN_AIR     # what a respawn must clear

    rig.ob = old.rebooted()
    rig.odo[2] = 0.0                         # respawned on the floor
    rig.clear()
    rig.tick(3)
    ob = rig.ob
    assert not ob.armed and ob.landed_state == ON_GROUND and ob.mode_name == "POSCTL"
    assert ob.params.get("TPL_LAND_SPEED") == 0.5           # the user's parameter kept
    assert Rig().ob.params.get("TPL_LAND_SPEED") != 0.5     # (not the default)
    hb = rig.last("gcs", "HEARTBEAT")
    assert hb is not None and hb.get_srcSystem() == 3       # same sysid, same links
    assert rig.last("api", "HEARTBEAT") is not None
    ext = rig.last("gcs", "EXTENDED_SYS_STATE")
    assert ext.landed_state == M.MAV_LANDED_STATE_ON_GROUND
    rig.cmd(M.MAV_CMD_COMPONENT_ARM_DISARM, 1, target=3)
    rig.tick(2)
    assert ob.armed and rig.ack(M.MAV_CMD_COMPONENT_ARM_DISARM) == M.MAV_RESULT_ACCEPTED
