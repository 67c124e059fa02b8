r"""Power-law (colored) noise as a finite sum of Ornstein-Uhlenbeck components.

A target spectrum ``1/f^beta`` over a band ``[f_min, f_max]`` (Hz) is approximated by the
spectrum of ``sum_k w_k z_k(t)``, each ``z_k`` an independent unit-variance OU process with time
constant ``tau_k`` (seconds), whose two-sided power spectral density is the Lorentzian

    S_k(f) = 2 tau_k / (1 + (2 pi f tau_k)^2).

The ``tau_k`` are log-spaced: their corner frequencies ``1/(2 pi tau_k)`` run from
``f_min / 4`` to ``2 f_max`` (a margin of two octaves below the band so that beta up to 2 is reached
at its low end, one above so that beta near 0 stays flat at its top). The weights ``c_k = w_k^2 >= 0``
minimise the log-spectral error over the band (non-negative least squares on the relative error,
iteratively reweighted towards the error in log) with a free overall level, then ``sum_k c_k = 1``
makes the marginal variance 1 (the caller scales by sigma).

The fit is made once, in continuous time, so one setting (beta, band, order) is one physical process:
sampled at a control step dt each component is exactly an AR(1) with ``phi_k = exp(-dt/tau_k)``, and
the sampled sequence at dt = 20, 10 or 5 ms is the same process observed at different rates. The
spectrum of the *sampled* sequence also contains the power folded from above the Nyquist frequency
(aliasing), which :func:`spectrum_error_db` reports separately with ``control_dt`` (docs/exploration.md
lists both errors). :func:`fit_weights` with ``control_dt`` instead fits the sampled spectrum of one
control step (a different process at each dt); the exploration spec does not use it.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.optimize import nnls

__all__ = [
    "LOW_MARGIN",
    "HIGH_MARGIN",
    "lorentzian_psd",
    "ar1_psd",
    "time_constants",
    "fit_weights",
    "colored_components",
    "spectrum_error_db",
]

#: the slowest component's corner frequency is f_min / LOW_MARGIN, the fastest's f_max * HIGH_MARGIN
LOW_MARGIN = 4.0
HIGH_MARGIN = 2.0
_N_FREQ = 400  # log-spaced frequencies over the band for the fit and the error
_REWEIGHTS = 4  # reweighting passes from the relative towards the log error


def lorentzian_psd(tau: np.ndarray, f: np.ndarray) -> np.ndarray:
    """Two-sided PSD (per Hz) of a unit-variance OU process with time constant ``tau`` at ``f`` Hz."""
    tau, f = np.asarray(tau, np.float64), np.asarray(f, np.float64)
    return 2.0 * tau / (1.0 + (2.0 * math.pi * f * tau) ** 2)


def ar1_psd(phi: np.ndarray, f: np.ndarray, control_dt: float) -> np.ndarray:
    """Two-sided PSD (per Hz) of a unit-variance AR(1) sequence with coefficient ``phi`` sampled every
    ``control_dt`` seconds: ``dt (1 - phi^2) / |1 - phi e^{-i 2 pi f dt}|^2``."""
    phi, f = np.asarray(phi, np.float64), np.asarray(f, np.float64)
    w = 2.0 * math.pi * f * control_dt
    return control_dt * (1.0 - phi**2) / (1.0 - 2.0 * phi * np.cos(w) + phi**2)


def time_constants(f_min_hz: float, f_max_hz: float, order: int) -> np.ndarray:
    """The ``order`` time constants (s), slowest first, log-spaced in corner frequency over
    ``[f_min / LOW_MARGIN, f_max * HIGH_MARGIN]`` (one component: at the band's geometric centre)."""
    if order == 1:
        fc = np.array([math.sqrt(f_min_hz * f_max_hz)])
    else:
        fc = np.geomspace(f_min_hz / LOW_MARGIN, f_max_hz * HIGH_MARGIN, order)
    return 1.0 / (2.0 * math.pi * fc)


def _band(f_min_hz: float, f_max_hz: float) -> np.ndarray:
    return np.geomspace(f_min_hz, f_max_hz, _N_FREQ)


def _component_psd(tau: np.ndarray, f: np.ndarray, control_dt: float | None) -> np.ndarray:
    if control_dt is None:
        return lorentzian_psd(tau[None, :], f[:, None])
    return ar1_psd(np.exp(-control_dt / tau)[None, :], f[:, None], control_dt)


def fit_weights(beta: float, f_min_hz: float, f_max_hz: float, tau: np.ndarray,
                control_dt: float | None = None) -> np.ndarray:
    """Weights ``w`` (``w_k >= 0``, ``sum w_k^2 = 1``) of the components with time constants ``tau``
    whose summed spectrum is closest to ``c / f^beta`` over the band, in log, for the best level c.

    ``control_dt=None`` fits the continuous-time (Lorentzian) spectrum; a number fits the spectrum
    of the sequence sampled every ``control_dt`` seconds instead.
    """
    tau = np.asarray(tau, np.float64)
    f = _band(f_min_hz, f_max_hz)
    target = f ** (-float(beta))
    M = _component_psd(tau, f, control_dt) / target[:, None]  # relative: M c = 1 is a perfect fit
    r = np.ones_like(f)
    for _ in range(_REWEIGHTS + 1):
        c, _ = nnls(M / r[:, None], 1.0 / r)  # minimise sum ((M c - 1) / r)^2, r = the last ratio
        r = np.maximum(M @ c, 1e-12)
    c = c / c.sum()
    return np.sqrt(c)


def colored_components(beta: float, f_min_hz: float, f_max_hz: float, order: int
                       ) -> tuple[np.ndarray, np.ndarray]:
    """``(tau (order,), w (order,))`` of the continuous-time fit (float64, slowest first)."""
    tau = time_constants(f_min_hz, f_max_hz, order)
    return tau, fit_weights(beta, f_min_hz, f_max_hz, tau)


def spectrum_error_db(beta: float, f_min_hz: float, f_max_hz: float, tau: np.ndarray, w: np.ndarray,
                      control_dt: float | None = None) -> float:
    """Largest deviation in dB of the components' spectrum from ``c / f^beta`` over the band, at the
    level c that makes it smallest (half the peak-to-peak of the log ratio). ``control_dt=None``: the
    continuous-time spectrum; a number: the spectrum of the sequence sampled at that step."""
    f = _band(f_min_hz, f_max_hz)
    S = _component_psd(np.asarray(tau, np.float64), f, control_dt) @ (np.asarray(w, np.float64) ** 2)
    db = 10.0 * np.log10(S * f ** float(beta))
    return float((db.max() - db.min()) / 2.0)
