"""DirectExecutor: a single-threaded rclpy executor that runs callbacks directly.

Why: rclpy's SingleThreadedExecutor rebuilds its wait set in Python on every wake — every
subscription, timer, service (six parameter services per node) and QoS event handler of
every node, each entered as a context manager — and wraps every callback in a Task
coroutine. On the live graph that is a large part of a cycle: with the seven control-path and
filter nodes in one process, building wait sets took a third of the profiled time, and the
process's CPU per 250 Hz cycle went from 5.2 ms with rclpy's executor to 3.7 ms with this one
(results/LIVE_GRAPH.md, first session). This executor keeps the same contract
for plain callbacks (rclpy.spin semantics, shutdown on the context, SIGINT wakes it,
entities served per node in creation order: timers, subscriptions, guard conditions,
clients, services, waitables) and does less per wake:

- the lists of entities are collected once and again only after a node created or
  destroyed one (rclpy wakes the executor then: `wake()` marks them stale) or a node was
  added or removed;
- a ready entity's callback is called directly; a coroutine returned by a callback is
  run as an rclpy Task (async callbacks keep working, just not faster);
- QoS event handlers (one per publisher and subscription: incompatible QoS, liveliness,
  matching), about a hundred on the composed graph, join the wait set on every
  EVENT_POLL_PERIOD-th wake only: their events are news for the log, not for the cycle, and
  stay ready until taken.

Callback groups are not consulted: one thread runs every callback in turn, which is what
the mutually exclusive default group asks for. Nodes that need parallel callbacks keep
rclpy's MultiThreadedExecutor.
"""
from __future__ import annotations

import inspect
from typing import Any

from rclpy.context import Context
from rclpy.event_handler import EventHandler
from rclpy.exceptions import InvalidHandle
from rclpy.executors import Executor, ExternalShutdownException, ShutdownException, TimeoutObject
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.node import Node
from rclpy.subscription import Subscription
from rclpy.task import Future
from rclpy.waitable import NumberOfEntities

EVENT_POLL_PERIOD = 25
"""Every EVENT_POLL_PERIOD-th wait includes the QoS event handlers (a 250 Hz node wakes at least 250 times a second)."""


class _Entities:
    """What one wait set holds: every node's entities, in the order they are served."""

    def __init__(self, nodes: list[Node], guards: list) -> None:
        self.per_node: list[tuple[list, list, list, list, list, list]] = []
        self.subscriptions, self.timers, self.clients, self.services = [], [], [], []
        self.guards = list(guards)
        self.waitables = []
        for node in nodes:
            subs, timers = list(node.subscriptions), list(node.timers)
            gcs, clients, services, waitables = (list(node.guards), list(node.clients), list(node.services),
                                                 list(node.waitables))
            self.per_node.append((_keyed(timers), _keyed(subs), _keyed(gcs), _keyed(clients), _keyed(services),
                                  waitables))
            self.subscriptions += subs
            self.timers += timers
            self.clients += clients
            self.services += services
            self.guards += gcs
            self.waitables += waitables
        self.cycle_waitables = [w for w in self.waitables if not isinstance(w, EventHandler)]
        """What joins every wait; the event handlers join every EVENT_POLL_PERIOD-th."""
        events = sum((w.get_num_entities() for w in self.waitables), NumberOfEntities())
        self.size = (len(self.subscriptions) + events.num_subscriptions,
                     len(self.guards) + events.num_guard_conditions,
                     len(self.timers) + events.num_timers,
                     len(self.clients) + events.num_clients,
                     len(self.services) + events.num_services,
                     events.num_events)


