# Screening driver: l = 30, seed 0 for both candidates in one program (they differ only in the traced beta_v).
import dataclasses, sys
from nmrl import options
from nmrl.runs import devices
devices.configure(devices.AUTO)
from nmrl.runs import driver
from nmrl.learners.ac_config import TrainConfig
base = options.build(TrainConfig, l=30, seed=0, num_envs=64, chunk_steps=250, trials=int(sys.argv[sys.argv.index("--trials") + 1]) if "--trials" in sys.argv else 2000, preset="fast",
                   actor_opt="sgd,clip:0.03", critic_opt="sgd,clip:1")
cfgs = [base, dataclasses.replace(base, beta_v=1e-4)]
driver.run_points("runs/screen/l30", ["clip__l30_s0", "clip_bv1e-4__l30_s0"], cfgs, resume="--resume" in sys.argv,
                 progress=True, table=False, checkpoint_every=4)
