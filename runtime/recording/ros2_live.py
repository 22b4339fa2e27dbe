"""Live ROS 2 topics of a run over rmw_zenoh (``ctrlunit start --ros2 [DOMAIN]``).

The recording's four ROS 2 topics (:mod:`.ros2`), with the same messages
byte for byte, published as a ROS 2 node ``/ctrlunit_<unit>`` would publish them with
rmw_zenoh (runtime/transport/ros2_zenoh.py), so that ``ros2 topic list`` and ``ros2
topic echo /joint_states`` on a host running ROS 2 with rmw_zenoh see them:
``/joint_states``, ``/platform/pose``, ``/platform/reference`` and
``/ctrlunit/diagnostics``. Stamps are the interval's command time on the run's clock, as
in the recording; the attachments' source timestamps are the wall clock, as rmw_zenoh's.

An observer, as the Foxglove view (runtime/observe/viewer.py): the central's thread only
appends an interval to a bounded deque, at most ``rate_hz`` a second of command time (the
live views' rate, ``--foxglove-rate``) and only while a ROS 2 subscriber matches; a
thread of its own, under the default scheduling policy, builds the messages and publishes
them under DROP congestion control at the lowest priority, into a Zenoh session of its
own that is a client of the ROS 2 router. The ROS 2 network never touches the unit's
links, and a subscriber slow, frozen or absent never delays a command: at worst Zenoh
drops messages, or the deque overflows and intervals are skipped (``dropped``).
"""

from __future__ import annotations

import threading
import time
from typing import TYPE_CHECKING, Any

from ..host import sched
from ..observe.signals import Interval, state_message
from ..observe.tap import IntervalTap
from ..observe.viewer import SEND_EVERY_S
from ..observe.zview import LISTENING_EVERY_S
from ..transport import ros2_zenoh as rz
from .ros2 import TOPICS, Ros2Channels, typestore

CLOSE_WAIT_S = 1.0
"""How long the end of a run waits for the session to close."""

if TYPE_CHECKING:
    from ..central.snapshot import Progress


class Ros2Publishers:
    """The node's liveliness token and one publisher per topic of :data:`TOPICS`, each
    with its token, in ``session``; ``add`` is a :class:`Ros2Channels`' sink."""

    def __init__(self, session: Any, *, domain: int, node: str) -> None:
        import zenoh

        self.session = session
        zid = str(session.info.zid())
        live = session.liveliness()
        self.tokens = [live.declare_token(rz.node_token(domain, zid, node))]
        self.pubs: list[Any] = []
        self.gids: list[bytes] = []
        self.seq: list[int] = []
        self.keys: dict[str, str] = {}
        for i, (topic, msgtype) in enumerate(TOPICS.items()):
            h = str(typestore().hash_rihs01(msgtype))
            token = rz.publisher_token(domain, zid, node, i + 1, topic, msgtype, h)
            self.keys[topic] = rz.topic_key(domain, topic, msgtype, h)
            self.pubs.append(session.declare_publisher(
                self.keys[topic], congestion_control=zenoh.CongestionControl.DROP,
                priority=zenoh.Priority.DATA_LOW))
            self.tokens.append(live.declare_token(token))
            self.gids.append(rz.gid(token))
            self.seq.append(0)
        self.sent = 0

    def register(self, topic: str, _msgtype: str, _definition: bytes) -> int:
        """The publisher of ``topic`` (its index)."""
        return list(TOPICS).index(topic)

    def add(self, i: int, _t_ns: int, data: bytes) -> None:
        """Publish ``data`` on publisher ``i`` with its attachment."""
        self.seq[i] += 1
        self.pubs[i].put(data, attachment=rz.attachment(self.seq[i], time.time_ns(),
                                                        self.gids[i]))
        self.sent += 1

    def matching(self) -> bool:
        """Whether a subscriber matches any topic."""
        return any(bool(getattr(p.matching_status, "matching", False)) for p in self.pubs)

    def close(self) -> None:
        for ent in (*self.pubs, *self.tokens):
            try:
                ent.undeclare()
            except Exception:  # the session closed first
                pass
        self.session.close()