class DirectExecutor(Executor):
    """Single-threaded executor: callbacks called directly, wait set rebuilt only on change."""

    def __init__(self, *, context: Context | None = None) -> None:
        super().__init__(context=context)
        self._entities: _Entities | None = None
        self._wait_set: Any = None
        self._wakes = 0

    # --- entity bookkeeping: rclpy wakes the executor whenever a node's entities change --------
    def wake(self) -> None:
        self._entities = None
        super().wake()

    def add_node(self, node: Node) -> bool:
        self._entities = None
        return super().add_node(node)

    def remove_node(self, node: Node) -> None:
        self._entities = None
        super().remove_node(node)

    def _collect(self) -> _Entities:
        if self._entities is None:
            self._entities = _Entities(self.get_nodes(), [self._guard, self._sigint_gc])
            self._wait_set = _rclpy.WaitSet(*self._entities.size, self._context.handle)
        return self._entities

    # --- spinning ------------------------------------------------------------------------------
    def spin_once(self, timeout_sec: float | None = None) -> None:
        if self._is_shutdown:
            raise ShutdownException()
        if not self._context.ok():
            raise ExternalShutdownException()
        self._run_tasks()
        ents = self._collect()
        ws = self._wait_set
        self._wakes += 1
        waitables = ents.waitables if self._wakes % EVENT_POLL_PERIOD == 0 else ents.cycle_waitables
        ws.clear_entities()
        try:
            for s in ents.subscriptions:
                ws.add_subscription(s.handle)
            for c in ents.clients:
                ws.add_client(c.handle)
            for srv in ents.services:
                ws.add_service(srv.handle)
            for t in ents.timers:
                ws.add_timer(t.handle)
            for g in ents.guards:
                ws.add_guard_condition(g.handle)
            for w in waitables:
                w.add_to_wait_set(ws)
        except InvalidHandle:  # destroyed by another thread since the last collection: collect again
            self._entities = None
            return
        timeout_ns = -1 if timeout_sec is None or timeout_sec < 0 else int(timeout_sec * 1e9)
        ws.wait(timeout_ns)
        if self._is_shutdown:
            raise ShutdownException()
        if not self._context.ok():
            raise ExternalShutdownException()
        subs = set(ws.get_ready_entities("subscription"))
        timers = set(ws.get_ready_entities("timer"))
        guards = set(ws.get_ready_entities("guard_condition"))
        clients = set(ws.get_ready_entities("client"))
        services = set(ws.get_ready_entities("service"))
        ready_waitables = [w for w in waitables if w.is_ready(ws)]
        for n_timers, n_subs, n_guards, n_clients, n_services, n_waitables in ents.per_node:
            work = ([(self._timer, t) for p, t in n_timers if p in timers]
                    + [(self._subscription, s) for p, s in n_subs if p in subs]
                    + [(self._guard_condition, g) for p, g in n_guards if p in guards]
                    + [(self._client, c) for p, c in n_clients if p in clients]
                    + [(self._service, s) for p, s in n_services if p in services]
                    + [(self._waitable, w) for w in n_waitables if w in ready_waitables])
            for fn, entity in work:
                self._run(fn, entity)
                if self._entities is None:
                    # a callback created or destroyed an entity: what is still ready stays ready
                    # (data, requests, due timers) and is served after the next collection
                    return

    def spin_once_until_future_complete(self, future: Future,
                                        timeout_sec: float | TimeoutObject | None = None) -> None:
        # rclpy's spin_until_future_complete passes what is left of its timeout as a TimeoutObject
        self.spin_once(timeout_sec.timeout if isinstance(timeout_sec, TimeoutObject) else timeout_sec)

    def _run(self, fn, *args) -> None:
        result = fn(*args)
        if inspect.iscoroutine(result):  # an async callback: rclpy's Task runs it
            self.create_task(result)

    def _run_tasks(self) -> None:
        with self._tasks_lock:
            tasks = [t for t, _, _ in self._tasks]
        for task in tasks:
            if not task.done() and not task.executing():
                task()
        with self._tasks_lock:
            self._tasks = [entry for entry in self._tasks if not entry[0].done()]

    # --- the work of one ready entity (rclpy.executors.Executor._take_* without the Task) -------
    @staticmethod
    def _timer(tmr):
        if tmr.handle.is_timer_ready():  # rcl reports cancelled timers ready (rclpy's workaround too)
            tmr.handle.call_timer()
            return tmr.callback()
        return None

    @staticmethod
    def _guard_condition(gc):
        return gc.callback() if gc.callback is not None else None

    @staticmethod
    def _subscription(sub: Subscription):
        msg_info = sub.handle.take_message(sub.msg_type, sub.raw)
        if msg_info is None:
            return None
        if sub._callback_type is Subscription.CallbackType.MessageOnly:
            return sub.callback(msg_info[0])
        return sub.callback(*msg_info)

    def _client(self, client):
        header, response = client.handle.take_response(client.srv_type.Response)
        if header is None:
            return None
        try:
            future = client.get_pending_request(header.request_id.sequence_number)
        except KeyError:  # the request was cancelled
            return None
        future._set_executor(self)
        future.set_result(response)
        return None

    @staticmethod
    def _service(srv):
        request, header = srv.handle.service_take_request(srv.srv_type.Request)
        if header is None:
            return None
        response = srv.callback(request, srv.srv_type.Response())
        srv.send_response(response, header)
        return None

    def _waitable(self, waitable):
        data = waitable.take_data()
        for future in waitable._futures:
            future._set_executor(self)
        return waitable.execute(data)  # a coroutine: run as a Task


def _keyed(entities: list) -> list[tuple[int, Any]]:
    """(rcl handle address, entity): how the wait set names a ready entity."""
    return [(e.handle.pointer, e) for e in entities]
