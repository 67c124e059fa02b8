"""The paper's robot behind the interfaces of other libraries, for their trainers (layer 2, beside
nmrl.learners): ``brax_env`` is the Half-Cheetah as a ``brax.envs.Env`` (Brax optional), ``brax_task``
Gymnasium's v5 tasks as one; ``gym_env`` is the Half-Cheetah as a ``gymnasium.Env`` on MuJoCo C
(Gymnasium optional; ``import nmrl.adapters.gym_env`` registers ``nmrl/PaperCheetah-v0``) with its
equations in NumPy in ``gym_robot``, and ``gym_noise`` nmrl's exploration processes as a Gymnasium
action-noise wrapper. Imports only nmrl.paper, nmrl.physics, nmrl.tasks and nmrl.explore."""
