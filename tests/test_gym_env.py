"""The Gymnasium door (nmrl/adapters/gym_env.py, gym_noise.py): the paper's robot as a
``gymnasium.Env`` on MuJoCo C in float64, and nmrl's exploration processes as an action-noise wrapper.

* Gymnasium's own checker passes for the environment and the wrapped environment, and a plain
  Gymnasium loop runs until the stop rule truncates the trial.
* Against nmrl's own C-physics environment (``HalfCheetah(EnvConfig(physics="c"))``, JAX, float32
  observation and reward): from the same reset state (nmrl's reset is the same state for every key)
  and the same actions, the MuJoCo state is the same bit for bit after every step, and the
  observation, the reward and each reward term (8)-(14) agree to float32 rounding; a NaN action
  fails the physics in both.
* The wrapper's noise statistics against the process's definition (nmrl/explore/process.py): the
  stationary variance sigma^2 and the autocorrelations in closed form from the spec's parameters
  (alpha = exp(-dt / corr_time_s), l = round(period_s / dt), or the colored fit's (phi_k, w_k)),
  within 5 standard errors of a long sample; the restart at reset, the seeding.
* Bad ``make`` kwargs raise ValueError naming the value and what is allowed.
"""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest

gym = pytest.importorskip("gymnasium")

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
from gymnasium.utils.env_checker import check_env  # noqa: E402

from nmrl.adapters import gym_env  # noqa: E402
from nmrl.adapters.gym_env import ENV_ID, PaperCheetahEnv  # noqa: E402
from nmrl.adapters.gym_noise import ExplorationNoise  # noqa: E402
from nmrl.explore.spec import PAPER_CORR_TIME_S, ExplorationSpec  # noqa: E402
from nmrl.paper.env import REWARD_TERMS, EnvConfig, HalfCheetah  # noqa: E402
from nmrl.physics.mujoco_c import from_bits  # noqa: E402

#: the only warnings Gymnasium's checker may give: the observation's Box is unbounded (velocities
#: are), and a wrapped environment is not its unwrapped self
_EXPECTED_WARNINGS = ("infinity", "different from the unwrapped version")


def _checked(env) -> list[str]:
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        check_env(env)
    return [str(w.message) for w in caught if not any(s in str(w.message) for s in _EXPECTED_WARNINGS)]


# --------------------------------------------------------------------------- Gymnasium's API
def test_check_env_passes_for_the_env_and_the_wrapped_env():
    env = gym.make(ENV_ID).unwrapped
    assert isinstance(env, PaperCheetahEnv) and env.spec is not None and env.spec.id == ENV_ID
    assert _checked(env) == []
    wrapped = ExplorationNoise(gym.make(ENV_ID), ExplorationSpec("nm-periods", sigma=0.1))
    assert _checked(wrapped) == []


def test_a_plain_gymnasium_loop_runs_until_the_stop_rule_truncates():
    env = gym.make(ENV_ID, control_dt=0.02)
    assert env.unwrapped.stop_prob == pytest.approx(1 / 250) and env.unwrapped.n_substeps == 4
    env.action_space.seed(3)
    obs, info = env.reset(seed=3)
    assert obs.shape == (31,) and obs.dtype == np.float64 and env.observation_space.contains(obs)
    steps, ret = 0, 0.0
    while True:
        obs, reward, terminated, truncated, info = env.step(env.action_space.sample())
        steps += 1
        ret += reward
        assert not terminated and not info["physics_failed"]
        assert np.all(np.isfinite(obs)) and math.isfinite(reward)
        assert reward == pytest.approx(sum(info[k] for k in REWARD_TERMS), abs=1e-12)
        if truncated:
            break
        assert steps < 5000
    assert steps > 1 and ret != 0.0
    env.close()


def test_the_stop_rule_is_a_truncation_at_its_rate():
    env = PaperCheetahEnv(control_dt=0.005, stop_prob=0.2)
    env.reset(seed=0)
    n, flags = 3000, []
    for _ in range(n):
        _, _, terminated, truncated, _ = env.step(np.zeros(6, np.float32))
        assert not terminated
        flags.append(truncated)
    se = math.sqrt(0.2 * 0.8 / n)
    assert abs(np.mean(flags) - 0.2) < 5 * se
    assert PaperCheetahEnv(stop_prob=0.0).stop_prob == 0.0
    # the default keeps the paper's mean trial of 5 s: 1/250 per 0.02 s step, 1/1000 per 0.005 s
    assert PaperCheetahEnv(control_dt=0.005).stop_prob == pytest.approx(1 / 1000)


