"""DirectExecutor keeps rclpy.spin's contract for the things CIML's nodes use: subscriptions
in creation order, wall and simulation-time timers, services and clients (parameter sets),
entities created and destroyed from callbacks, async callbacks, and shutdown."""
import time

import pytest

rclpy = pytest.importorskip("rclpy")
from rcl_interfaces.srv import SetParameters  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from rclpy.qos import QoSProfile, ReliabilityPolicy  # noqa: E402
from rosgraph_msgs.msg import Clock  # noqa: E402
from std_msgs.msg import Int32  # noqa: E402

from ciml_learning.ros.executor import DirectExecutor  # noqa: E402

pytestmark = pytest.mark.ros
QOS = QoSProfile(depth=50, reliability=ReliabilityPolicy.RELIABLE)


@pytest.fixture
def ctx():
    context = rclpy.Context()
    rclpy.init(context=context)
    yield context
    rclpy.try_shutdown(context=context)


def spin_until(ex: DirectExecutor, done, timeout: float = 10.0) -> bool:
    end = time.monotonic() + timeout
    while time.monotonic() < end and not done():
        ex.spin_once(timeout_sec=0.05)
    return done()


def test_messages_timers_and_order(ctx):
    pub_node = rclpy.create_node("pub", context=ctx)
    node = rclpy.create_node("sub", context=ctx)
    got: list[tuple[str, int]] = []
    a = pub_node.create_publisher(Int32, "/a", QOS)
    b = pub_node.create_publisher(Int32, "/b", QOS)
    node.create_subscription(Int32, "/a", lambda m: got.append(("a", m.data)), QOS)
    node.create_subscription(Int32, "/b", lambda m: got.append(("b", m.data)), QOS)
    ticks = []
    node.create_timer(0.01, lambda: ticks.append(time.monotonic()))
    ex = DirectExecutor(context=ctx)
    ex.add_node(pub_node)
    ex.add_node(node)
    assert spin_until(ex, lambda: a.get_subscription_count() and b.get_subscription_count())
    for i in range(20):  # /b published first, /a served first: creation order, as rclpy's executor
        b.publish(Int32(data=i))
        a.publish(Int32(data=i))
    time.sleep(0.2)
    got.clear()
    ex.spin_once(timeout_sec=1.0)
    assert got[:2] == [("a", 0), ("b", 0)]
    assert spin_until(ex, lambda: len(got) == 40 and len(ticks) >= 20)
    assert [v for k, v in got if k == "a"] == list(range(20))


def test_simulation_time_timer_follows_clock(ctx):
    node = rclpy.create_node("sim", context=ctx, parameter_overrides=[Parameter("use_sim_time", value=True)])
    clock_node = rclpy.create_node("clock", context=ctx)
    pub = clock_node.create_publisher(Clock, "/clock", 10)
    ticks = []
    node.create_timer(0.1, lambda: ticks.append(node.get_clock().now().nanoseconds))
    ex = DirectExecutor(context=ctx)
    ex.add_node(node)
    ex.add_node(clock_node)
    assert spin_until(ex, lambda: pub.get_subscription_count() > 0)
    spin_until(ex, lambda: False, 0.3)
    assert ticks == []  # simulated time has not started: no tick on the wall clock
    for k in range(1, 31):  # 3 simulated seconds, fast
        msg = Clock()
        msg.clock.sec, msg.clock.nanosec = divmod(k * 100_000_000, 1_000_000_000)
        pub.publish(msg)
        spin_until(ex, lambda: False, 0.01)
    assert spin_until(ex, lambda: len(ticks) >= 20, 5.0), ticks


def test_parameter_service_and_client(ctx):
    node = rclpy.create_node("server", context=ctx)
    node.declare_parameter("rate", 250.0)
    caller = rclpy.create_node("caller", context=ctx)
    client = caller.create_client(SetParameters, "/server/set_parameters")
    ex = DirectExecutor(context=ctx)
    ex.add_node(node)
    ex.add_node(caller)
    assert spin_until(ex, client.service_is_ready)
    future = client.call_async(SetParameters.Request(parameters=[Parameter("rate", value=50.0).to_parameter_msg()]))
    assert spin_until(ex, future.done)
    assert future.result().results[0].successful
    assert node.get_parameter("rate").value == 50.0


def test_entities_changed_from_callbacks_and_async_callbacks(ctx):
    node = rclpy.create_node("changer", context=ctx)
    pub = node.create_publisher(Int32, "/c", QOS)
    seen, later, done_async = [], [], []
    state = {}

    def once(msg):  # destroys its own subscription and creates another one, mid-wake
        seen.append(msg.data)
        node.destroy_subscription(state["sub"])
        node.create_subscription(Int32, "/c", lambda m: later.append(m.data), QOS)

    async def coroutine_callback():
        done_async.append(True)

    state["sub"] = node.create_subscription(Int32, "/c", once, QOS)
    node.create_timer(0.02, coroutine_callback)
    ex = DirectExecutor(context=ctx)
    ex.add_node(node)
    assert spin_until(ex, lambda: pub.get_subscription_count() == 1)
    pub.publish(Int32(data=1))
    assert spin_until(ex, lambda: seen == [1] and pub.get_subscription_count() == 1)
    pub.publish(Int32(data=2))
    assert spin_until(ex, lambda: later == [2] and done_async)
    assert seen == [1]


def test_spin_ends_when_the_context_shuts_down(ctx):
    node = rclpy.create_node("ender", context=ctx)
    node.create_timer(0.01, lambda: rclpy.try_shutdown(context=ctx))
    ex = DirectExecutor(context=ctx)
    ex.add_node(node)
    t0 = time.monotonic()
    with pytest.raises(Exception) as err:  # rclpy's ExternalShutdownException, as rclpy.spin raises it
        while True:
            ex.spin_once(timeout_sec=0.1)
    assert type(err.value).__name__ == "ExternalShutdownException"
    assert time.monotonic() - t0 < 5.0


def test_publish_periods_report_rate_and_jitter(monkeypatch):
    """PublishPeriods (ros_common): after a window of publications, the rate and the p99 of
    |period − nominal| on the node's /diagnostics counters."""
    from collections import Counter
    from types import SimpleNamespace

    from ciml_learning.ros import ros_common

    health = SimpleNamespace(counts=Counter())
    clock = iter([k * 0.004 + (0.003 if k % 50 == 7 else 0.0) for k in range(1000)])  # 2 % of samples 3 ms late
    monkeypatch.setattr(ros_common.time, "monotonic", lambda: next(clock))
    periods = ros_common.PublishPeriods(health, "torque_command", 250.0, window=500)
    for _ in range(400):
        periods.mark()
    assert "torque_command_rate_hz" not in health.counts
    for _ in range(200):
        periods.mark()
    assert abs(health.counts["torque_command_rate_hz"] - 250.0) < 1.0
    assert abs(health.counts["torque_command_jitter_p99_ms"] - 3.0) < 1e-6
