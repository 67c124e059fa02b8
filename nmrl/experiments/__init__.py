"""Experiments built on the driver: the Fig. 3 sweep over l, the finer-time-step study and its
conversion rules, the per-period variance of the actor's gradient estimate."""