def test_registration_and_make_kwargs():
    assert gym_env.ACTION_SCALE == 20.0
    from nmrl.adapters import brax_env

    assert gym_env.ACTION_SCALE == brax_env.ACTION_SCALE  # the same action map as the Brax adapter's
    env = gym.make(ENV_ID, control_dt=0.01, stop_prob=0.01)
    assert env.unwrapped.n_substeps == 2 and env.unwrapped.dt == 0.01 and env.unwrapped.stop_prob == 0.01
    env = gym.make(f"nmrl.adapters.gym_env:{ENV_ID}", control_dt=0.005)
    assert env.unwrapped.n_substeps == 1
    gym_env.register()  # idempotent


@pytest.mark.parametrize("kwargs, named, allowed", [
    ({"control_dt": 0.0}, "control_dt=0.0", "multiple of the physics timestep 0.005"),
    ({"control_dt": -0.02}, "control_dt=-0.02", "(0, 1]"),
    ({"control_dt": 0.012}, "control_dt=0.012", "multiple of the physics timestep 0.005"),
    ({"control_dt": 2.0}, "control_dt=2.0", "(0, 1]"),
    ({"control_dt": float("nan")}, "control_dt=nan", "(0, 1]"),
    ({"control_dt": float("inf")}, "control_dt=inf", "(0, 1]"),
    ({"control_dt": "0.02"}, "control_dt='0.02'", "number of seconds"),
    ({"control_dt": True}, "control_dt=True", "number of seconds"),
    ({"stop_prob": 1.0}, "stop_prob=1.0", "[0, 1)"),
    ({"stop_prob": -0.1}, "stop_prob=-0.1", "[0, 1)"),
    ({"stop_prob": float("nan")}, "stop_prob=nan", "[0, 1)"),
    ({"stop_prob": "often"}, "stop_prob='often'", "[0, 1)"),
    ({"render_mode": "human"}, "render_mode='human'", "use None"),
])
def test_bad_make_kwargs_raise_value_error_naming_the_value(kwargs, named, allowed):
    with pytest.raises(ValueError) as e, warnings.catch_warnings():
        warnings.simplefilter("ignore")  # Gymnasium's own warning about a render mode not declared
        gym.make(ENV_ID, **kwargs)
    assert named in str(e.value) and allowed in str(e.value), str(e.value)


# ------------------------------------------------------------------ equal to nmrl's own C env
@pytest.mark.parametrize("control_dt", [0.02, 0.01])
def test_steps_equal_nmrls_c_environment(control_dt):
    """1 s of random actions from the reset state (50 steps at 0.02 s), then a NaN action (failed physics)."""
    ref = HalfCheetah(EnvConfig(physics="c", control_dt=control_dt, stop_prob=0.0, auto_reset=False, threads=1))
    jstep = jax.jit(ref.step)
    env = PaperCheetahEnv(control_dt=control_dt, stop_prob=0.0)
    obs, _ = env.reset(seed=0)
    s = ref.reset(jax.random.key(0))  # the state does not depend on the key (only the stop rule does)
    np.testing.assert_array_equal(from_bits(np.asarray(s.data.state)), env.mujoco_state())
    np.testing.assert_allclose(obs, np.asarray(s.obs), rtol=0, atol=1e-6)
    rng = np.random.default_rng(0)
    # u on a grid of 1/1024 (some beyond [-1, 1]: clipped), so that 20 u is exact in float32 and both
    # environments get the same action bits
    u = rng.integers(-1100, 1101, size=(round(1.0 / control_dt), 6)) / 1024
    worst = {"obs": 0.0, "reward": 0.0, **dict.fromkeys(REWARD_TERMS, 0.0)}
    seen = dict.fromkeys(REWARD_TERMS, False)
    for t in range(len(u)):
        s = jstep(s, jnp.asarray(gym_env.ACTION_SCALE * np.clip(u[t], -1, 1), jnp.float32))
        obs, reward, terminated, truncated, info = env.step(u[t].astype(np.float32))
        assert not terminated and not truncated and float(s.done) == 0.0
        # the same MuJoCo state, bit for bit (the same mj_step in float64 from the same state and action)
        np.testing.assert_array_equal(from_bits(np.asarray(s.data.state)), env.mujoco_state())
        d_obs = np.abs(obs - np.asarray(s.obs, np.float64)) / (1 + np.abs(obs))
        worst["obs"] = max(worst["obs"], float(d_obs.max()))
        worst["reward"] = max(worst["reward"], abs(reward - float(s.reward)) / (1 + abs(reward)))
        for k in REWARD_TERMS:
            worst[k] = max(worst[k], abs(info[k] - float(s.metrics[k])) / (1 + abs(info[k])))
            seen[k] |= info[k] != 0.0
        for k in ("forward_speed", "x", "heel_ground", "knee_ground", "head_ground"):
            assert info[k] == pytest.approx(float(s.metrics[k]), rel=1e-5, abs=1e-5), k
    print(f"control_dt={control_dt}: worst relative differences |d|/(1+|value|):",
          {k: f"{v:.2e}" for k, v in worst.items()})
    assert all(seen.values()), seen  # every term of (8)-(14) was exercised
    assert worst["obs"] < 2e-5 and worst["reward"] < 2e-5, worst
    assert max(worst[k] for k in REWARD_TERMS) < 2e-5, worst
    # a NaN action: MuJoCo warns, both flag it and start over from the initial pose with reward 0
    s = jstep(s, jnp.full(6, jnp.nan, jnp.float32))
    obs, reward, terminated, truncated, info = env.step(np.full(6, np.nan, np.float32))
    assert float(s.metrics["nonfinite"]) == 1.0 and terminated and not truncated and info["physics_failed"]
    assert reward == 0.0 == float(s.reward)
    np.testing.assert_array_equal(from_bits(np.asarray(s.data.state)), env.mujoco_state())
    np.testing.assert_allclose(obs, env.reset()[0])


