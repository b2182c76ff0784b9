"""LeanExecutor (hand_capture/nodes/executor.py), the executor of every node (``run_node``'s
default): everything rclpy's SingleThreadedExecutor does for them --
timers (with and without TimerInfo, under sim time, created and destroyed in callbacks),
subscriptions (message, MessageInfo, raw), services and clients, guard conditions, QoS events,
coroutine callbacks, futures and timeouts, lifecycle transitions. (Its CPU per wake-up against
rclpy's: ``hand-suite bench executor``.) No ``from __future__ import annotations`` here: rclpy,
and LeanExecutor like it, recognise a TimerInfo parameter by its annotation object."""

import time

import pytest
from rcl_interfaces.msg import Parameter as ParameterMsg
from rcl_interfaces.srv import GetParameters, SetParameters
from rclpy.parameter import Parameter
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rclpy.task import Future
from rclpy.timer import TimerInfo
from rosgraph_msgs.msg import Clock
from std_msgs.msg import String

from hand_capture.nodes.executor import LeanExecutor


@pytest.fixture()
def lean():
    """``(make_node, executor)``: nodes on one LeanExecutor, destroyed at teardown."""
    import rclpy

    rclpy.init()
    ex = LeanExecutor()
    nodes = []

    def make_node(name: str, **kw):
        node = rclpy.create_node(name, **kw)
        nodes.append(node)
        ex.add_node(node)
        return node

    try:
        yield make_node, ex
    finally:
        ex.shutdown()
        for n in nodes:
            n.destroy_node()
        rclpy.try_shutdown()


def spin_for(ex: LeanExecutor, cond, timeout: float) -> bool:
    deadline = time.monotonic() + timeout
    while not cond() and time.monotonic() < deadline:
        ex.spin_once(timeout_sec=0.02)
    return cond()


def test_timers_subscriptions_and_message_info(lean) -> None:
    make_node, ex = lean
    node = make_node("lean_a")
    got, infos, raw = [], [], []
    node.create_subscription(String, "t", lambda m: got.append(m.data), 10)
    node.create_subscription(String, "t", lambda m, i: infos.append(i), 10)
    node.create_subscription(String, "t", lambda m: raw.append(m), 10, raw=True)
    pub = node.create_publisher(String, "t", 10)
    ticks, with_info = [], []
    node.create_timer(0.01, lambda: (ticks.append(1), pub.publish(String(data=str(len(ticks))))))

    def timed(info: TimerInfo) -> None:
        with_info.append(info)

    node.create_timer(0.02, timed)
    assert spin_for(ex, lambda: len(got) >= 20 and len(with_info) >= 5, 10.0)
    assert got == sorted(got, key=int)  # in order
    assert infos[0]["received_timestamp"] > 0  # a MessageInfo
    assert isinstance(raw[0], bytes) and len(raw) >= 20
    assert isinstance(with_info[0], TimerInfo)


def test_entities_created_and_destroyed_in_callbacks(lean) -> None:
    make_node, ex = lean
    node = make_node("lean_b")
    fired, late = [], []

    def once() -> None:
        fired.append(1)
        node.destroy_timer(timer)  # a timer that destroys itself
        node.create_subscription(String, "late", lambda m: late.append(m.data), 10)

    timer = node.create_timer(0.01, once)
    pub = node.create_publisher(String, "late", 10)
    assert spin_for(ex, lambda: fired, 5.0)
    assert spin_for(ex, lambda: (pub.publish(String(data="x")), late)[1], 5.0)
    time.sleep(0.05)
    ex.spin_once(timeout_sec=0.05)
    assert fired == [1]  # destroyed: never again


def test_services_clients_and_parameters(lean) -> None:
    make_node, ex = lean
    server = make_node("lean_server")
    server.declare_parameter("gain", 1.5)
    client_node = make_node("lean_client")
    get = client_node.create_client(GetParameters, "/lean_server/get_parameters")
    set_ = client_node.create_client(SetParameters, "/lean_server/set_parameters")
    assert spin_for(ex, lambda: get.service_is_ready() and set_.service_is_ready(), 10.0)
    fut = get.call_async(GetParameters.Request(names=["gain"]))
    ex.spin_until_future_complete(fut, timeout_sec=10.0)
    assert fut.done() and fut.result().values[0].double_value == 1.5
    p = ParameterMsg(name="gain", value=Parameter("gain", value=2.5).get_parameter_value())
    fut = set_.call_async(SetParameters.Request(parameters=[p]))
    ex.spin_until_future_complete(fut, timeout_sec=10.0)
    assert fut.result().results[0].successful
    assert server.get_parameter("gain").value == 2.5


