"""The trainer of a run configuration: the algorithm's agent (its :class:`train.config.AlgoSpec`) in its training
loop, traced at the configuration's matrix-product precision."""

from __future__ import annotations

from jaxsmarl.layout import layout
from train.config import COMMON, spec
from train.offpolicy import make_offpolicy_train
from train.onpolicy import make_onpolicy_train
from train.trainer import Trainer, config_env, with_matmul_precision

__all__ = ["LOOPS", "make_train"]

# AlgoSpec.loop -> the function building that loop's trainer from (config, env, agent)
LOOPS = {"offpolicy": make_offpolicy_train, "onpolicy": make_onpolicy_train}


def make_train(config: dict, env=None) -> Trainer:
    """The trainer of ``config["algo"]``, its programs traced at ``config["matmul_precision"]`` (full float32
    matrix products by default on every backend). ``env``: optional ``(env, wrapped_env, params)``."""
    algo = spec(config["algo"])
    env = config_env(config) if env is None else env
    trainer = LOOPS[algo.loop](config, env, algo.make_agent(config, env[0]))
    if algo.seeds_in_sequence_on_cpu:  # the column layout (XLA:CPU) runs a device's seeds one after another
        trainer = trainer._replace(seeds_in_sequence=layout() == "columns")
    return with_matmul_precision(trainer, config.get("matmul_precision", COMMON["matmul_precision"]))
