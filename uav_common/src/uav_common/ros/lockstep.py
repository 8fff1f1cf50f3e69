"""A ROS node's side of the causal lockstep (docs/lockstep.md), or a thin pass-through to rospy.

Every in-loop Python node builds one :class:`Participant` after ``rospy.init_node`` and makes its subscriptions,
publishers, timers, services, service calls and tf through it, then calls :meth:`Participant.spin`. With the
global parameter ``/lockstep/causal`` false (free-running time, plain lockstep, a real vehicle) those are
rospy's own, exactly as before. With it true, the node takes part in the causal lockstep:

* it joins the step master (``/lockstep/join``) with its manifest and lookahead, and then works step by step
  in the thread that called :meth:`spin`: for each tick it waits until every counted input has arrived,
  dispatches the step's messages in a fixed order, fires its simulated-time timers and step hooks, and
  reports done with its published counts;
* ``rospy.get_time()`` is the step's time in every thread of the node (``/clock`` no longer moves it);
* its subscriptions are unbounded and ``tcp_nodelay``; its publishers never drop (an unbounded queue);
* its services apply requests at the step boundary the caller names, and its calls name that boundary.

The bookkeeping is :mod:`uav_common.lockstep.protocol` (pure); this module only moves messages and threads.
"""

from __future__ import annotations

import contextlib
import threading
import time
from collections import deque
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any

from uav_common.lockstep.protocol import (
    BoundaryQueue,
    InputLedger,
    LockstepError,
    Manifest,
    Missing,
    StepBarrier,
    Tick,
)
from uav_common.lockstep.timers import SimTimer

__all__ = ["APPLY_AFTER_HEADER", "LockstepSettings", "Participant", "StepMaster", "causal_enabled", "read_settings"]

#: The service connection header naming the step boundary a request applies at (docs/lockstep.md).
APPLY_AFTER_HEADER = "lockstep_apply_after"
DEFAULT_NS = "/lockstep"
#: Wall seconds between "still waiting" log lines (a watchdog that only reports).
_REPORT_EVERY_S = 10.0


@dataclass(frozen=True)
class LockstepSettings:
    """The global ``/lockstep/*`` parameters as one node sees them."""

    causal: bool = False
    lookahead_steps: int = 1
    watchdog_s: float = 120.0
    ns: str = DEFAULT_NS


def causal_enabled(ns: str = DEFAULT_NS) -> bool:
    """Is this run's time the causal lockstep (``/lockstep/causal``)?"""
    import rospy  # noqa: PLC0415

    return bool(rospy.get_param(f"{ns}/causal", False))


def read_settings(node: str, default_lookahead: int, ns: str = DEFAULT_NS) -> LockstepSettings:
    """The node's lockstep settings from the parameter server.

    Raises:
        LockstepError: a malformed ``/lockstep/lookahead_steps`` or ``/lockstep/watchdog_s``.
    """
    import rospy  # noqa: PLC0415

    causal = bool(rospy.get_param(f"{ns}/causal", False))
    table = rospy.get_param(f"{ns}/lookahead_steps", {}) or {}
    if not isinstance(table, Mapping):
        msg = f"{ns}/lookahead_steps must map node names to steps, got {table!r}"
        raise LockstepError(msg)
    bare = node.lstrip("/")
    value = table.get(bare, table.get(node, default_lookahead))
    if isinstance(value, bool) or not isinstance(value, int) or value < 1:
        msg = f"{ns}/lookahead_steps/{bare} must be an integer >= 1, got {value!r}"
        raise LockstepError(msg)
    watchdog = rospy.get_param(f"{ns}/watchdog_s", 120.0)
    if isinstance(watchdog, bool) or not isinstance(watchdog, int | float) or not watchdog > 0:
        msg = f"{ns}/watchdog_s must be a positive number of seconds, got {watchdog!r}"
        raise LockstepError(msg)
    return LockstepSettings(causal, int(value), float(watchdog), ns)


