"""Learned residuals and gain schedules on the thesis's hybrid law, as
drake_contact controllers: the ``policy`` controller
(drake_contact.control.policy) with trained weights (NumpyPolicy files, no
torch) and the hybrid law of the benchmark's ``hybrid_pi`` contender (K_fp
1, K_fi 0.003, joint 2's drive calibrated), acting every 10 ms: the same
law, observation and action the Gymnasium environment trained them on.

- ``learned_residual``: ``policy.json``, CMA-ES on single environments
  (the first trained policy, kept as it ranked).
- ``learned_ppo_s<k>`` and ``learned_cmaes_s<k>``, k = 0, 1, 2:
  ``policies/<method>_seed<k>.json``, trained on the vector environment
  with the same budget of environment steps by ``train_ppo.py``
  (Stable-Baselines3's PPO, exported to numpy) and ``train.py`` (CMA-ES),
  training seed k; each method's spread over its three seeds is the
  benchmark's spread over these contenders.

Each declares ``ensemble``: the benchmark's packs of runs serve N
environments with one law, one observation and one policy runner."""
from pathlib import Path

from drake_contact.app.benchmark import contender_scenario
from drake_contact.control.hybrid_controller import HybridControllerConfig
from drake_contact.control.policy import NumpyPolicy, PolicyConfig, PolicyController
from drake_contact.errors import ScenarioError
from drake_contact.options import config_from_options
from drake_contact.plugins import declare

HERE = Path(__file__).resolve().parent
#: The first trained weights, and how they were trained (their "about").
WEIGHTS = HERE / "policy.json"
#: The policies trained on the vector environment, by contender name.
POLICIES = {f"learned_{method}_s{seed}": HERE / "policies" / f"{method}_seed{seed}.json"
            for method in ("ppo", "cmaes") for seed in range(3)}
#: The policy's control period (ms), as trained.
PERIOD_MS = 10
_SIGNALS = {
    "policy_observation": "the policy's observation (drake_contact.control.policy_spaces)",
    "policy_action": "the policy's action [force_residual, force_gain_scale, "
                     "integral_gain_scale, damping_x]"}


def hybrid_config() -> HybridControllerConfig:
    """The benchmark's hybrid_pi law, as the Gymnasium environment drives it
    (drake_contact.app.gym_env.BASE_CONTENDER)."""
    section = contender_scenario("hybrid_pi")["controller"]["hybrid"]
    return config_from_options(HybridControllerConfig, section, "controller.hybrid")


def _controller(name: str, weights: Path):
    """The factory of contender ``name``: the policy controller with
    ``weights``, for one environment (options: a mapping) or N (a list)."""
    @declare(signals=_SIGNALS, unlogged=("tip_jacobian",), ensemble=True,
             structure=lambda options: {})
    def make(options):
        """Takes no options: the trained weights are the controller."""
        rows = options if isinstance(options, list) else [options]
        for row in rows:
            if row:
                raise ScenarioError(f"controller.options: {name} takes none, got "
                                    f"{', '.join(row)}")
        policy = NumpyPolicy.load(weights)
        if not isinstance(options, list):
            return PolicyController(hybrid_config(), PolicyConfig(period_ms=PERIOD_MS),
                                    policy=policy)
        count = len(options)
        return PolicyController([hybrid_config()] * count, PolicyConfig(period_ms=PERIOD_MS),
                                policy=[policy] * count)
    make.__name__ = make.__qualname__ = f"make_{name}"
    return make


make_controller = _controller("learned_residual", WEIGHTS)
make_ppo_s0, make_ppo_s1, make_ppo_s2 = (
    _controller(f"learned_ppo_s{k}", POLICIES[f"learned_ppo_s{k}"]) for k in range(3))
make_cmaes_s0, make_cmaes_s1, make_cmaes_s2 = (
    _controller(f"learned_cmaes_s{k}", POLICIES[f"learned_cmaes_s{k}"]) for k in range(3))
