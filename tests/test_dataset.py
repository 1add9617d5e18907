"""The shipped reference dataset is exactly what its generator makes, and is shaped like the paper's."""
from __future__ import annotations

import json

import numpy as np
import pytest

from cobra_model import CobraModel
from cobra_model.errors import InputError
from cobra_model.run_files import read_run
from cobra_model.servo import AMP_PER_CURRENT_UNIT, CURRENT_NOISE_A
from sysid.generators.dataset import DATA_DIR, RunPlan, generate, load_manifest, measure


@pytest.mark.slow
def test_shipped_files_match_the_generator(tmp_path):
    generate(tmp_path)
    # the folder is also the package sysid.reference: its __init__.py is not the generator's
    shipped = sorted(p.name for p in DATA_DIR.iterdir() if p.suffix in (".csv", ".json"))
    assert shipped == sorted(p.name for p in tmp_path.iterdir())
    for name in shipped:
        assert (tmp_path / name).read_bytes() == (DATA_DIR / name).read_bytes(), name


def test_dataset_shape():
    train, validation = load_manifest(DATA_DIR / "manifest.json")
    assert len(train) + len(validation) == 25
    freqs = {}
    for path in train + validation:
        run = read_run(path)
        f = run.meta["gait"]["frequency_hz"]
        freqs.setdefault(f, []).append(path in validation)
        assert run.duration >= 3.0 / f                         # at least three gait cycles
        q_step = np.diff(np.unique(np.round(run.q[:, 5] / (2 * np.pi / 4096), 6)))
        assert np.allclose(q_step, np.round(q_step))          # encoder quantised to 4096 counts
    assert sorted(freqs) == [0.35, 0.5, 0.65]
    assert all(sum(v) == 1 for v in freqs.values())            # one held-out run per gait
    total_dropout = np.mean([np.isnan(read_run(p).head_pos[:, 0]).mean() for p in train])
    assert 0.001 < total_dropout < 0.1
    size = sum(p.stat().st_size for p in DATA_DIR.iterdir() if p.is_file())
    assert size < 6e6
    assert json.loads((DATA_DIR / "manifest.json").read_text())["format"] == "cobra-dataset/1"


def test_logged_currents_have_present_currents_noise_and_resolution():
    """``measure(current=...)``: the currents on the joint log's times, with a Present Current
    reading's noise and resolution; every other column and draw is what it is without them."""
    model = CobraModel.load()
    plan = RunPlan("c", 0.5, 4.0, (0.0, 0.0), 0.0, "train")
    t = np.arange(0, 4.0 + 1e-9, 2e-3)
    q = np.tile(model.configuration(), (len(t), 1))
    truth = np.tile(0.3 * np.sin(2 * np.pi * 0.5 * t)[:, None], (1, model.n_joints))
    plain = measure(t, q, q[:, 7:], plan, np.random.default_rng(3), model)
    logged = measure(t, q, q[:, 7:], plan, np.random.default_rng(3), model, current=truth)
    assert plain.current is None and logged.current.shape == (plain.n_samples, model.n_joints)
    assert np.array_equal(plain.t, logged.t) and np.array_equal(plain.q, logged.q)
    assert np.array_equal(plain.head_pos, logged.head_pos, equal_nan=True)
    units = logged.current / AMP_PER_CURRENT_UNIT
    assert np.allclose(units, np.round(units), atol=1e-9)
    error = logged.current - 0.3 * np.sin(2 * np.pi * 0.5 * logged.t)[:, None]
    # 550 samples x 11 joints: the noise's RMS within 5 % of CURRENT_NOISE_A (rounding adds 0.8 mA RMS)
    assert np.sqrt(np.mean(error ** 2)) == pytest.approx(np.hypot(CURRENT_NOISE_A, AMP_PER_CURRENT_UNIT / np.sqrt(12)),
                                                         rel=0.05)
    assert abs(np.mean(error)) < 3 * CURRENT_NOISE_A / np.sqrt(error.size)
    with pytest.raises(InputError, match="current must be"):
        measure(t, q, q[:, 7:], plan, np.random.default_rng(3), model, current=truth[:, :3])