class Ros2Live:
    """The live ROS 2 topics of one run; the central's ``on_cycle`` callback.

    Parameters
    ----------
    conf : the Zenoh configuration (runtime/transport/ros2_zenoh.py, ``session_config``).
    domain : the ROS 2 domain.
    unit : the unit id (the node ``ctrlunit_<unit>``, the diagnostics' hardware id).
    task : the task whose position is the reference (``None`` in freerun).
    period_s : the nominal period (s).
    rate_hz : intervals published a second of command time at most (0: every one).

    Raises whatever Zenoh raises when the session cannot open (no router answers).
    """

    def __init__(self, conf: Any, *, domain: int, unit: str, task: Any | None,
                 period_s: float, rate_hz: float) -> None:
        import zenoh

        self.domain, self.node = domain, rz.node_name(unit)
        self.router = ", ".join(rz.router_endpoints(conf))
        self.task, self.period_s = task, period_s
        self.pubs = Ros2Publishers(zenoh.open(conf), domain=domain, node=self.node)
        self.channels = Ros2Channels(self.pubs.register, self.pubs.add, unit)
        self.tap = IntervalTap(rate_hz=rate_hz)
        self._listening, self._asked = False, 0.0
        self._rejected_total = 0  # messages rejected, as of the last interval
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="ctrlunit-ros2", daemon=True)
        self._thread.start()

    @property
    def sent(self) -> int:
        """Messages published."""
        return self.pubs.sent

    @property
    def dropped(self) -> int:
        """Intervals due to be published that the thread skipped because it fell behind."""
        return self.tap.dropped

    # -- the central's thread ----------------------------------------------------------

    def __call__(self, progress: Progress, ctx: dict) -> None:
        """``on_cycle``: note the interval if it is due (a tuple into a bounded deque)."""
        self._rejected_total = sum(progress.rejected.values())
        if self._listening:
            self.tap.offer(progress, ctx)

    # -- its own thread ----------------------------------------------------------------

    def _publish_pending(self) -> None:
        self.tap.drain(self._publish)

    def _publish(self, iv: Interval) -> None:
        ch = self.channels
        sig = state_message(iv, period_s=self.period_s, task=self.task,
                            previous_cmd_ns=iv.previous_cmd_ns)
        ch.interval(iv.cmd_ns, sig, iv.qd)
        if ch.due(iv.cmd_ns):
            ch.status(iv.cmd_ns, misses=iv.misses, skipped=iv.skipped,
                      rejected=self._rejected_total)

    def _run(self) -> None:
        while not self._stop.wait(SEND_EVERY_S):
            # made after the real-time policy, and put back under it by the throttling
            # guard's restore: its work can wait
            sched.leave_rt()
            now = time.monotonic()
            if now - self._asked >= LISTENING_EVERY_S:
                self._asked = now
                try:
                    self._listening = self.pubs.matching()
                except Exception:  # the session is closing
                    self._listening = False
            self._publish_pending()
        self._publish_pending()

    # -- end ---------------------------------------------------------------------------

    def close(self, *, join_s: float = 1.0) -> None:
        """Publish what is left, then undeclare the tokens and close the session, waiting
        at most ``join_s`` for the thread and :data:`CLOSE_WAIT_S` for the session."""
        if self._stop.is_set():
            return
        self._stop.set()
        self._thread.join(timeout=join_s)
        closer = threading.Thread(target=self.pubs.close, name="ctrlunit-ros2-close",
                                  daemon=True)
        closer.start()
        closer.join(timeout=CLOSE_WAIT_S)

    def report(self) -> dict[str, Any]:
        """The report's ``ros2``: domain, node, router, messages sent, intervals dropped."""
        return {"domain": self.domain, "node": "/" + self.node, "router": self.router,
                "topics": list(TOPICS), "sent": self.sent, "dropped": self.dropped}