@dataclass
class _Request:
    handler: Callable[[Any], Any]
    request: Any
    done: threading.Event = field(default_factory=threading.Event)
    response: Any = None
    error: BaseException | None = None


class _Counter:
    """Who counts a :class:`CountingPublisher`'s messages (a participant or the step master)."""

    def count(self, topic: str) -> None:
        raise NotImplementedError


class CountingPublisher:
    """A rospy publisher whose messages the lockstep counts (it never drops in causal mode)."""

    def __init__(self, owner: _Counter, topic: str, pub: Any) -> None:
        self._owner = owner
        self.topic = topic
        self.impl = pub

    @property
    def name(self) -> str:
        return str(self.impl.resolved_name)

    def publish(self, msg: Any) -> None:
        self.impl.publish(msg)
        self._owner.count(self.name)

    def get_num_connections(self) -> int:
        return int(self.impl.get_num_connections())

    def unregister(self) -> None:
        self.impl.unregister()


class TfBroadcaster:
    """``sendTransform`` onto a counted ``/tf`` (or latched ``/tf_static``) publisher."""

    def __init__(self, pub: CountingPublisher, *, static: bool) -> None:
        self._pub = pub
        self._static = static
        self._statics: dict[str, Any] = {}

    def sendTransform(self, transform: Any) -> None:  # noqa: N802 - tf2_ros's name
        from tf2_msgs.msg import TFMessage  # noqa: PLC0415

        items = list(transform) if isinstance(transform, list | tuple) else [transform]
        if self._static:  # like tf2_ros.StaticTransformBroadcaster: the latched message holds every static frame
            for t in items:
                self._statics[t.child_frame_id] = t
            items = list(self._statics.values())
        self._pub.publish(TFMessage(transforms=items))


