"""Host latency: from a mocap frame arriving to the command datagram leaving.

Run: ``.venv/bin/python benchmarks/bench_host.py [--decisions 2000]``

A publisher process sends the UDP pose stream at 200 Hz, stamping each datagram with
``time.monotonic()`` as it leaves (same machine, same clock); the real controller, with
the bundled nav-flat ONNX policy, decides on every 4th frame (period 20 ms instead of 1 s,
so thousands of decisions fit in a minute) and sends each command to the real Pi agent
(its own process, as on the Pi; serial on pyserial's ``loop://``). Two latencies per
decision:

* frame sent → command sent: includes the loopback UDP hop and the select() wake-up;
* frame read by the host → command sent: our own code (filter, task frame, ONNX, HMAC).

Side by side in the same run, the bare ONNX inference time of the same observations gives
the share of the latency that is the policy. Target (issue #6): p99 ≤ 2 ms.
"""

from __future__ import annotations

import argparse
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from tumblebot.defaults import XI3_ROBOT
from tumblebot.host.link import AgentClient, free_port, load_host_key, new_key
from tumblebot.host.mocap import open_source
from tumblebot.host.trial_runner import ControllerConfig, TrialRunner
from tumblebot.host.triallog import BackgroundLog, TrialLogWriter
from tumblebot.sim.control.policy import OnnxPolicy, bundled_policy

PUBLISHER = """
import socket, sys, time
from tumblebot.host.mocap import encode_pose_datagram
from tumblebot.sim.world.frames import yaw_quaternion
port, seq = int(sys.argv[1]), 0
with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
    while True:
        seq += 1
        s.sendto(encode_pose_datagram("tumbler", seq, time.monotonic(), (0.8, -0.4, 0.05),
                                      yaw_quaternion(0.3 + 1e-4 * seq)), ("127.0.0.1", port))
        time.sleep(0.005)
"""


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--decisions", type=int, default=2000)
    args = ap.parse_args()
    source = open_source("udp://127.0.0.1:0?body=tumbler")
    port = source.address[1]  # type: ignore[attr-defined]
    with tempfile.TemporaryDirectory() as tmp:
        key = Path(tmp) / "key"
        new_key(key)
        agent_port = free_port()
        config = Path(tmp) / "agent.toml"
        config.write_text(f'serial_port = "loop://"\nbind_address = "127.0.0.1"\nbind_port = {agent_port}\n'
                          f'allowed_host = "127.0.0.1"\nkey_file = "{key}"\n')
        procs = [subprocess.Popen([sys.executable, "-c", PUBLISHER, str(port)]),
                 subprocess.Popen([sys.executable, "-m", "tumblebot.pi_agent.agent", "--config", str(config)],
                                  stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)]
        try:
            policy = OnnxPolicy(bundled_policy("nav-flat"), task="nav-flat")
            policy.bind_design(XI3_ROBOT)  # as trial run --design does
            client = AgentClient(("127.0.0.1", agent_port), load_host_key(key))
            deadline = time.monotonic() + 30
            while not client.poll():  # the agent process is up
                assert time.monotonic() < deadline, "the agent did not start"
                client.request_telemetry()
                time.sleep(0.2)
            controller = TrialRunner(source, client, policy, (0.0, 0.0), 0.0,
                                    ControllerConfig(period=0.02, steps=args.decisions, agent_timeout=5.0,
                                                     first_pose_timeout=20.0))
            results = {}
            for label in ("no log", "MCAP log"):  # side by side: what the crash-safe log costs
                if label == "no log":
                    results[label] = controller.run_trial()
                else:
                    with TrialLogWriter(Path(tmp) / "trial.mcap") as log:
                        background = BackgroundLog(log)  # as tumblebot trial run does
                        results[label] = controller.run_trial(background)
                        background.close()
        finally:
            for proc in procs:
                proc.terminate()
                proc.wait()
    obs = np.array([controller.observation(controller.filter.last)] * 2000)  # type: ignore[arg-type]
    t0 = time.perf_counter()
    for k, o in enumerate(obs):
        if k % 20 == 0:
            policy.reset()  # a trial's worth of decisions, then a new trial
        policy.act(o)
    onnx_ms = (time.perf_counter() - t0) / len(obs) * 1e3
    print(f"{platform.node()} ({platform.machine()}), {args.decisions} decisions per run, {time.strftime('%Y-%m-%d')}")
    p99 = {}
    for label, result in results.items():
        assert result.status == "complete", result.reason
        sent = np.array([(s - src) * 1e3 for _, src, s in result.decision_times if src is not None])
        read = np.array(result.latencies_ms)
        p99[label] = float(np.percentile(sent, 99))
        for name, x in (("frame sent -> command sent", sent), ("frame read -> command sent", read)):
            print(f"{label:8s} {name:28s} p50 {np.percentile(x, 50):.3f} ms   p99 {np.percentile(x, 99):.3f} ms   "
                  f"max {x.max():.3f} ms")
    print(f"ONNX inference alone: mean {onnx_ms:.3f} ms; p99 with the log / without: "
          f"{p99['MCAP log'] / p99['no log']:.2f}")
    print(f"target p99 <= 2 ms (with the log): {'met' if p99['MCAP log'] <= 2.0 else 'NOT met'}")


if __name__ == "__main__":
    main()