def test_guard_conditions_coroutines_futures_and_timeouts(lean) -> None:
    make_node, ex = lean
    node = make_node("lean_c")
    hits = []
    gc = node.create_guard_condition(lambda: hits.append("gc"))
    gc.trigger()
    assert spin_for(ex, lambda: "gc" in hits, 5.0)
    inner: Future = Future()

    async def coro() -> None:  # an async timer callback awaiting a future
        hits.append("start")
        await inner
        hits.append("end")

    t = node.create_timer(0.01, coro)
    assert spin_for(ex, lambda: "start" in hits, 5.0)
    node.destroy_timer(t)
    inner.set_result(1)
    assert spin_for(ex, lambda: "end" in hits, 5.0)
    never = Future()
    t0 = time.monotonic()
    ex.spin_until_future_complete(never, timeout_sec=0.2)
    assert 0.15 < time.monotonic() - t0 < 2.0 and not never.done()
    done = Future()
    node.create_timer(0.05, lambda: done.done() or done.set_result(7))
    ex.spin_until_future_complete(done, timeout_sec=5.0)
    assert done.result() == 7


def test_qos_events_reach_their_callbacks(lean) -> None:
    from rclpy.event_handler import SubscriptionEventCallbacks

    make_node, ex = lean
    node = make_node("lean_d")
    events = []
    node.create_subscription(
        String, "qos", lambda m: None,
        QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE),
        event_callbacks=SubscriptionEventCallbacks(incompatible_qos=events.append))
    node.create_publisher(String, "qos",
                          QoSProfile(depth=10, reliability=ReliabilityPolicy.BEST_EFFORT))
    assert spin_for(ex, lambda: events, 10.0)


def test_timers_follow_sim_time(lean) -> None:
    make_node, ex = lean
    node = make_node("lean_e", parameter_overrides=[Parameter("use_sim_time", value=True)])
    clock_node = make_node("lean_clock")
    pub = clock_node.create_publisher(Clock, "/clock", 10)
    ticks = []
    node.create_timer(1.0, lambda: ticks.append(node.get_clock().now().nanoseconds))
    sim = [0]

    def advance() -> bool:  # 0.1 s of sim time per call
        sim[0] += 100_000_000
        msg = Clock()
        msg.clock.sec, msg.clock.nanosec = divmod(sim[0], 1_000_000_000)
        pub.publish(msg)
        return len(ticks) >= 3

    assert spin_for(ex, advance, 20.0)
    assert all(t % 1_000_000_000 < 200_000_000 for t in ticks[1:])  # on sim-time seconds


def test_lifecycle_transitions_through_services(lean) -> None:
    from lifecycle_msgs.msg import Transition
    from lifecycle_msgs.srv import ChangeState
    from rclpy.lifecycle import LifecycleNode

    make_node, ex = lean
    lc = LifecycleNode("lean_lc")
    ex.add_node(lc)
    try:
        client_node = make_node("lean_lc_client")
        cli = client_node.create_client(ChangeState, "/lean_lc/change_state")
        assert spin_for(ex, cli.service_is_ready, 10.0)
        for tid in (Transition.TRANSITION_CONFIGURE, Transition.TRANSITION_ACTIVATE):
            fut = cli.call_async(ChangeState.Request(transition=Transition(id=tid)))
            ex.spin_until_future_complete(fut, timeout_sec=10.0)
            assert fut.result().success
        assert lc._state_machine.current_state[1] == "active"
    finally:
        ex.remove_node(lc)
        lc.destroy_node()


def test_a_node_can_ask_for_batched_wake_ups(lean) -> None:
    """A node's ``min_wake_interval`` (the recorder's batch_period): messages that arrive
    meanwhile are all taken at the next wake-up, none is lost."""
    make_node, ex = lean
    node = make_node("lean_batch")
    node.min_wake_interval = 0.0  # added before the attribute is set: no batching yet
    assert ex.min_wake_interval == 0.0
    got, wakes = [], []
    node.create_subscription(String, "batch", lambda m: (got.append(m.data),
                                                         wakes.append(time.monotonic())), 100)
    batched = make_node("lean_batch_2")
    batched.min_wake_interval = 0.25
    ex.add_node(batched)  # re-adding reads the attribute (rclpy ignores the duplicate)
    assert ex.min_wake_interval == 0.25
    pub = batched.create_publisher(String, "batch", 100)
    assert spin_for(ex, lambda: pub.get_subscription_count() == 1, 5.0)
    ex.spin_once(timeout_sec=0.0)  # a wake-up now: the next one is 0.25 s later
    t0 = time.monotonic()
    for i in range(10):
        pub.publish(String(data=str(i)))
    assert spin_for(ex, lambda: len(got) == 10, 5.0)
    assert got == [str(i) for i in range(10)]
    assert wakes[0] - t0 >= 0.2  # taken together after the interval, not one by one
    assert wakes[-1] - wakes[0] < 0.1
