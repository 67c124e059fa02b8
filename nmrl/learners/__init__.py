"""Learners behind one contract (nmrl/learners/contract.py): the paper's actor-critic (``ac``) and
others (``ppo``); the driver, checkpoints, sweep, evaluation and command line take any of them."""

from nmrl.learners.contract import (BUILTIN, DEFAULT, KEY, LATER_FIELDS, Config, Learner, Policy, Trainer,  # noqa: F401
                                    config_dict, config_from_dict, get, is_diverged, names, norm_keys, of,
                                    program_key, register, replace_state, saved_fields)
