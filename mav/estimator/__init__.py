"""The onboard estimator, a part of its own (like PX4's EKF2): the vehicle hands it each
sensor-fed HIL datagram, it answers the state estimate.

    est = Estimator(vs.own, vs.stats, geo)
    est.estimate(data)         # data: HIL_SENSOR + HIL_OPTICAL_FLOW + DISTANCE_SENSOR (+ HIL_GPS)
                               # -> True if the estimate moved on (the datagram had a HIL_SENSOR)
    est.odometry(mav)          # -> the estimate as an ODOMETRY frame (quality -1: position lost)
    est.estimate_parts(parts)  # `estimate` of the messages unframed (MIL's typed exchange)
    est.record()               # -> the estimate as the 17-tuple wire.decode_odometry gives of
                               #    `odometry`'s frame (the same values, no frame)
    od = est.on_hil(data)      # `estimate`, then `record`, or None
    est.impl                   -> TemplateEstimator or ReleaseEstimator (its subclass): the
                               estimate in its fields
    est.link(hil, mav)         -> the HIL link with the estimator in front of the vehicle's
                               tick (link.py: sensor datagrams in, ODOMETRY of the estimate
                               to the tick, appended to the HIL answer for the logs)

Which estimator: the parameter TPL_EST_TYPE (0: none, the vehicle flies on ODOMETRY; 2: paper
1's released estimator, `release.py`, the Mambo's default; 1: the template's structure with
this stack's additions, `template.py`, the Bebop 2's and a Mambo with a GPS; an EKF is future
work). The truth in HIL_STATE_QUATERNION is never read here.
"""

from mav.estimator.core import Estimator
from mav.estimator.template import TemplateEstimator

__all__ = ["Estimator", "TemplateEstimator"]
