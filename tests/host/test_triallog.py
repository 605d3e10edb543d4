"""Trial logs survive kill -9; the index is replaced atomically."""

from __future__ import annotations

import json
import random
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from tumblebot.host.triallog import TrialLogWriter, read_trial, write_json_atomic

WRITER = """
import sys, time
from pathlib import Path
from tumblebot.host.triallog import TrialLogWriter
w = TrialLogWriter(Path(sys.argv[1]), {"trial": "0"}, on_written=lambda s: print("@written", s, flush=True))
i = 0
while True:
    i += 1
    w.write("/pose", {"t": time.monotonic(), "p": [i * 1e-3, 0.0, 0.05], "q": [0, 0, 0, 1], "seq": i})
    if i % 10 == 0:
        w.write("/command", {"right": 1, "left": -1, "kind": "policy"})
"""


def test_that_a_finished_log_reads_back_in_order_with_its_metadata(tmp_path: Path) -> None:
    path = tmp_path / "t.mcap"
    with TrialLogWriter(path, {"trial": "3"}) as w:
        for i in range(50):
            w.write("/pose", {"p": [i, 0, 0], "q": [0, 0, 0, 1]})
        w.write("/event", {"event": "end", "detail": ""})
    log = read_trial(path)
    assert log.complete and log.metadata == {"trial": "3"}
    assert [m.data["p"][0] for m in log.topic("/pose")] == list(range(50))
    # each /pose is followed by its Foxglove /tf and /robot/pose: 50 × 3 + 1 messages, numbered in order
    assert [m.sequence for m in log.messages] == list(range(1, 152))
    assert [m.topic for m in log.messages[:3]] == ["/pose", "/tf", "/robot/pose"]


@pytest.mark.slow
def test_that_every_message_whose_write_returned_survives_kill_9(tmp_path: Path) -> None:
    rng = random.Random(20261122)
    for attempt in range(12):
        path = tmp_path / f"k{attempt}.mcap"
        proc = subprocess.Popen([sys.executable, "-c", WRITER, str(path)], stdout=subprocess.PIPE, text=True)
        assert proc.stdout is not None
        first = proc.stdout.readline()  # the writer is up (imports take a while)
        written: list[int] = [int(first.split()[1])]
        deadline = time.monotonic() + 0.05 + rng.random() * 1.0  # then kill it at a random moment
        while time.monotonic() < deadline:
            line = proc.stdout.readline()
            if line.startswith("@written"):
                written.append(int(line.split()[1]))
        proc.send_signal(signal.SIGKILL)
        rest, _ = proc.communicate()
        written += [int(ln.split()[1]) for ln in rest.splitlines() if ln.startswith("@written")]
        log = read_trial(path)
        assert not log.complete
        got = {m.sequence for m in log.messages}
        assert set(written) <= got, f"attempt {attempt}: lost {sorted(set(written) - got)[:5]}"
        assert len(written) > 5


def test_that_the_index_is_replaced_atomically(tmp_path: Path) -> None:
    path = tmp_path / "index.json"
    write_json_atomic(path, {"trials": [1]})
    write_json_atomic(path, {"trials": [1, 2]})
    assert json.loads(path.read_text()) == {"trials": [1, 2]}
    assert [p.name for p in tmp_path.iterdir()] == ["index.json"]  # no temporary left behind