class Participant(_Counter):
    """One node's lockstep participation (see the module docstring). Build it after ``rospy.init_node``.

    Args:
        lookahead_steps: the node's default lookahead (``/lockstep/lookahead_steps`` overrides it).
        ns: the protocol's namespace.
    """

    def __init__(self, *, lookahead_steps: int, ns: str = DEFAULT_NS) -> None:
        import rospy  # noqa: PLC0415

        self.node = rospy.get_name()
        self.settings = read_settings(self.node, lookahead_steps, ns)
        self.causal = self.settings.causal
        self._cond = threading.Condition()
        self._ledger: InputLedger[Any] = InputLedger(())
        self._callbacks: dict[str, list[Callable[[Any], None]]] = {}
        self._counts: dict[str, int] = {}
        self._count_lock = threading.Lock()
        self._ticks: deque[Tick] = deque()
        self._requests: BoundaryQueue[_Request] = BoundaryQueue()
        self._timers: list[tuple[SimTimer, Callable[[float], None]]] = []
        self._step_hooks: list[Callable[[int, float], None]] = []
        self._before_hooks: list[Callable[[int, float], None]] = []
        self._after_hooks: list[Callable[[int, float], None]] = []
        self._subs: list[Any] = []
        self._inputs: list[str] = []
        self._outputs: list[str] = []
        self.finished_step = 0
        self.processing_step: int | None = None
        self.t_s = 0.0
        self.step_s = 0.0
        self._first_step = 1
        self._joined = False
        self._stopped = False
        if self.causal:
            self._take_over_clock()
            self._tick_sub = rospy.Subscriber(f"{ns}/tick", _tick_class(), self._on_tick, queue_size=None)
            self._done_pub = rospy.Publisher(f"{ns}/done", _done_class(), queue_size=0, tcp_nodelay=True)
            rospy.on_shutdown(self._on_shutdown)

    # ------------------------------------------------------------------ building the node
    def subscribe(
        self,
        topic: str,
        msg_class: Any,
        callback: Callable[[Any], None],
        *,
        queue_size: int | None = 1,
        buff_size: int = 2**16,
        priority: bool = False,
    ) -> Any:
        """A lockstep input (causal) or a plain subscription with ``queue_size`` (otherwise)."""
        import rospy  # noqa: PLC0415

        if not self.causal:
            sub = rospy.Subscriber(topic, msg_class, callback, queue_size=queue_size, buff_size=buff_size)
            self._subs.append(sub)
            return sub
        resolved = rospy.resolve_name(topic)
        first = resolved not in self._callbacks
        self._callbacks.setdefault(resolved, []).append(callback)
        if not first:
            return None
        self._ledger.add_topic(resolved, first=priority)
        self._inputs.append(resolved)

        def received(msg: Any, _topic: str = resolved) -> None:
            header = getattr(msg, "_connection_header", None) or {}
            publisher = str(header.get("callerid", ""))
            with self._cond:
                self._ledger.received(_topic, publisher, msg)
                self._cond.notify_all()

        sub = rospy.Subscriber(resolved, msg_class, received, queue_size=None, buff_size=buff_size, tcp_nodelay=True)
        self._subs.append(sub)
        return sub

    def publisher(self, topic: str, msg_class: Any, *, queue_size: int = 10, latch: bool = False) -> Any:
        """A counted publisher that never drops (causal) or a plain one (otherwise)."""
        import rospy  # noqa: PLC0415

        if not self.causal:
            return rospy.Publisher(topic, msg_class, queue_size=queue_size, latch=latch)
        pub = rospy.Publisher(topic, msg_class, queue_size=0, latch=latch, tcp_nodelay=True)
        counted = CountingPublisher(self, topic, pub)
        if counted.name not in self._outputs:
            self._outputs.append(counted.name)
            with self._count_lock:
                self._counts.setdefault(counted.name, 0)
        return counted

    def count(self, topic: str) -> None:
        with self._count_lock:
            self._counts[topic] = self._counts.get(topic, 0) + 1

    def timer(self, period_s: float, callback: Callable[[float], None], *, name: str = "") -> None:
        """``callback(now_s)`` every ``period_s`` of simulated time (from the step when causal)."""
        import rospy  # noqa: PLC0415

        if not self.causal:
            rospy.Timer(rospy.Duration(period_s), lambda _e: callback(rospy.get_time()))
            return
        self._timers.append((SimTimer(period_s, name=name or getattr(callback, "__name__", "")), callback))

    def on_step(self, callback: Callable[[int, float], None]) -> None:
        """``callback(step, now_s)`` once a step, after the inputs and timers (causal only)."""
        self._step_hooks.append(callback)

    def around_step(
        self,
        before: Callable[[int, float], None] | None = None,
        after: Callable[[int, float], None] | None = None,
    ) -> None:
        """``before(step, now_s)`` ahead of the step's inputs (e.g. a MAVLink link reads up to the step's marker),
        ``after(step, now_s)`` once the step's work is done, before done is reported (causal only)."""
        if before is not None:
            self._before_hooks.append(before)
        if after is not None:
            self._after_hooks.append(after)

    def service(self, name: str, srv_class: Any, handler: Callable[[Any], Any]) -> Any:
        """A service whose requests apply at step boundaries (causal) or at once (otherwise)."""
        import rospy  # noqa: PLC0415

        if not self.causal:
            return rospy.Service(name, srv_class, handler)

        def deferred(req: Any) -> Any:
            header = getattr(req, "_connection_header", None) or {}
            item = _Request(handler, req)
            with self._cond:
                raw = header.get(APPLY_AFTER_HEADER)
                if raw is None:  # an operator or a test: the next boundary
                    boundary = self.processing_step if self.processing_step is not None else self.finished_step
                else:
                    boundary = int(raw)
                    if boundary < self.finished_step:
                        text = (
                            f"{self.node}: {name} from {header.get('callerid', '?')} for the boundary after step "
                            f"{boundary} came after step {self.finished_step}: the run is no longer reproducible"
                        )
                        rospy.logerr(text)
                        raise rospy.ServiceException(text)
                self._requests.put(boundary, item)
                self._cond.notify_all()
            while not item.done.wait(1.0):
                if rospy.is_shutdown():
                    text = f"{self.node} is shutting down"
                    raise rospy.ServiceException(text)
            if item.error is not None:
                raise item.error
            return item.response

        return rospy.Service(name, srv_class, deferred)

    def call(self, name: str, srv_class: Any, request: Any, *, wait_s: float = 2.0) -> Any:
        """Call a service (``rospy.ServiceProxy``); causal: applied at the boundary after step
        ``processing_step + L - 1`` of the server (docs/lockstep.md).

        Raises:
            rospy.ROSException, rospy.ServiceException: as ``rospy.ServiceProxy`` does.
        """
        import rospy  # noqa: PLC0415

        rospy.wait_for_service(name, timeout=wait_s)
        headers = None
        if self.causal:
            step = self.processing_step if self.processing_step is not None else self.finished_step
            headers = {APPLY_AFTER_HEADER: str(step + self.settings.lookahead_steps - 1)}
        return rospy.ServiceProxy(name, srv_class, headers=headers)(request)

    def tf_buffer(self, cache_s: float = 30.0) -> Any:
        """A tf2 buffer: fed by counted ``/tf`` and ``/tf_static`` inputs (causal), or a ``TransformListener``."""
        import rospy  # noqa: PLC0415
        import tf2_ros  # noqa: PLC0415
        from tf2_msgs.msg import TFMessage  # noqa: PLC0415

        buf = tf2_ros.Buffer(cache_time=rospy.Duration(cache_s))
        if not self.causal:
            self._listener = tf2_ros.TransformListener(buf)
            return buf

        def dynamic(msg: Any) -> None:
            for t in msg.transforms:
                buf.set_transform(t, "lockstep")

        def static(msg: Any) -> None:
            for t in msg.transforms:
                buf.set_transform_static(t, "lockstep")

        self.subscribe("/tf_static", TFMessage, static, priority=True, buff_size=2**20)
        self.subscribe("/tf", TFMessage, dynamic, priority=True, buff_size=2**20)
        return buf

    def tf_broadcaster(self, *, static: bool = False) -> Any:
        """``sendTransform`` onto ``/tf`` (``/tf_static``, latched): counted (causal) or tf2_ros's."""
        import tf2_ros  # noqa: PLC0415
        from tf2_msgs.msg import TFMessage  # noqa: PLC0415

        if not self.causal:
            return tf2_ros.StaticTransformBroadcaster() if static else tf2_ros.TransformBroadcaster()
        topic = "/tf_static" if static else "/tf"
        return TfBroadcaster(self.publisher(topic, TFMessage, latch=static), static=static)

    def now_s(self) -> float:
        import rospy  # noqa: PLC0415

        return self.t_s if self.causal else rospy.get_time()

    # ------------------------------------------------------------------ running
    def spin(self) -> None:
        """``rospy.spin()``; causal: join, then process ticks in this thread until shutdown.

        Raises:
            LockstepError: the master refused the join, a tick came out of order, an input never arrived.
        """
        import rospy  # noqa: PLC0415

        if not self.causal:
            rospy.spin()
            return
        self._join()
        while not rospy.is_shutdown() and not self._stopped:
            work = self._next_work()
            if work is None:
                continue
            if isinstance(work, Tick):
                self._run_step(work)
            else:
                self._serve(work)

    def _join(self) -> None:
        import rospy  # noqa: PLC0415

        from uav_msgs.srv import LockstepJoin, LockstepJoinRequest  # noqa: PLC0415

        service = f"{self.settings.ns}/join"
        started = time.monotonic()
        while not rospy.is_shutdown():
            try:
                rospy.wait_for_service(service, timeout=_REPORT_EVERY_S)
                break
            except rospy.ROSException:
                rospy.logwarn(
                    f"{self.node}: lockstep: still waiting for the step master's {service} "
                    f"({time.monotonic() - started:.0f} s; is the sim bridge up?)"
                )
        with self._count_lock:
            published = dict(self._counts)
        req = LockstepJoinRequest(
            node=self.node,
            lookahead_steps=self.settings.lookahead_steps,
            inputs=list(self._inputs),
            outputs=list(self._outputs),
            timers=[t.describe() for t, _ in self._timers],
            published=_count_msgs(self.node, published),
        )
        resp = rospy.ServiceProxy(service, LockstepJoin)(req)
        if not resp.accepted:
            msg = f"{self.node}: the step master refused the join: {resp.message}"
            raise LockstepError(msg)
        self._first_step = int(resp.first_step)
        self.finished_step = self._first_step - 1
        self.step_s = float(resp.step_s)
        self._joined = True
        rospy.loginfo(
            f"{self.node}: lockstep: joined (lookahead {self.settings.lookahead_steps} steps, "
            f"{len(self._inputs)} inputs, {len(self._outputs)} outputs, {len(self._timers)} timers)"
        )

    def _next_work(self) -> Tick | list[_Request] | None:
        """The due service requests, else the next tick; waits (reporting, never giving up) for either."""
        import rospy  # noqa: PLC0415

        waited_since = time.monotonic()
        reported = waited_since
        with self._cond:
            while not rospy.is_shutdown() and not self._stopped:
                due = self._requests.due(self.finished_step)
                if due:
                    return due
                if self._ticks:
                    return self._ticks.popleft()
                self._cond.wait(1.0)
                now = time.monotonic()
                if now - reported >= _REPORT_EVERY_S and self._joined:
                    reported = now
                    rospy.logdebug(
                        f"{self.node}: lockstep: no tick after step {self.finished_step} for "
                        f"{now - waited_since:.0f} s (the master waits for another participant)"
                    )
        return None

    def _serve(self, requests: Iterable[_Request]) -> None:
        for item in requests:
            try:
                item.response = item.handler(item.request)
            except Exception as err:  # the caller gets the error (rospy turns it into a ServiceException)
                item.error = err
            item.done.set()

    def _run_step(self, tick: Tick) -> None:
        expected = self.finished_step + 1
        if tick.step != expected:
            self._fail(f"tick of step {tick.step} after step {self.finished_step}: ticks must come in order")
        self.processing_step = tick.step
        self._set_clock(tick.t_s)
        for hook in self._before_hooks:
            hook(tick.step, tick.t_s)
        batch = self._wait_inputs(tick)
        for topic, msg in batch:
            for callback in self._callbacks.get(topic, ()):
                callback(msg)
        for t, callback in self._timers:
            if t.due(tick.t_s):
                callback(tick.t_s)
        for hook in self._step_hooks:
            hook(tick.step, tick.t_s)
        for hook in self._after_hooks:
            hook(tick.step, tick.t_s)
        self._report_done(tick.step, "")
        with self._cond:
            self.finished_step = tick.step
            self.processing_step = None

    def _wait_inputs(self, tick: Tick) -> list[tuple[str, Any]]:
        import rospy  # noqa: PLC0415

        started = reported = time.monotonic()
        with self._cond:
            while True:
                try:
                    missing = self._ledger.missing(tick)
                    if not missing:
                        return self._ledger.take(tick)
                except LockstepError as err:
                    self._fail(f"step {tick.step}: {err}")
                self._cond.wait(0.5)
                if rospy.is_shutdown():
                    text = "shutting down"
                    raise rospy.ROSInterruptException(text)
                now = time.monotonic()
                if now - started > self.settings.watchdog_s:
                    self._fail(f"step {tick.step}: inputs never arrived: {_describe(missing)}")
                if now - reported >= _REPORT_EVERY_S:
                    reported = now
                    rospy.logwarn(
                        f"{self.node}: lockstep: step {tick.step} still waits after {now - started:.0f} s for "
                        f"{_describe(missing)}"
                    )

    def _report_done(self, step: int, error: str) -> None:
        from uav_msgs.msg import LockstepDone  # noqa: PLC0415

        with self._count_lock:
            published = dict(self._counts)
        self._done_pub.publish(
            LockstepDone(node=self.node, step=step, published=_count_msgs(self.node, published), error=error)
        )

    def _fail(self, text: str) -> None:
        """Report the error to the master (which stops the run) and stop this node."""
        step = self.processing_step if self.processing_step is not None else self.finished_step + 1
        with contextlib.suppress(Exception):  # the error below is the report; the publish is best effort
            self._report_done(step, text)
        msg = f"{self.node}: {text}"
        raise LockstepError(msg)

    def stop(self) -> None:
        with self._cond:
            self._stopped = True
            self._cond.notify_all()

    def _on_shutdown(self) -> None:
        self.stop()

    # ------------------------------------------------------------------ rospy plumbing
    def _on_tick(self, msg: Any) -> None:
        counts = {(c.topic, c.publisher): int(c.count) for c in msg.counts}
        tick = Tick(int(msg.step), msg.header.stamp.to_sec(), counts, frozenset(msg.participants))
        with self._cond:
            if self.step_s == 0.0:
                self.step_s = float(msg.step_s)
            if tick.step >= self._first_step:
                self._ticks.append(tick)
            self._cond.notify_all()

    @staticmethod
    def _take_over_clock() -> None:
        """From now on the node's ROS time is the step's (rospy's ``/clock`` subscription is dropped)."""
        from rospy.impl import simtime  # noqa: PLC0415

        sub = getattr(simtime, "_clock_sub", None)
        if sub is not None:
            sub.unregister()
            simtime._clock_sub = None

    def _set_clock(self, t_s: float) -> None:
        import rospy  # noqa: PLC0415

        self.t_s = t_s
        rospy.rostime._set_rostime(rospy.Time.from_sec(t_s))


