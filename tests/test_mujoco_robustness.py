"""The MuJoCo robustness benchmark's cases: each adds one effect to MuJoCo's robot and states it
once, in our model's terms (no run recorded, no diagnosis)."""
from __future__ import annotations

import dataclasses
import sys
from pathlib import Path

import pytest

from benchmarks._robot import with_error

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "benchmarks"))

from mujoco_robustness import CASES, CONTACTS, at_mujoco_values  # noqa: E402
from sysid.discrepancy.effects import EffectLibrary  # noqa: E402
from sysid.generators.mujoco_recording import EFFECT_OPTIONS, STIFF_SOLREF_S, counterpart_under  # noqa: E402

ROBOT = with_error()


@pytest.mark.parametrize("contact", list(CONTACTS))
def test_each_case_changes_mujocos_robot_by_its_effect_alone(contact):
    """A case's twin differs from the no-effect twin only in its effect's option, at the value
    the case gives its effect; the armature case only in armature and damping, by its amounts."""
    base = CASES["none"].twin(ROBOT, CONTACTS[contact])
    assert base.solref[0] == (STIFF_SOLREF_S if contact == "stiff" else 0.02)
    for name, case in CASES.items():
        twin = case.twin(ROBOT, CONTACTS[contact])
        changed = {f.name for f in dataclasses.fields(twin) if getattr(twin, f.name) != getattr(base, f.name)}
        if case.effects:
            (effect, value), = case.effects.items()
            assert changed == {EFFECT_OPTIONS[effect]} and getattr(twin, EFFECT_OPTIONS[effect]) == value, name
        elif case.raised:
            assert changed == {"armature", "damping"}
            assert twin.armature == pytest.approx(base.armature + 0.03)
            assert twin.damping == pytest.approx(base.damping + 0.2)
        else:
            assert changed == set()


def test_counterparts_are_the_effects_own_parameters_at_mujocos_values():
    library = EffectLibrary()
    for name, case in CASES.items():
        expected = {library[e].parameter.name: v for e, v in case.effects.items()}
        assert case.counterparts() == expected, name
    assert CASES["anisotropic_friction"].counterparts() == {"lateral_friction_ratio": 2.0}
    assert CASES["forcerange"].counterparts() == {"torque_limit": 2.0}
    assert CASES["none"].counterparts() == CASES["armature_damping"].counterparts() == {}


@pytest.mark.parametrize("law", ["compliant", "soft_constraint"])
def test_floors_use_mujocos_values_with_the_case_in_our_terms(law):
    """``--floors`` reproduces a case with our model at MuJoCo's values plus the case's effect
    (or raised parameters): nothing else differs from the no-effect counterpart."""
    base = CASES["none"].twin(ROBOT, CONTACTS["default"])
    plain = counterpart_under(ROBOT, base, law)
    assert at_mujoco_values("none", ROBOT, base, law) == plain
    payload = at_mujoco_values("payload", ROBOT, base, law)
    assert payload.value("link_mass_error") == 0.8
    assert all(payload.value(n) == plain.value(n) for n in plain.names if n != "link_mass_error")
    raised = at_mujoco_values("armature_damping", ROBOT, base, law)
    assert raised.value("armature") == pytest.approx(plain.value("armature") + 0.03)
    assert raised.value("joint_damping") == pytest.approx(plain.value("joint_damping") + 0.2)
