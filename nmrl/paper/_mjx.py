"""``mujoco.mjx`` imported without its stdout message about the optional warp backend."""

import contextlib
import io

with contextlib.redirect_stdout(io.StringIO()):
    from mujoco.mjx import *  # noqa: F401,F403
    from mujoco.mjx import Data, Model  # noqa: F401
