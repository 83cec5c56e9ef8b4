"""The Gymnasium environment of the contact station (the optional extra
``drake_contact[gym]``): importing this module registers
``drake_contact/ForceTracking-v0``::

    import gymnasium
    import drake_contact.gym

    env = gymnasium.make("drake_contact/ForceTracking-v0", task="square")

(or, without the import, ``gymnasium.make("drake_contact.gym:drake_contact/ForceTracking-v0")``).
The environment, its observation, action, reward, termination and
randomization: :mod:`drake_contact.app.gym_env`.
"""

from drake_contact.app.gym_env import (
    ENV_ID, LOWEST_REWARD, ForceTrackingEnv, TrainingDistribution, register)

__all__ = ["ENV_ID", "LOWEST_REWARD", "ForceTrackingEnv", "TrainingDistribution", "register"]

register()
