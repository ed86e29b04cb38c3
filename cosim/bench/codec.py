"""The fast codec's speed against pymavlink's (`python -m cosim.bench.codec` prints the table;
tests/test_onboard_wire.py checks the speed-up): mav/wire.py's benchmark, in a file of its own."""

from __future__ import annotations

import math

from pymavlink.dialects.v20 import common as mavlink2

from mav.wire import (
    ATTITUDE,
    HIL_ACTUATOR_CONTROLS,
    LOCAL_POSITION_NED,
    ODOMETRY,
    SET_POSITION_TARGET_LOCAL_NED,
    decode_fast,
    decode_odometry,
    encode_attitude,
    encode_hil_actuator_controls,
    encode_local_position_ned,
    encode_odometry,
    encode_set_position_target_local_ned,
)


def bench(n: int = 20000, repeat: int = 5) -> dict[str, tuple[float, float]]:
    """us per message (pymavlink, fast) for encode and decode of the per-tick messages
    (best of `repeat` runs of `n`). pymavlink encode = message construction + pack, decode =
    `MAVLink.decode`; fast = mav/wire.py. `python -m cosim.bench.codec` prints the table."""
    import timeit

    mav_a = mavlink2.MAVLink(None, 1, 1)
    mav_b = mavlink2.MAVLink(None, 1, 1)
    cov = [math.nan] + [0.0] * 20
    odo_args = (123456789, 0.1, -0.2, -1.0, 0.99, 0.01, -0.02, 0.1, 0.3, -0.1, 0.05, 0.01,
                0.02, -0.03)
    objs = {
        "ODOMETRY": (mavlink2.MAVLink_odometry_message(
            odo_args[0], 1, 1, *odo_args[1:4], list(odo_args[4:8]), *odo_args[8:14], cov, cov,
            0, 0, 100),
            lambda: encode_odometry(mav_b, *odo_args, quality=100), ODOMETRY),
        "HIL_ACTUATOR_CONTROLS": (mavlink2.MAVLink_hil_actuator_controls_message(
            123456789, [0.61, 0.62, 0.63, 0.64] + [0.0] * 12, 129, 1),
            lambda: encode_hil_actuator_controls(mav_b, 123456789, 0.61, 0.62, 0.63, 0.64, 129),
            HIL_ACTUATOR_CONTROLS),
        "SET_POSITION_TARGET_LOCAL_NED": (mavlink2.MAVLink_set_position_target_local_ned_message(
            1234, 1, 1, 1, 0x0DF8, 1.0, 2.0, -1.0, 0, 0, 0, 0, 0, 0, 0, 0),
            lambda: encode_set_position_target_local_ned(mav_b, 1234, 1, 1, 1, 0x0DF8, 1.0, 2.0,
                                                         -1.0, 0, 0, 0, 0, 0, 0, 0, 0),
            SET_POSITION_TARGET_LOCAL_NED),
        "LOCAL_POSITION_NED": (mavlink2.MAVLink_local_position_ned_message(
            1234, 1.0, 2.0, -1.0, 0.1, 0.2, 0.3),
            lambda: encode_local_position_ned(mav_b, 1234, 1.0, 2.0, -1.0, 0.1, 0.2, 0.3),
            LOCAL_POSITION_NED),
        "ATTITUDE": (mavlink2.MAVLink_attitude_message(1234, 0.1, 0.2, 0.3, 0.01, 0.02, 0.03),
                     lambda: encode_attitude(mav_b, 1234, 0.1, 0.2, 0.3, 0.01, 0.02, 0.03),
                     ATTITUDE),
    }
    out = {}
    for name, (msg, fast_enc, fm) in objs.items():
        data = msg.pack(mav_a)
        cls = type(msg)
        args = [getattr(msg, f) for f in cls.fieldnames]

        def py_enc(cls=cls, args=args):      # construct + pack, as mav.<msg>_send does
            return cls(*args).pack(mav_a)

        assert py_enc() == data
        t_pe = min(timeit.repeat(py_enc, number=n, repeat=repeat))
        t_fe = min(timeit.repeat(fast_enc, number=n, repeat=repeat))
        t_pd = min(timeit.repeat(lambda data=data: mav_a.decode(bytearray(data)), number=n,
                                 repeat=repeat))
        def fast_dec(data=data, fm=fm):
            return decode_odometry(data) if fm is ODOMETRY else decode_fast(fm, data)

        t_fd = min(timeit.repeat(fast_dec, number=n, repeat=repeat))
        out[name + " encode"] = (t_pe / n * 1e6, t_fe / n * 1e6)
        out[name + " decode"] = (t_pd / n * 1e6, t_fd / n * 1e6)
    return out



def main() -> None:
    print(f"{'message':<40}{'pymavlink us':>14}{'fast us':>10}{'speed-up':>10}")
    for k, (a, b) in bench().items():
        print(f"{k:<40}{a:>14.2f}{b:>10.2f}{a / b:>9.1f}x")


if __name__ == "__main__":
    main()
