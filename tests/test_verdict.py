"""The diagnosis's verdict in words (``sysid.discrepancy.diagnose.verdict``)."""
from __future__ import annotations

import pytest

from sysid.discrepancy.diagnose import HEAD_GROWTH_FLOOR_M, Diagnosis, NamedEffect, head_grew, verdict
from sysid.gap.report import GapSummary

OFFSET = NamedEffect("encoder_offset", "encoder_offset", 0.0378, "rad", (0.0365, 0.0392), 0.58, 3, -900.0, 0.7,
                     "a constant joint residual")


def gap(head_m: float | None, joints_rad: float) -> GapSummary:
    return GapSummary(head_m, head_m, joints_rad, {})


def named(before: GapSummary, after: GapSummary) -> Diagnosis:
    return Diagnosis(effects=[OFFSET], gap_before=before, gap_after=after)


def test_a_head_that_grows_while_the_named_effect_explains_the_joints_is_said_to():
    """MuJoCo's encoder offset diagnosed under the compliant law (``mujoco_robustness.md``,
    2026-12-04): the joints 17.3 -> 6.7 mrad, the held-out head 18.0 -> 36.1 mm, up to the law's
    floor on MuJoCo's nulls. The verdict names the offset and says the head path's gap is not its."""
    text = verdict(named(gap(0.0180, 0.0173), gap(0.0361, 0.0067)))
    assert text.startswith("missing effect: encoder_offset; held-out final head error 0.0180 -> 0.0361 m")
    assert "the head's error grew while the joints' RMSE went 0.0173 -> 0.0067 rad" in text
    assert "ground contact" in text


@pytest.mark.parametrize("before, after", [
    (0.1166, 0.0038),                                 # the same offset under the soft-constraint law: closed
    (0.0300, 0.0300 + 0.9 * HEAD_GROWTH_FLOOR_M),     # within the motion capture's noise
    (0.0500, 0.0540),                                 # 8 %: within a tenth
    (None, None),                                     # joint-only runs
])
def test_a_head_that_shrinks_or_moves_within_noise_is_not_said_to_grow(before, after):
    d = named(gap(before, 0.0173), gap(after, 0.0067))
    assert not head_grew(d.gap_before, d.gap_after)
    assert "grew" not in verdict(d)
