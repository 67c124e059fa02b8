"""The paper's robot behind the interfaces of other libraries, for their trainers (layer 2, beside
nmrl.learners): ``brax_env`` is the Half-Cheetah as a ``brax.envs.Env`` (Brax optional). Imports only
nmrl.paper."""