def _describe(missing: list[Missing]) -> str:
    parts = [f"{m.topic} from {m.publisher} ({m.received} of {m.expected})" for m in missing[:6]]
    more = f" and {len(missing) - 6} more" if len(missing) > 6 else ""
    return ", ".join(parts) + more


def _count_msgs(node: str, published: Mapping[str, int]) -> list[Any]:
    from uav_msgs.msg import LockstepCount  # noqa: PLC0415

    return [LockstepCount(topic=t, publisher=node, count=n) for t, n in sorted(published.items())]


def _tick_class() -> Any:
    from uav_msgs.msg import LockstepTick  # noqa: PLC0415

    return LockstepTick


def _done_class() -> Any:
    from uav_msgs.msg import LockstepDone  # noqa: PLC0415

    return LockstepDone


class StepMaster(_Counter):
    """The step master's ROS side (the sim bridge uses it): joins, dones, ticks, the start and the watchdog.

    The master's own loop decides when to simulate; it asks :meth:`can_grant` before granting step
    ``step + 1``, publishes that step's outputs through :meth:`publisher` (counted), then :meth:`publish_tick`.
    Done reports wake :attr:`wake_fd` (readable), so a loop that waits on sockets with ``select`` learns of
    them at once.

    Args:
        step_s: simulated seconds per step (informative, in every tick).
        expected: the participants the run starts with (``/lockstep/participants``).
    """

    def __init__(self, *, step_s: float, expected: Iterable[str], ns: str = DEFAULT_NS) -> None:
        import socket  # noqa: PLC0415

        import rospy  # noqa: PLC0415

        from uav_msgs.msg import LockstepDone, LockstepTick  # noqa: PLC0415
        from uav_msgs.srv import LockstepJoin  # noqa: PLC0415

        self.node = rospy.get_name()
        self.ns = ns
        self.step_s = float(step_s)
        self.expected = sorted({rospy.resolve_name(n) for n in expected})
        observers = rospy.get_param(f"{ns}/observers", []) or []
        if not isinstance(observers, list):
            msg = f"{ns}/observers must be a list of node names, got {observers!r}"
            raise LockstepError(msg)
        #: Nodes outside the barrier (a recorder) whose subscriptions must be connected before the first step.
        self.observers = sorted({rospy.resolve_name(str(n)) for n in observers})
        settings = read_settings(self.node, 1, ns)
        self.watchdog_s = settings.watchdog_s
        self.barrier = StepBarrier(self.node)
        self._lock = threading.Lock()
        self._counts: dict[str, int] = {}
        self._errors: list[str] = []
        self._progress_wall = time.monotonic()
        self._reported_wall = self._progress_wall
        self._wake_r, self._wake_w = socket.socketpair()
        self._wake_r.setblocking(False)
        self._wake_w.setblocking(False)
        self._tick_pub = rospy.Publisher(f"{ns}/tick", LockstepTick, queue_size=0, tcp_nodelay=True)
        self._done_sub = rospy.Subscriber(f"{ns}/done", LockstepDone, self._on_done, queue_size=None, tcp_nodelay=True)
        self._join_srv = rospy.Service(f"{ns}/join", LockstepJoin, self._on_join)
        self._graph_checked = 0.0
        self.dones = 0

    # ------------------------------------------------------------------ outputs
    def publisher(self, topic: str, msg_class: Any, *, latch: bool = False) -> CountingPublisher:
        import rospy  # noqa: PLC0415

        counted = CountingPublisher(self, topic, rospy.Publisher(topic, msg_class, queue_size=0, latch=latch))
        with self._lock:
            self._counts.setdefault(counted.name, 0)
        return counted

    def count(self, topic: str) -> None:
        with self._lock:
            self._counts[topic] = self._counts.get(topic, 0) + 1

    def tf_broadcaster(self, *, static: bool = False) -> TfBroadcaster:
        from tf2_msgs.msg import TFMessage  # noqa: PLC0415

        topic = "/tf_static" if static else "/tf"
        return TfBroadcaster(self.publisher(topic, TFMessage, latch=static), static=static)

    # ------------------------------------------------------------------ protocol
    @property
    def step(self) -> int:
        return self.barrier.step

    @property
    def started(self) -> bool:
        return self.barrier.started

    @property
    def wake_fd(self) -> int:
        return self._wake_r.fileno()

    def drain_wake(self) -> None:
        try:
            while self._wake_r.recv(4096):
                pass
        except (BlockingIOError, InterruptedError, OSError):
            return

    def _wake(self) -> None:
        try:
            self._wake_w.send(b"\0")
        except (BlockingIOError, InterruptedError, OSError):  # full: the loop is awake anyway
            return

    def _on_join(self, req: Any) -> Any:
        import rospy  # noqa: PLC0415

        from uav_msgs.srv import LockstepJoinResponse  # noqa: PLC0415

        manifest = Manifest(
            str(req.node),
            max(1, int(req.lookahead_steps)),
            tuple(req.inputs),
            tuple(req.outputs),
            tuple(req.timers),
        )
        published = {c.topic: int(c.count) for c in req.published}
        with self._lock:
            try:
                self.barrier.join(manifest, published)
            except LockstepError as err:
                rospy.logerr(f"lockstep: {err}")
                return LockstepJoinResponse(accepted=False, message=str(err), first_step=0, step_s=self.step_s)
        rospy.loginfo(
            f"lockstep: {manifest.node} joined (lookahead {manifest.lookahead_steps}; inputs {list(manifest.inputs)}; "
            f"timers {list(manifest.timers)})"
        )
        self._wake()
        return LockstepJoinResponse(accepted=True, message="", first_step=1, step_s=self.step_s)

    def _on_done(self, msg: Any) -> None:
        published = {c.topic: int(c.count) for c in msg.published}
        with self._lock:
            self.dones += 1
            if msg.error:
                self._errors.append(f"{msg.node} at step {msg.step}: {msg.error}")
            else:
                try:
                    self.barrier.done(str(msg.node), int(msg.step), published)
                except LockstepError as err:
                    self._errors.append(str(err))
            self._progress_wall = time.monotonic()
        self._wake()

    def try_start(self) -> bool:
        """Start once every expected participant has joined and every lockstep input of theirs is connected to
        every counted publisher of its topic (checked at most twice a second). Logs what it waits for."""
        import rosgraph  # noqa: PLC0415
        import rospy  # noqa: PLC0415

        from uav_common.ros.graph import (  # noqa: PLC0415
            bus_info_over_xmlrpc,
            node_uri_lookup,
            unconnected_subscriptions,
        )

        if self.barrier.started:
            return True
        now = time.monotonic()
        if now - self._graph_checked < 0.5:
            return False
        self._graph_checked = now
        with self._lock:
            missing = self.barrier.missing(self.expected)
            names = self.barrier.participants
            inputs = {t for n in names for t in self.barrier.manifest(n).inputs}
        pending: list[str] = [f"{n} has not joined" for n in missing]
        if not pending:
            master = rosgraph.Master(self.node)
            try:
                pubs, subs, _ = master.getSystemState()
                uri = node_uri_lookup(master.lookupNode)
                info = bus_info_over_xmlrpc(self.node, uri)
                counted = {*names, self.node}
                pending = unconnected_subscriptions(
                    pubs, subs, subscriber_nodes=set(names), publisher_nodes=counted, topics=inputs,
                    bus_info=info, node_uri=uri,
                )  # fmt: skip
                registered = {n for _, nodes in subs for n in nodes}
                pending += [f"observer {n} is not up" for n in self.observers if n not in registered]
                pending += unconnected_subscriptions(
                    pubs, subs, subscriber_nodes=set(self.observers), publisher_nodes=counted, bus_info=info,
                    node_uri=uri,
                )  # fmt: skip
            except (rosgraph.MasterError, OSError) as err:
                pending = [f"the ROS master: {err}"]
        if pending:
            if now - self._reported_wall >= _REPORT_EVERY_S:
                self._reported_wall = now
                rospy.loginfo(f"lockstep: waiting to start: {'; '.join(pending[:6])}")
            return False
        with self._lock:
            self.barrier.start()
            self._progress_wall = time.monotonic()
        rospy.loginfo(f"lockstep: starting with {len(names)} participants: {', '.join(names)}")
        return True

    def can_grant(self) -> bool:
        """May step ``step + 1`` be simulated now?

        Raises:
            LockstepError: a participant reported an error or a protocol violation (the run must stop).
        """
        with self._lock:
            if self._errors:
                raise LockstepError("; ".join(self._errors))
            return self.barrier.can_grant()

    def check_watchdog(self) -> None:
        """Report who the master has waited for; past ``/lockstep/watchdog_s`` of no progress, fail.

        Raises:
            LockstepError: no participant made progress for ``watchdog_s`` wall seconds (a deadlock or a
                participant that died), naming whom the master waits for.
        """
        import rospy  # noqa: PLC0415

        now = time.monotonic()
        with self._lock:
            if not self.barrier.started:
                return
            idle = now - self._progress_wall
            waiting = self.barrier.waiting()
        if not waiting:
            return
        held = ", ".join(f"{w.node} (needs step {w.needs_step}, done {w.done_step})" for w in waiting)
        if idle > self.watchdog_s:
            msg = f"no progress for {idle:.0f} s waiting for step {self.step + 1}: {held}"
            raise LockstepError(msg)
        if idle >= _REPORT_EVERY_S and now - self._reported_wall >= _REPORT_EVERY_S:
            self._reported_wall = now
            rospy.logwarn(f"lockstep: step {self.step + 1} has waited {idle:.0f} s for {held}")

    def publish_tick(self, t_s: float) -> None:
        """Step ``step + 1``'s outputs are published: tell the participants."""
        import rospy  # noqa: PLC0415
        from std_msgs.msg import Header  # noqa: PLC0415

        from uav_msgs.msg import LockstepCount, LockstepTick  # noqa: PLC0415

        with self._lock:
            tick = self.barrier.tick(t_s, dict(self._counts))
            self._progress_wall = time.monotonic()
        msg = LockstepTick(
            header=Header(stamp=rospy.Time.from_sec(t_s)),
            step=tick.step,
            step_s=self.step_s,
            counts=[LockstepCount(topic=t, publisher=p, count=n) for (t, p), n in sorted(tick.counts.items())],
            participants=sorted(tick.participants),
        )
        self._tick_pub.publish(msg)
