"""The parameter-tuning environments and the PPO fit (paper: state = parameters, action =
modifications, reward = -(external + internal) errors)."""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

from cobra_model.gait import SidewindingGait
from cobra_model.parameters import ModelParameters
from integrators.simulate import simulate_gait, simulate_like
from sysid.identification.env import ParameterTuningEnv
from sysid.identification.lsq import FitStatus
from sysid.identification.objective import Objective, ObjectiveTerms
from sysid.identification.ppo import PPOSettings, fit_ppo
from sysid.identification.vec_env import WORST_RATIO, BatchedTuningVecEnv

FREE = ["mu_c", "joint_damping"]


def _truth() -> ModelParameters:
    return ModelParameters.nominal().with_frozen(free=FREE)


@dataclass
class BowlObjective:
    """A stand-in objective without simulation: total = |z - target|_1 in unit coordinates;
    parameter vectors with ``z[0] > diverge_above`` diverge as a simulation does (raise, or
    None with ``divergence="mask"``)."""

    params: ModelParameters
    target: np.ndarray
    diverge_above: float = 2.0

    def terms(self, X: np.ndarray, divergence: str = "raise") -> list[ObjectiveTerms | None]:
        """The objective's terms for the rows of X (physical free-parameter values)."""
        out: list[ObjectiveTerms | None] = []
        for x in np.atleast_2d(X):
            z = self.params.update_from_vector(x).to_unit()
            if z[0] > self.diverge_above:
                if divergence == "raise":
                    raise RuntimeError("diverged")
                out.append(None)
                continue
            err = float(np.abs(z - self.target).sum())
            out.append(ObjectiveTerms(err, err / 2, err / 4, 0.0, external=err, internal=0.0, total=err))
        return out


@pytest.fixture(scope="module")
def tiny_objective() -> Objective:
    """One 0.5 s run simulated from the truth; the guess is 40 % off in both free parameters."""
    run = simulate_gait(SidewindingGait(0.5), 0.5, params=_truth(), sample_rate_hz=50)
    return Objective([run], _truth().with_values(mu_c=0.42, joint_damping=0.14))


def test_check_env_passes(tiny_objective: Objective) -> None:
    env = ParameterTuningEnv(tiny_objective)
    check_env(env, skip_render_check=True)
    assert env.observation_space.shape == (2,)


def test_check_env_passes_with_terms_and_jitter() -> None:
    """The optional observation of the objective terms and the jittered start (on the stand-in:
    a jittered start evaluates the objective at every reset)."""
    params = _truth()
    env = ParameterTuningEnv(BowlObjective(params, params.to_unit() + 0.05), observe_terms=True, start_jitter=0.02)
    check_env(env, skip_render_check=True)
    obs, _ = env.reset(seed=0)
    assert obs.shape == (6,) and np.all(np.abs(obs[2:]) < 1.0)


def test_action_moves_unit_coordinates_and_best_is_kept() -> None:
    params = _truth()
    target = params.to_unit() + np.array([0.05, -0.05])
    bowl = BowlObjective(params, target)
    env = ParameterTuningEnv(bowl, episode_length=3, max_step=0.1)
    obs, _ = env.reset(seed=0)
    np.testing.assert_allclose(obs, params.to_unit(), atol=1e-6)
    obs, reward, terminated, truncated, info = env.step(np.array([0.5, -0.5], dtype=np.float32))
    np.testing.assert_allclose(obs, target, atol=1e-6)          # 0.5 * max_step = the 0.05 offsets
    assert reward == pytest.approx(0.0, abs=1e-9) and not terminated and not truncated
    _, reward, _, truncated, _ = env.step(np.array([1.0, 0.0], dtype=np.float32))
    assert reward == pytest.approx(-0.1) and not truncated
    _, reward, _, truncated, info = env.step(np.array([1.0, 0.0], dtype=np.float32))
    assert reward == pytest.approx(-0.2)
    assert truncated and info["best_total"] == pytest.approx(0.0, abs=1e-9)
    np.testing.assert_allclose(env.best_z, target, atol=1e-9)
    np.testing.assert_allclose(env.best_params.as_vector(), params.from_unit(target).as_vector())
    assert env.evaluations == 4                                  # the initial parameters and 3 steps


