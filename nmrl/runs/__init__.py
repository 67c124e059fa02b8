"""Running the learner: the devices and their sharding, the run directory (store), its checkpoints,
and one chunk-loop driver for 1..P points. Imports only nmrl.paper. (Importing this package does not
import JAX: nmrl.runs.devices must run before JAX starts.)"""
