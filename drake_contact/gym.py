"""The Gymnasium environment of the contact station (the optional extra
``drake_contact[gym]``): importing this module registers
``drake_contact/ForceTracking-v0``::

    import gymnasium
    import drake_contact.gym

    env = gymnasium.make("drake_contact/ForceTracking-v0", task="square")
    envs = gymnasium.make_vec("drake_contact/ForceTracking-v0", num_envs=16, task="square")

(or, without the import, ``gymnasium.make("drake_contact.gym:drake_contact/ForceTracking-v0")``).
The environment, its observation, action, reward, termination and
randomization: :mod:`drake_contact.app.gym_env`; the vector environment
(N of them in one ensemble diagram, synchronised episodes):
:mod:`drake_contact.app.gym_vector`.
"""

from drake_contact.app.gym_env import (
    ENV_ID, LOWEST_REWARD, ForceTrackingEnv, TrainingDistribution, register)
from drake_contact.app.gym_vector import ForceTrackingVectorEnv

__all__ = ["ENV_ID", "LOWEST_REWARD", "ForceTrackingEnv", "ForceTrackingVectorEnv",
           "TrainingDistribution", "register"]

register()
