"""The policy's feature layer computed in Python ahead of the graph's MLP: the same actions as the whole graph."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from tumblebot.sim.control.features import DESIGN_SCALE, FEATURES, compute
from tumblebot.sim.control.policy import OnnxPolicy, bundled_policy
from tumblebot.sim.observation import LAYOUTS
from tumblebot.sim.world.design import Design
from tumblebot.sim.world.env import TumblerEnv
from tumblebot.sim.world.randomization import Randomization

POLICIES = sorted(Path(bundled_policy("nav-flat")).parent.glob("*.onnx"))


@pytest.mark.parametrize("layout", sorted(LAYOUTS))
def test_that_every_layout_has_its_named_features(layout: str) -> None:
    x = np.random.default_rng(1).normal(size=(5, len(LAYOUTS[layout]))).astype(np.float32)
    out = compute(layout, x)
    assert out.shape == (5, len(FEATURES[layout])) and out.dtype == np.float32 and np.all(np.isfinite(out))


@pytest.mark.parametrize("path", POLICIES, ids=lambda p: p.stem)
def test_that_act_gives_the_whole_graphs_action_at_every_step_of_episodes(path: Path) -> None:
    policy = OnnxPolicy(path)
    assert policy.split, "the bundled policies compute their feature layer themselves"
    task = str(policy.task)
    env = TumblerEnv(task=task, randomization=Randomization(design=True))
    reference = OnnxPolicy(path)  # drives the episodes through the whole graph
    steps = 0
    try:
        for seed in range(6):
            obs, _ = env.reset(seed=seed)
            policy.reset(env.design.as_tuple())
            reference.reset(env.design.as_tuple())
            for _ in range(env.episode_steps):
                x = reference.context(obs)
                whole = reference.act_batch(x[None])[0]
                np.testing.assert_array_equal(policy.act(obs), whole)
                obs, *_ = env.step(whole)
                steps += 1
    finally:
        env.close()
    assert steps >= 6 * 10


def test_that_a_graph_whose_feature_layer_is_not_ours_runs_whole(tmp_path: Path) -> None:
    import hashlib
    import json

    import onnx
    from onnx import helper

    source = bundled_policy("nav-flat", layout="thesis")
    model = onnx.load(str(source))
    # Double the position before the feature layer: the computed features no longer match
    # the graph's, and the load-time check must notice and keep the whole graph.
    first = model.graph.input[0].name
    model.graph.node.insert(0, helper.make_node("Mul", [first, "two"], ["doubled"]))
    model.graph.initializer.append(helper.make_tensor("two", onnx.TensorProto.FLOAT, [1], [2.0]))
    for node in model.graph.node[1:]:
        node.input[:] = ["doubled" if name == first else name for name in node.input]
    path = tmp_path / "other.onnx"
    onnx.save(model, str(path))
    card = json.loads(source.with_suffix(".json").read_text())
    card["onnx_sha256"] = hashlib.sha256(path.read_bytes()).hexdigest()
    path.with_suffix(".json").write_text(json.dumps(card))
    policy = OnnxPolicy(path)
    assert not policy.split
    obs = np.array([0.5, -0.3, 0.1, 0, 0, 0.38, 0.92, 1, 0], dtype=np.float32)
    np.testing.assert_array_equal(policy.act(obs), policy.act_batch(obs[None])[0])


def test_that_the_design_of_an_episode_reaches_the_features() -> None:
    policy = OnnxPolicy(bundled_policy("nav-flat"))
    obs = np.array([0.5, -0.3, 0.1, 0, 0, 0.38, 0.92, 1, 0], dtype=np.float32)
    a = Design(0.292, 0.129, 0.098, 0.136).as_tuple()
    policy.reset(a)
    x = policy.context(obs)
    names = FEATURES[policy.layout]
    at = slice(names.index("design_x"), names.index("design_l") + 1)
    assert np.allclose(compute(policy.layout, x[None])[0, at], np.array(a) / DESIGN_SCALE)
