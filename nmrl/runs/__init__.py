"""Running the learner: the devices and their sharding, the run directory (store), its checkpoints,
and one chunk-loop driver for 1..P points, for any learner of nmrl.learners (the contract:
nmrl/learners/contract.py). Imports only nmrl.learners and nmrl.paper. (Importing this package does not
import JAX: nmrl.runs.devices must run before JAX starts.)"""
