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

from uav_common.errors import StopRequestedError
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


def _sync_publisher(topic: str, msg_class: Any, *, latch: bool = False) -> Any:
    """A publisher that writes in the caller's thread (rospy's ``queue_size=None``): lossless, in order, and for
    the protocol's small messages cheaper than a writer thread per connection. rospy warns about a missing
    ``queue_size`` there; here it is the point."""
    import warnings  # noqa: PLC0415

    import rospy  # noqa: PLC0415

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SyntaxWarning)
        return rospy.Publisher(topic, msg_class, queue_size=None, latch=latch, tcp_nodelay=True)


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
    if isinstance(value, bool) or not isinstance(value, int) or value < (0 if default_lookahead == 0 else 1):
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
        lookahead_steps: the node's default lookahead (``/lockstep/lookahead_steps`` overrides it); 0: a static
            participant, which publishes only before the first step (e.g. static transforms), joins and then only
            spins: nobody waits for it and it gets no ticks.
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
        #: Wall seconds this node spent per input topic, timer and in its step hooks (the log at the end).
        self.spent_s: dict[str, float] = {}
        self._calls: Any = None  # the threads of call_later
        self.t_s = 0.0
        self.step_s = 0.0
        self._first_step = 1
        self._joined = False
        self._stopped = False
        self.static = self.settings.lookahead_steps == 0
        self._keys: tuple[tuple[str, str], ...] = ()
        self._counted = ""
        self._participants: frozenset[str] = frozenset()
        self._participants_text = ""
        if self.causal and not self.static:
            self._take_over_clock()
            self._tick_sub = rospy.Subscriber(
                f"{ns}/tick", _tick_class(), self._on_tick, queue_size=None, tcp_nodelay=True
            )
            self._done_pub = _sync_publisher(f"{ns}/done", _done_class())
        if self.causal:
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

    def call_later(self, name: str, srv_class: Any, request: Any, *, wait_s: float = 2.0) -> tuple[int, Any]:
        """Causal lockstep: start a service call that the server applies at the boundary after step
        ``processing_step + L - 1`` (as :meth:`call`), without waiting for it in this step; returns
        ``(due_step, future)``: the answer is the caller's to take at step ``due_step`` (``processing_step + L``)
        with ``future.result()``. By then the server has applied it (the master cannot grant that step before),
        so taking it there is the same in every run, and the caller does not stand still meanwhile: a
        participant with a long lookahead would otherwise wait that many steps for the answer.

        Raises:
            LockstepError: not in the causal lockstep (use :meth:`call`).
        """
        import concurrent.futures  # noqa: PLC0415

        import rospy  # noqa: PLC0415

        if not self.causal:
            msg = "call_later is for the causal lockstep; use call"
            raise LockstepError(msg)
        step = self.processing_step if self.processing_step is not None else self.finished_step
        boundary = step + self.settings.lookahead_steps - 1
        headers = {APPLY_AFTER_HEADER: str(boundary)}

        def run() -> Any:
            rospy.wait_for_service(name, timeout=wait_s)
            return rospy.ServiceProxy(name, srv_class, headers=headers)(request)

        if self._calls is None:
            self._calls = concurrent.futures.ThreadPoolExecutor(max_workers=2, thread_name_prefix="lockstep-call")
        return boundary + 1, self._calls.submit(run)

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

        # priority topics go first, the last declared first: /tf_static, then /tf (as the C++ twin)
        self.subscribe("/tf", TFMessage, dynamic, priority=True, buff_size=2**20)
        self.subscribe("/tf_static", TFMessage, static, priority=True, buff_size=2**20)
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
        if self.static:
            rospy.spin()
            return
        try:
            while not rospy.is_shutdown() and not self._stopped:
                work = self._next_work()
                if work is None:
                    continue
                if isinstance(work, Tick):
                    self._run_step(work)
                else:
                    self._serve(work)
        except (StopRequestedError, rospy.ROSInterruptException):
            if not (rospy.is_shutdown() or self._stopped):
                raise  # not a shutdown: a failure, reported as such

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
        topics = sorted(published)
        req = LockstepJoinRequest(
            node=self.node,
            lookahead_steps=self.settings.lookahead_steps,
            inputs=list(self._inputs),
            outputs=list(self._outputs),
            timers=[t.describe() for t, _ in self._timers],
            topics="\n".join(topics),
            published=[published[t] for t in topics],
        )
        resp = rospy.ServiceProxy(service, LockstepJoin)(req)
        if not resp.accepted:
            msg = f"{self.node}: the step master refused the join: {resp.message}"
            raise LockstepError(msg)
        self._first_step = int(resp.first_step)
        self.finished_step = self._first_step - 1
        self.step_s = float(resp.step_s)
        self._joined = True
        what = "static" if self.static else f"lookahead {self.settings.lookahead_steps} steps"
        rospy.loginfo(
            f"{self.node}: lockstep: joined ({what}, {len(self._inputs)} inputs, {len(self._outputs)} outputs, "
            f"{len(self._timers)} timers)"
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
        t0 = time.perf_counter()
        batch = self._wait_inputs(tick)
        clock = time.perf_counter
        spent = self.spent_s
        t1 = clock()
        spent["(waiting for inputs)"] = spent.get("(waiting for inputs)", 0.0) + t1 - t0
        for topic, msg in batch:
            for callback in self._callbacks.get(topic, ()):
                callback(msg)
            t2 = clock()
            spent[topic] = spent.get(topic, 0.0) + t2 - t1
            t1 = t2
        for t, callback in self._timers:
            if t.due(tick.t_s):
                callback(tick.t_s)
                t2 = clock()
                key = f"(timer {t.name})"
                spent[key] = spent.get(key, 0.0) + t2 - t1
                t1 = t2
        for hook in self._step_hooks:
            hook(tick.step, tick.t_s)
        for hook in self._after_hooks:
            hook(tick.step, tick.t_s)
        spent["(step hooks)"] = spent.get("(step hooks)", 0.0) + clock() - t1
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
            topics = sorted(self._counts)
            counts = [self._counts[t] for t in topics]
        self._done_pub.publish(
            LockstepDone(node=self.node, step=step, topics="\n".join(topics), published=counts, error=error)
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
        import rospy  # noqa: PLC0415

        self.stop()
        if self.spent_s:
            top = sorted(self.spent_s.items(), key=lambda kv: -kv[1])[:8]
            rospy.loginfo(
                f"{self.node}: lockstep: {self.finished_step} steps; wall time per input and timer: "
                + ", ".join(f"{k} {v:.2f} s" for k, v in top)
            )

    # ------------------------------------------------------------------ rospy plumbing
    def _on_tick(self, msg: Any) -> None:
        if msg.counted != self._counted:  # changes only when a publisher first publishes on a topic
            self._counted = msg.counted
            self._keys = _parse_keys(msg.counted)
        if msg.participants != self._participants_text:
            self._participants_text = msg.participants
            self._participants = frozenset(msg.participants.split("\n")) if msg.participants else frozenset()
        if len(self._keys) != len(msg.counts):
            self._fail(f"a malformed tick of step {msg.step}: {len(self._keys)} keys, {len(msg.counts)} counts")
        counts = dict(zip(self._keys, msg.counts, strict=True))
        tick = Tick(int(msg.step), msg.header.stamp.to_sec(), counts, self._participants)
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


def _parse_keys(counted: str) -> tuple[tuple[str, str], ...]:
    """A tick's ``counted`` lines ("topic publisher") as keys."""
    out = []
    for line in counted.split("\n") if counted else ():
        topic, _, publisher = line.partition(" ")
        out.append((topic, publisher))
    return tuple(out)


def _parse_counts(topics: str, counts: Iterable[int]) -> dict[str, int]:
    """A done's (or join's) ``topics`` lines and ``published`` counts as a mapping.

    Raises:
        LockstepError: the two do not line up.
    """
    names = topics.split("\n") if topics else []
    values = [int(n) for n in counts]
    if len(names) != len(values):
        msg = f"{len(names)} topics but {len(values)} counts"
        raise LockstepError(msg)
    return dict(zip(names, values, strict=True))


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
        self._tick_pub = _sync_publisher(f"{ns}/tick", LockstepTick)
        self._counted = ""
        self._keys: tuple[tuple[str, str], ...] = ()
        self._done_sub = rospy.Subscriber(f"{ns}/done", LockstepDone, self._on_done, queue_size=None, tcp_nodelay=True)
        self._join_srv = rospy.Service(f"{ns}/join", LockstepJoin, self._on_join)
        self._graph_checked = 0.0
        self.dones = 0
        #: Wall seconds the master waited for each participant: the one whose done made the next step grantable
        #: after the master had asked (the run's bottleneck, in the log at the end).
        self.waited_s: dict[str, float] = {}
        self._asked_wall: float | None = None

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
            str(req.node), int(req.lookahead_steps), tuple(req.inputs), tuple(req.outputs), tuple(req.timers)
        )
        with self._lock:
            try:
                published = _parse_counts(req.topics, req.published)
                self.barrier.join(manifest, published)
            except LockstepError as err:
                rospy.logerr(f"lockstep: {err}")
                return LockstepJoinResponse(accepted=False, message=str(err), first_step=0, step_s=self.step_s)
        what = "static" if manifest.static else f"lookahead {manifest.lookahead_steps}"
        rospy.loginfo(
            f"lockstep: {manifest.node} joined ({what}; inputs {list(manifest.inputs)}; timers {list(manifest.timers)})"
        )
        self._wake()
        return LockstepJoinResponse(accepted=True, message="", first_step=1, step_s=self.step_s)

    def _on_done(self, msg: Any) -> None:
        with self._lock:
            self.dones += 1
            if msg.error:
                self._errors.append(f"{msg.node} at step {msg.step}: {msg.error}")
            else:
                try:
                    self.barrier.done(str(msg.node), int(msg.step), _parse_counts(msg.topics, msg.published))
                except LockstepError as err:
                    self._errors.append(f"{msg.node}: {err}")
            self._progress_wall = time.monotonic()
            if self._asked_wall is not None and self.barrier.can_grant():
                node = str(msg.node)
                self.waited_s[node] = self.waited_s.get(node, 0.0) + self._progress_wall - self._asked_wall
                self._asked_wall = None
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
                # the protocol's own topics: every participant hears the ticks, the master hears every done
                pending += unconnected_subscriptions(
                    pubs, subs, subscriber_nodes=set(names), publisher_nodes={self.node},
                    topics={f"{self.ns}/tick"}, bus_info=info, node_uri=uri,
                )  # fmt: skip
                pending += unconnected_subscriptions(
                    pubs, subs, subscriber_nodes={self.node}, publisher_nodes=set(names),
                    topics={f"{self.ns}/done"}, bus_info=info, node_uri=uri,
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
            ok = self.barrier.can_grant()
            if not ok and self._asked_wall is None and self.barrier.started:
                self._asked_wall = time.monotonic()
            return ok

    def summary(self) -> str:
        """What the master waited for, per participant (wall seconds), for the log at the end of a run."""
        with self._lock:
            waited = sorted(self.waited_s.items(), key=lambda kv: -kv[1])
        total = sum(v for _, v in waited)
        parts = ", ".join(f"{n} {v:.1f} s" for n, v in waited[:8])
        return f"{self.step} steps, {self.dones} done reports; waited {total:.1f} s for participants ({parts})"

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

        from uav_msgs.msg import LockstepTick  # noqa: PLC0415

        with self._lock:
            tick = self.barrier.tick(t_s, dict(self._counts))
            self._progress_wall = time.monotonic()
        keys = tuple(sorted(tick.counts))
        if keys != self._keys:
            self._keys = keys
            self._counted = "\n".join(f"{t} {p}" for t, p in keys)
        msg = LockstepTick(
            header=Header(stamp=rospy.Time.from_sec(t_s)),
            step=tick.step,
            step_s=self.step_s,
            counted=self._counted,
            counts=[tick.counts[k] for k in keys],
            participants="\n".join(sorted(tick.participants)),
        )
        self._tick_pub.publish(msg)