# ------------------------------------------------------------------ the exploration wrapper
class _Recorder(gym.Env):
    """Records the actions it gets; never ends. Its Box is wide, so clipping never touches the noise."""

    metadata = {"render_modes": []}

    def __init__(self, dt: float, n: int = 6):
        self.dt = dt
        self.action_space = gym.spaces.Box(-100.0, 100.0, (n,), np.float64)
        self.observation_space = gym.spaces.Box(-1.0, 1.0, (1,), np.float64)
        self.actions: list[np.ndarray] = []

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        return np.zeros(1), {}

    def step(self, action):
        self.actions.append(np.array(action, np.float64))
        return np.zeros(1), 0.0, False, False, {}


def _noise(spec: ExplorationSpec, dt: float, steps: int, seed: int = 0, agent: float = 0.3) -> np.ndarray:
    """(steps, 6) noise the environment received beyond the agent's constant action, one trial."""
    env = ExplorationNoise(_Recorder(dt), spec)
    env.reset(seed=seed)
    for _ in range(steps):
        env.step(np.full(6, agent))
    return np.array(env.env.actions) - agent


def _corr(a: np.ndarray, b: np.ndarray, sigma: float) -> float:
    """E[a b] / sigma^2 over every pair (the process has mean 0 and variance sigma^2)."""
    return float(np.mean(a * b)) / sigma**2


def _se(rho, h: int, n: int, horizon: int = 4000) -> float:
    """Standard error of ``_corr(x[h:], x[:-h])`` from n pairs of a stationary Gaussian process with
    mean 0 and autocorrelation ``rho`` (Bartlett's formula for a known mean: the variance of a
    sample autocovariance is sum_k (rho(k)^2 + rho(k + h) rho(k - h)) / n; h = 0 is the variance)."""
    return math.sqrt(sum(rho(k) ** 2 + rho(k + h) * rho(k - h) for k in range(-horizon, horizon + 1)) / n)


@pytest.mark.parametrize("dt", [0.02, 0.005])
def test_ou_noise_has_its_stationary_variance_and_autocorrelation(dt):
    sigma, tau = 0.5, 0.1
    xi = _noise(ExplorationSpec("ou", sigma=sigma, corr_time_s=tau), dt, 20000)
    phi = math.exp(-dt / tau)  # the process's definition: AR(1) with alpha = exp(-dt / corr_time_s)
    rho = lambda k: phi ** abs(k)  # noqa: E731
    for h in (0, 1, 5):
        got = _corr(xi[h:], xi[: len(xi) - h], sigma)
        assert abs(got - rho(h)) < 5 * _se(rho, h, xi[h:].size), (h, got, rho(h))


