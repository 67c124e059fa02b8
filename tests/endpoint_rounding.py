"""A published deterministic endpoint recomputed on this processor: equal within its own sampling error.

XLA compiles the policy for the host processor's vector instructions, so its float32 results differ in
the last bits from one processor to another, and a walking robot's 10 s rollouts amplify those bits.
Measured on an AMD EPYC (Zen 3, AVX2) against study 2's endpoints published on another processor:

* perturbing every parameter of the published white policy (``grid/dt0.02/white`` s0, 108.92 reward/s
  published) by one unit in the last place gave endpoints of 109.93-110.96 here (110.23 unperturbed);
* the stages' NMp s1 after 32 iterations, a policy on the verge of walking (46.28 published), gave
  28.43-63.18 (33.44 unperturbed): some rollouts walk or fall depending on the last bits;
* a standing policy (``grid/dt0.02/nmp`` s0, -46.006) gave -46.006 every time.

On the processor that published an endpoint, its recomputation is exact. Elsewhere the recomputation is
another draw of the same rollouts' outcome, so it is held to the sampling error the study's intervals
already carry: the difference of two 8-rollout means within 3 of its standard errors, the rollouts' SD
taken from both sides where both are published (5.5 reward/s for the white policy above, 83 for the
verge-of-walking one, whose rollouts range from falling to walking). The stages' NMp s1 one stage
earlier, at 28 iterations, scored -61.09: 107 below its 46.28, beyond that band.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np


def assert_same_endpoint(here: Sequence[float], published_mean: float,
                         published: Sequence[float] | None = None, label: str = "") -> None:
    """``here`` (per-rollout values recomputed on this processor) agrees with ``published_mean``
    (with its per-rollout values ``published`` where the record keeps them) within 3 standard errors
    of the difference of the two means."""
    here = np.asarray(here, float)
    other = here if published is None else np.asarray(published, float)
    assert published is None or np.isclose(np.mean(other), published_mean), "the published mean is its rollouts'"
    se = np.sqrt(np.var(here, ddof=1) / here.size + np.var(other, ddof=1) / other.size)
    gap = abs(float(np.mean(here)) - published_mean)
    assert gap <= 3 * se, f"{label}: recomputed {np.mean(here):.4f} against {published_mean:.4f} published, " \
                          f"{gap:.4f} apart, beyond 3 standard errors ({3 * se:.4f})"
