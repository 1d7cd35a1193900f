"""rsl_rl's PPO (rsl-rl-lib 5.x) as a second PPO arm on the shared gym: ``train-rsl-rl`` (docs/rsl-rl.md).

- :mod:`ppo.rslrl.config`: the config, rsl_rl's runner dict with each setting that differs from its defaults marked;
- :mod:`ppo.rslrl.env`: the gym as rsl_rl's ``VecEnv`` (our PPO's observation, rewards, termination, RSI, adaptive
  clip weights and PD targets);
- :mod:`ppo.rslrl.learner`: rsl_rl's ``OnPolicyRunner`` and ``PPO`` as the shared trainer's learner;
- :mod:`ppo.rslrl.export`: the evaluation policy and its ONNX graph, for the report, ``watch-policy`` and
  ``export-policy``;
- :mod:`ppo.rslrl.train`: the command.

rsl-rl-lib is an optional extra (``pip install -e ".[rsl_rl]"``): this package and its config and command modules
import without it; :mod:`ppo.rslrl.env`, :mod:`ppo.rslrl.learner` and the policy loaders need it.
"""

from __future__ import annotations

INSTALL_HINT = 'rsl_rl\'s PPO needs rsl-rl-lib: pip install -e ".[rsl_rl]"'


def require_rsl_rl() -> None:
    """Raises ModuleNotFoundError with :data:`INSTALL_HINT` (one line) unless rsl-rl-lib and its tensordict import."""
    try:
        import rsl_rl  # noqa: F401
        import tensordict  # noqa: F401
    except ModuleNotFoundError:
        raise ModuleNotFoundError(INSTALL_HINT, name="rsl_rl") from None