@pytest.mark.parametrize("dt", [0.02, 0.01])
def test_nm_periods_noise_is_eq4_inside_a_period_and_independent_across(dt):
    """The paper's alpha = 0.8 per 20 ms (corr_time_s = -0.02 / ln 0.8), periods of 0.2 s. Each
    period starts afresh, so the periods of one long trial are independent blocks of l steps in
    which cov(xi_i, xi_j) = sigma^2 alpha^|i-j| (eq. (5)): the statistics below are means of
    independent products with known variances."""
    sigma = 0.2
    spec = ExplorationSpec("nm-periods", sigma=sigma, period_s=0.2, corr_time_s=PAPER_CORR_TIME_S)
    alpha = 0.8 ** (dt / 0.02)
    l = round(0.2 / dt)  # noqa: E741 (the paper's name)
    assert alpha == pytest.approx(math.exp(-dt / spec.corr_time_s)) and l == spec.components(dt)[2]
    xi = _noise(spec, dt, 2000 * l, seed=1).reshape(2000, l, 6)  # the first draw starts a period
    n = xi[:, 0].size
    for j in (0, l // 2, l - 1):  # stationary inside the period: N(0, sigma^2) at every step
        assert abs(_corr(xi[:, j], xi[:, j], sigma) - 1) < 5 * math.sqrt(2 / n), j
    for i, j in ((0, 1), (l - 2, l - 1), (0, 2), (1, l - 1)):  # alpha^|i-j|, product variance 1 + alpha^2|i-j|
        r = alpha ** (j - i)
        assert abs(_corr(xi[:, i], xi[:, j], sigma) - r) < 5 * math.sqrt((1 + r * r) / n), (i, j)
    # across a period boundary: independent (product variance 1)
    assert abs(_corr(xi[:-1, -1], xi[1:, 0], sigma)) < 5 * math.sqrt(1 / xi[1:, 0].size)


def test_white_and_colored_noise_have_their_autocovariance():
    sigma, dt = 0.3, 0.02
    xi = _noise(ExplorationSpec("white", sigma=sigma), dt, 10000, seed=2)
    rho = lambda k: float(k == 0)  # noqa: E731
    for h in (0, 1, 3):
        assert abs(_corr(xi[h:], xi[: len(xi) - h], sigma) - rho(h)) < 5 * _se(rho, h, xi[h:].size, 5), h
    # colored: cov(xi_t, xi_{t+h}) = sigma^2 sum_k w_k^2 phi_k^|h| with the fit's (phi_k, w_k)
    spec = ExplorationSpec("colored", sigma=sigma, beta=1.0, f_min_hz=2.0, f_max_hz=25.0, order=4)
    phi, w, period = spec.components(dt)
    assert period > 10**8  # no period resets
    xi = _noise(spec, dt, 30000, seed=3)
    rho = lambda k: float(np.sum(w**2 * phi ** abs(k)))  # noqa: E731
    for h in (0, 1, 5, 20):
        got = _corr(xi[h:], xi[: len(xi) - h], sigma)
        assert abs(got - rho(h)) < 5 * _se(rho, h, xi[h:].size, 2000), (h, got, rho(h))


def test_noise_restarts_at_reset_and_is_seeded_by_reset():
    sigma, dt = 1.0, 0.02
    spec = ExplorationSpec("ou", sigma=sigma, corr_time_s=2.0)  # phi = 0.990: slow
    env = ExplorationNoise(_Recorder(dt), spec)
    env.reset(seed=5)
    for _ in range(3000):  # trials of 4 steps
        for _ in range(4):
            env.step(np.zeros(6))
        env.reset()
    xi = np.array(env.env.actions).reshape(3000, 4, 6)  # independent trials
    phi = math.exp(-dt / 2.0)
    n = xi[:, 0].size
    assert abs(_corr(xi[:, 0], xi[:, 0], sigma) - 1) < 5 * math.sqrt(2 / n)  # a trial starts stationary
    assert abs(_corr(xi[:, 1], xi[:, 0], sigma) - phi) < 5 * math.sqrt((1 + phi**2) / n)
    # the first draw of a trial is independent of the last draw of the trial before
    assert abs(_corr(xi[1:, 0], xi[:-1, -1], sigma)) < 5 / math.sqrt(xi[1:, 0].size)
    # reset(seed=s) gives the same noise again; another seed other noise
    a, b, c = (_noise(spec, dt, 20, seed=s) for s in (7, 7, 8))
    np.testing.assert_array_equal(a, b)
    assert not np.allclose(a, c)


def test_wrapper_leaves_the_stop_rule_alone_and_sends_valid_actions():
    """The noise has a generator of its own: the wrapped env truncates at the same steps as the
    unwrapped one with the same seed; the noisy action is clipped to [-1, 1] and float32."""
    spec = ExplorationSpec("nm-periods", sigma=0.5)
    bare, wrapped = PaperCheetahEnv(stop_prob=0.3), ExplorationNoise(PaperCheetahEnv(stop_prob=0.3), spec)
    bare.reset(seed=11)
    wrapped.reset(seed=11)
    for _ in range(30):
        _, _, _, t_bare, _ = bare.step(np.full(6, 0.9, np.float32))
        _, _, _, t_wrapped, info = wrapped.step(np.full(6, 0.9, np.float32))
        assert t_bare == t_wrapped
        act = info["executed_action"]
        assert act.dtype == np.float32 and np.all(np.abs(act) <= 1.0)
        np.testing.assert_allclose(act, np.clip(0.9 + info["exploration_noise"], -1, 1), atol=1e-6)


def test_wrapper_refuses_a_spec_the_control_step_cannot_take():
    with pytest.raises(ValueError, match=r"period_s must be >= the control step 0.02 s, got 0.01"):
        ExplorationNoise(PaperCheetahEnv(), ExplorationSpec("nm-periods", period_s=0.01))
    with pytest.raises(ValueError, match="Box"):
        ExplorationNoise(gym.make("CartPole-v1"), ExplorationSpec("white"))