def test_invalid_or_diverging_parameters_are_not_applied() -> None:
    params = _truth().with_values(mu_c=0.44)                      # mu_s = 0.45 is frozen
    mu_c = params.free_names.index("mu_c")
    z0 = params.to_unit()
    bowl = BowlObjective(params, z0, diverge_above=z0[1 - mu_c] + 0.05)
    env = ParameterTuningEnv(bowl, failure_factor=3.0)
    reference = env.reference_terms.total
    env.reset(seed=0)
    up = np.zeros(2, dtype=np.float32)
    up[mu_c] = 1.0                                                # mu_c would exceed mu_s
    obs, reward, _, _, info = env.step(up)
    assert info["failed"] and reward == -3.0 * reference
    np.testing.assert_allclose(obs, z0, atol=1e-6)
    other = np.zeros(2, dtype=np.float32)
    other[1 - mu_c] = 1.0                                         # the stand-in simulation diverges
    obs, reward, _, _, info = env.step(other)
    assert info["failed"] and reward == -3.0 * reference
    np.testing.assert_allclose(obs, z0, atol=1e-6)


def test_jittered_reset_is_seeded() -> None:
    params = _truth()
    env = ParameterTuningEnv(BowlObjective(params, params.to_unit()), start_jitter=0.05)
    a, _ = env.reset(seed=7)
    b, _ = env.reset(seed=7)
    c, _ = env.reset(seed=8)
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)
    assert np.all(np.abs(a - params.to_unit()) <= 0.05 + 1e-6)


def test_batched_env_proposes_around_the_best_and_rewards_the_ratio() -> None:
    """One vectorised step: proposals z_best + a * radius, reward -ln(total / best total)
    clipped to +-ln(WORST_RATIO), the best proposal becomes the next start."""
    params = _truth()
    z0 = params.to_unit()
    target = z0 + np.array([0.04, -0.02])
    env = BatchedTuningVecEnv(BowlObjective(params, target), 3, max_step=0.1, patience=2)
    best0 = env.best_terms.total
    assert best0 == pytest.approx(0.06)
    np.testing.assert_allclose(env.reset(), np.repeat(z0[None], 3, axis=0), atol=1e-6)
    actions = np.array([[0.4, -0.2], [0.4, 0.0], [-1.0, 1.0]], dtype=np.float32)
    obs, rewards, dones, infos = env.step(actions)
    np.testing.assert_allclose(rewards, [np.log(WORST_RATIO), np.log(3.0), -np.log(0.26 / 0.06)], rtol=1e-5)
    assert dones.all() and all(info["episode"]["l"] == 1 for info in infos)
    np.testing.assert_allclose(env.best_z, target, atol=1e-7)
    np.testing.assert_allclose(obs, np.repeat(target[None], 3, axis=0), atol=1e-6)
    assert env.evaluations == 4                                  # the initial parameters and 3 proposals


def test_batched_env_halves_its_radius_without_progress_and_floors_failures() -> None:
    """Patience 2: two vectorised steps without a better proposal halve the radius. An
    infeasible proposal (mu_c above the frozen mu_s) and a diverging one get the floor reward
    and do not stop the others of the batch from being evaluated."""
    params = _truth().with_values(mu_c=0.44)                      # mu_s = 0.45 is frozen
    mu_c = params.free_names.index("mu_c")
    other = 1 - mu_c
    z0 = params.to_unit()
    target = z0.copy()
    target[other] += 0.01                                         # the start's total: 0.01
    env = BatchedTuningVecEnv(BowlObjective(params, target, diverge_above=z0[other] + 0.05), 3, max_step=0.1)
    actions = np.zeros((3, 2), dtype=np.float32)
    actions[0, mu_c] = 1.0                                        # mu_c would exceed mu_s
    actions[1, other] = 1.0                                       # the stand-in simulation diverges
    actions[2, other] = -0.5                                      # evaluated: total 0.06
    _, rewards, _, _ = env.step(actions)
    np.testing.assert_allclose(rewards, [-np.log(WORST_RATIO), -np.log(WORST_RATIO), -np.log(6.0)], rtol=1e-5)
    assert env.radius == 0.1
    env.step(actions)
    assert env.radius == pytest.approx(0.05)                      # halved after two steps without progress
    np.testing.assert_allclose(env.best_z, z0)
    assert env.evaluations == 1 + 2 * 2                           # the infeasible rows are not simulated


