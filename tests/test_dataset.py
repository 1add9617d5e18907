"""The shipped reference dataset is exactly what its generator makes, and is shaped like the paper's."""
from __future__ import annotations

import json

import numpy as np
import pytest

from cobra_model.run_files import read_run
from sysid.generators.dataset import DATA_DIR, generate, load_manifest


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
