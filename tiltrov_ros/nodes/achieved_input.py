"""The pid's anti-windup input of the controller node: ``wrench_achieved``.

The allocator answers each ``wrench_cmd`` with ``wrench_achieved`` (eq. (4) of
its answer) stamped alike. The pid is given, at each tick, the achieved wrench
that answers the controller's previous wrench (the one stamped with the last
tick the node answered; :class:`~tiltrov_ros.core.controllers.PIDController`):
with ``gains.antiwindup`` > 0 its integral then holds still where that wrench
fell short. The headless runner passes the same, one tick late, so a lockstep
run stays equal to it: there, while the anti-windup is on, a pid tick waits
for that answer as for its setpoint velocity, however long, when a node publishes
it at the run's handshake (the controller decides once). The newest message by
stamp is kept; a stamp going back (a restarted stack) is taken as it comes.
"""

from __future__ import annotations

from typing import Any

from geometry_msgs.msg import WrenchStamped

from tiltrov_ros.core.names import FRAME_BODY, WRENCH_ACHIEVED
from tiltrov_ros.core.validation import check_finite

from .conversions import FloatArray, wrench_array
from .guard import input_callback
from .qos import RELIABLE_QOS


class AchievedInput:
    """A base of the controller node (which gives ``kind``, ``_last_ns``,
    ``period_ns``, ``_try_compute`` and the node's subscriptions)."""

    def init_achieved_input(self: Any) -> None:
        self._achieved: tuple[int, FloatArray] | None = None
        if self.kind == 'pid':
            self.create_input_subscription(WrenchStamped, WRENCH_ACHIEVED, self._on_achieved,
                                           RELIABLE_QOS)

    @input_callback(WRENCH_ACHIEVED)
    def _on_achieved(self: Any, msg: WrenchStamped) -> None:
        ns = self.check_header(msg.header, FRAME_BODY)
        wrench = wrench_array(msg)
        check_finite(wrench, 'wrench')
        if self._achieved is None or ns >= self._achieved[0] or ns < self._last_ns:
            self._achieved = (ns, wrench)
            self._try_compute()

    def achieved_of_last(self: Any) -> FloatArray | None:
        """The achieved wrench that answers the node's last wrench, if it came."""
        got = self._achieved
        return got[1] if got is not None and got[0] == self._last_ns else None

    def waits_for_achieved(self: Any, ns: int) -> bool:
        """Lockstep: the pid's tick ``ns`` still waits for the answer to the previous tick."""
        return bool(getattr(self.controller, 'uses_achieved', False)
                    and self._last_ns == ns - self.period_ns and self.achieved_of_last() is None)