def test_fit_ppo_smoke(tiny_objective: Objective, tmp_path) -> None:
    seen: list[tuple[int, float, float]] = []
    png = tmp_path / "reward.png"
    result = fit_ppo(tiny_objective, total_timesteps=192, n_envs=2, seed=0,
                     progress=lambda *point: seen.append(point), curve_png=png)
    assert result.method == "ppo" and result.status is FitStatus.MAX_ITERATIONS
    assert result.cost <= result.initial_cost
    assert result.cost == pytest.approx(tiny_objective(result.params.as_vector()), rel=1e-9)
    curve = result.extra["reward_curve"]
    assert [(steps, best, reward) for steps, reward, best in curve] == seen   # progress order differs
    assert curve[-1][0] == result.extra["timesteps"] == 192
    assert all(later[2] <= earlier[2] for earlier, later in zip(curve, curve[1:]))
    assert result.evaluations >= 2 and png.stat().st_size > 0
    assert result.params.free_names == tiny_objective.params.free_names
    assert [row.name for row in result.report] == list(tiny_objective.params.free_names)
    for row in result.report:
        assert math.isnan(row.ci_low) and math.isnan(row.ci_high)
        assert row.identifiable and row.reason == "no interval (PPO)"


def test_fit_ppo_searches_on_a_subset_and_reports_the_cost_on_every_run(tiny_objective: Objective) -> None:
    """With ``episode_runs`` = 1 of two runs (two gaits) the proposals simulate one run; the
    result's cost and initial cost are the objective's on both."""
    other = simulate_gait(SidewindingGait(0.35), 0.5, params=_truth(), sample_rate_hz=50)
    objective = Objective([*tiny_objective.runs, other], tiny_objective.params)
    result = fit_ppo(objective, total_timesteps=64, n_envs=8, seed=0, settings=PPOSettings(episode_runs=1))
    assert result.extra["episode_runs"] == 1
    assert result.cost == pytest.approx(objective(result.params.as_vector()), rel=1e-9)
    assert result.initial_cost == pytest.approx(objective(objective.params.as_vector()), rel=1e-9)
    assert result.cost < result.initial_cost


def test_fit_ppo_leaves_no_log_folder_behind(tiny_objective: Objective, tmp_path, monkeypatch) -> None:
    """stable-baselines3's default logger makes an ``SB3-<date>`` folder in the temporary
    directory on every fit (dozens of empty folders after a test run); ``fit_ppo`` logs nowhere."""
    import tempfile

    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    fit_ppo(tiny_objective, total_timesteps=64, n_envs=1, seed=3)
    assert list(tmp_path.glob("SB3-*")) == []


def test_fit_ppo_same_seed_same_result(tiny_objective: Objective) -> None:
    first, second = (fit_ppo(tiny_objective, total_timesteps=64, n_envs=1, seed=3) for _ in range(2))
    np.testing.assert_array_equal(first.params.as_vector(), second.params.as_vector())
    assert first.extra["reward_curve"] == second.extra["reward_curve"]


def test_fit_ppo_stops_on_budget(tiny_objective: Objective) -> None:
    result = fit_ppo(tiny_objective, budget_seconds=0.0, total_timesteps=10_000, n_envs=1)
    assert result.status is FitStatus.BUDGET
    assert result.extra["timesteps"] < 10_000 and len(result.extra["reward_curve"]) == 1


@pytest.mark.slow
def test_ppo_recovers_friction_and_damping() -> None:
    """Two 3 s runs from known parameters, a guess 40 % off: PPO closes >= 80 % of the final
    head error gap on a held-out run (another gait frequency and heading)."""
    truth = _truth()
    runs = [simulate_gait(SidewindingGait(0.5), 3.0, params=truth, sample_rate_hz=50, heading_rad=h)
            for h in (0.0, 1.0)]
    held_out = simulate_gait(SidewindingGait(0.65), 3.0, params=truth, sample_rate_hz=50, heading_rad=2.5)
    guess = truth.with_values(mu_c=0.42, joint_damping=0.14)
    result = fit_ppo(Objective(runs, guess), total_timesteps=512, seed=0)

    def final_head_error(params: ModelParameters) -> float:
        """Through the single-environment simulator, independently of the objective's batch."""
        sim = simulate_like(held_out, params=params)
        return float(np.linalg.norm(sim.head_pos[-1, :2] - held_out.head_pos[-1, :2]))

    before, after = final_head_error(guess), final_head_error(result.params)
    assert after <= 0.2 * before, (before, after, result.params)
