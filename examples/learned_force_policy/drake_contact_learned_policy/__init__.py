"""A learned residual and gain schedule on the thesis's hybrid law, as a
drake_contact controller: the ``policy`` controller
(drake_contact.control.policy) with the weights ``train.py`` found
(``policy.json``, a linear policy through tanh) and the hybrid law of the
benchmark's ``hybrid_pi`` contender (K_fp 1, K_fi 0.003, joint 2's drive
calibrated), acting every 10 ms: the same law, observation and action the
Gymnasium environment trained it on."""
from pathlib import Path

from drake_contact.app.benchmark import contender_scenario
from drake_contact.control.hybrid_controller import HybridControllerConfig
from drake_contact.control.policy import NumpyPolicy, PolicyConfig, PolicyController
from drake_contact.options import config_from_options
from drake_contact.plugins import declare

#: The trained weights, and how they were trained (their "about").
WEIGHTS = Path(__file__).with_name("policy.json")
#: The policy's control period (ms), as trained.
PERIOD_MS = 10


def hybrid_config() -> HybridControllerConfig:
    """The benchmark's hybrid_pi law, as the Gymnasium environment drives it
    (drake_contact.app.gym_env.BASE_CONTENDER)."""
    section = contender_scenario("hybrid_pi")["controller"]["hybrid"]
    return config_from_options(HybridControllerConfig, section, "controller.hybrid")


@declare(signals={
    "policy_observation": "the policy's observation (drake_contact.control.policy_spaces)",
    "policy_action": "the policy's action [force_residual, force_gain_scale, "
                     "integral_gain_scale, damping_x]"}, unlogged=("tip_jacobian",))
def make_controller(options: dict):
    """Takes no options: the trained weights are the controller."""
    if options:
        from drake_contact.errors import ScenarioError
        raise ScenarioError(f"controller.options: learned_residual takes none, got "
                            f"{', '.join(options)}")
    return PolicyController(hybrid_config(), PolicyConfig(period_ms=PERIOD_MS),
                            policy=NumpyPolicy.load(WEIGHTS))
