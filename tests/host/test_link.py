"""The host's end of the UDP link against the real agent, in process (no serial device:
pyserial's loop://)."""

from __future__ import annotations

import time
from collections.abc import Iterator

import pytest

from tumblebot.host.link import AgentClient
from tumblebot.pi_agent.agent import Agent, AgentConfig

KEY = bytes(range(32))


@pytest.fixture
def pair() -> Iterator[tuple[Agent, AgentClient]]:
    agent = Agent(AgentConfig(serial_port="loop://", bind_address="127.0.0.1", bind_port=0,
                              allowed_host="127.0.0.1"), KEY)
    client = AgentClient(agent.address, KEY)
    try:
        yield agent, client
    finally:
        client.close()
        agent.sock.close()


def _until(agent: Agent, client: AgentClient, done: object, timeout: float = 10.0) -> list[dict[str, object]]:
    bodies: list[dict[str, object]] = []
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        agent.step(timeout=0.01)
        bodies += client.poll()
        if callable(done) and done(bodies):
            break
    return bodies


def test_that_telemetry_answering_another_requester_is_ignored(pair: tuple[Agent, AgentClient]) -> None:
    agent, client = pair
    client.hello()
    _until(agent, client, lambda _: client.session is not None)
    assert client.session is not None
    client.request_telemetry()
    mine = _until(agent, client, lambda bodies: bool(bodies))
    assert len(mine) == 1
    own = ("127.0.0.1", client.sock.getsockname()[1])
    agent._send_telemetry(own, nonce=0xC0FFEE, now=time.monotonic())  # authentic, but not an answer to us
    time.sleep(0.2)
    assert client.poll() == [] and client.foreign_telemetry == 1


def test_that_a_host_silent_past_the_agents_timeout_says_hello_again_before_commanding(
        pair: tuple[Agent, AgentClient]) -> None:
    agent, client = pair
    client.hello()
    _until(agent, client, lambda _: client.session is not None)
    first = client.session
    client.request_telemetry()
    _until(agent, client, lambda bodies: bool(bodies))
    _until(agent, client, lambda _: False, timeout=1.2)  # the host says nothing; the agent runs on
    assert agent.sessions_expired == 1 and agent.session != first
    unsent = client.unsent
    client.command(1, 1)  # silent too long: a HELLO goes out instead of the command
    assert client.unsent == unsent + 1
    _until(agent, client, lambda _: client.session is not None)
    assert client.session == agent.session
    client.command(1, 1)
    _until(agent, client, lambda _: agent.pending == (1, 1) or agent.command == (1, 1), timeout=2.0)
    assert (1, 1) in (agent.pending, agent.command)
    client.stop()


def test_that_a_host_whose_control_was_taken_stops_its_trial_saying_why() -> None:
    from tumblebot.host.trial_runner import TrialRunner

    body = {"serial_connected": True, "epoch": 3, "controller": 12345}
    fault = TrialRunner.link_fault(body, 3, sender=777)
    assert fault is not None and fault[0] == "taken_over" and "sender 12345" in fault[1] and "--take-over" in fault[1]
    assert TrialRunner.link_fault({**body, "controller": 777}, 3, sender=777) is None
    assert TrialRunner.link_fault({**body, "controller": None}, 3, sender=777) is None


def test_that_two_host_processes_do_not_share_a_sender_id() -> None:
    clients = [AgentClient(("127.0.0.1", 9), KEY) for _ in range(20)]
    for client in clients:
        client.close()
    ids = {client.sender for client in clients}
    assert len(ids) == 20 and all(i >= 2 for i in ids)
