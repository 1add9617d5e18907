"""Discrepancy workflow on runs MuJoCo generated: MuJoCo effect vs named effect, gap before/after, wall time.

Mirrors ``benchmarks/diagnose_accuracy.py``, but the "measured" runs come from MuJoCo's twin of
the same URDF (:mod:`sysid.generators.mujoco_recording`: another contact model, integrator and servo model),
with the same parameter error (``PARAMETER_ERROR``) and one physical effect added in MuJoCo per case:

| case | MuJoCo effect | closest effect of our library |
|---|---|---|
| none | - | none |
| frictionloss | joint ``frictionloss`` 0.3 N m | joint_coulomb_friction |
| armature_damping | joint ``armature`` +0.03 kg m^2, ``damping`` +0.2 N m s/rad | none (parameters) |
| forcerange | actuator ``forcerange`` 2 N m (peak demand 3.5-4 N m on the pitch joints) | torque_saturation |
| anisotropic_friction | sideways / along-body ground friction 2 (body-aligned capsule pairs) | anisotropic_ground_friction |
| command_delay | commands reach the servos 40 ms late (a buffer on the bus) | actuator_delay |
| encoder_offset | every encoder reads 0.03 rad more than its joint (the loop holds the reading) | encoder_offset |
| payload | 0.8 kg more on the head body (inertia scaled with its mass) | link_mass_error |

Per case: 9 runs (3 per gait frequency 0.35/0.5/0.65 Hz, ``--duration`` s each, random start),
the first 6 for training and the last 3 held out; ``diagnose`` starts from the nominal model with
``FREE`` parameters free: the actuator parameters the robot's error is in and every ground
parameter, the ground's shape (``friction_cone``, ``contact_rounding``) included, because
MuJoCo's contact (soft constraints, a friction cone, capsule ends) is another model than ours
and only the fitted ground can stand in for it. Per case the table gives the effect(s) named,
the structural differences reported instead of a proxy (``sysid.discrepancy.diagnose.choose``), the best
candidate of round 1, the held-out gap, and, when the effect MuJoCo added is named, whether
the 95 % interval of its parameter holds MuJoCo's value (:meth:`Case.counterparts`:
frictionloss -> joint_coulomb, forcerange -> torque_limit, and the anisotropy, delay, offset and
payload to their own parameters). Written to ``benchmarks/results/mujoco_robustness.{json,md}``; progress to stderr.
Seeds 3 and 11 were used while developing (``DEV_SEEDS``; 11, reported until 6b31db5, is the
seed the drives' check of ``sysid.discrepancy.diagnose.effect_share`` was found on); the
default reports seed 12.

``--effect-sizes`` diagnoses nothing: it prints, per case, how much the MuJoCo effect changes
the runs (each case's runs against the no-effect runs, same starts and noise) beside how much
our simulator differs from MuJoCo with no effect, both at the true parameters (mean joint RMSE
[rad] and final head distance [m] over the 9 runs). An effect smaller than that structural
difference is hard to tell from it.

``--contact stiff`` runs the same cases on MuJoCo's contact near its rigid limit (2 ms time
constant instead of 20 ms, :func:`sysid.generators.mujoco_recording.stiff_contact`), the configuration on which
our ground can follow MuJoCo's (``benchmarks/contact_time_constant.py``); results then go to
``mujoco_robustness_stiff.{json,md}``.

``--current`` logs the motor currents in the same runs (every other draw is unchanged: the
current's noise has its own generator), as a Dynamixel's Present Current: the drive torque over
``r Km``, with 20 mA of noise and 2.69 mA resolution. The diagnosis then fits them as a third
channel (``DiagnoseConfig.use_current``); results go to ``*_current.{json,md}``.

``--contact-law soft_constraint`` (or another of ``cobra_model.parameters.CONTACT_LAWS``)
diagnoses under that law of our ground instead of the compliant one, with the law's own ground
parameters freed and those it does not read frozen, as ``cobra diagnose --contact`` does (the
law that ``cobra fit --contact choose`` keeps on MuJoCo's runs, ``mujoco_fit_residual.md``);
results then go to ``..._<law>.{json,md}``.

``--floors`` diagnoses nothing either: per case and seed it reproduces the runs with our
simulator at MuJoCo's own values (:func:`sysid.generators.mujoco_recording.counterpart_under`:
under ``--contact-law``, a soft law at MuJoCo's contact time constant) and the case's effect at its MuJoCo
value in our library's form (:class:`Case`), and reports the held-out final head
error and joint RMSE that leaves: what a diagnosis that named the effect and found every value
could reach with our model's structure, to read its "after" figures against. Results go to
``..._floors.{json,md}``.

Run: ``.venv/bin/python benchmarks/mujoco_robustness.py [--cases none,frictionloss] [--seeds 12]
[--duration 6] [--contact stiff] [--contact-law soft_constraint] [--current] [--effect-sizes]
[--floors]``.
"""
from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from typing import Callable

import numpy as np

from _results import runs_fingerprint, write_results
from _args import number_list
from _robot import PARAMETER_ERROR, with_error

from cobra_model import CobraModel, ModelParameters
from cobra_model.parameters import CONTACT_LAWS
from cobra_model.run import Run
from integrators.mujoco_twin import TwinOptions
from integrators.simulate import simulate_like
from integrators.simulator import SimSettings, contact_resolved
from sysid.discrepancy.diagnose import Diagnosis
from sysid.generators.dataset import RunPlan
from sysid.discrepancy.diagnose import DiagnoseConfig, diagnose
from sysid.discrepancy.effects import EffectLibrary
from sysid.gap.metrics import compare_runs
from sysid.identification.contact_choice import nominal_start
from sysid.generators.mujoco_recording import (counterpart_under, record_mujoco, stiff_contact, twin_options,
                                               with_effects)

DEV_SEEDS = (3, 11)
EVAL_SEEDS = (12,)
#: MuJoCo's contacts the benchmark runs on (``--contact``): what each makes of the twin's options.
CONTACTS: dict[str, Callable[[TwinOptions], TwinOptions]] = {"default": lambda options: options,
                                                             "stiff": stiff_contact}
FREE = ["joint_damping", "motor_km", "k1", "k2", "mu_c", "mu_s", "mu_v", "v_s", "friction_cone", "contact_rounding"]


@dataclasses.dataclass(frozen=True)
class Case:
    """What one case adds to the robot MuJoCo runs, in our model's terms.

    Attributes:
        label: the table's name for it.
        effects: effects of our library (name -> value in its parameter's unit), added on
            MuJoCo's side by their twin options at the same value
            (:data:`sysid.generators.mujoco_recording.EFFECT_OPTIONS`).
        raised: parameters of ours (name -> amount added, their unit) that the twin takes from
            the robot (:func:`sysid.generators.mujoco_recording.twin_options`).
    """
    label: str
    effects: dict[str, float] = dataclasses.field(default_factory=dict)
    raised: dict[str, float] = dataclasses.field(default_factory=dict)

    def robot(self, truth: ModelParameters) -> ModelParameters:
        """``truth`` with the raised parameters (the effects are not parameters of the twin's robot)."""
        return truth.with_values(**{n: truth.value(n) + dv for n, dv in self.raised.items()})

    def twin(self, truth: ModelParameters, contact: Callable[[TwinOptions], TwinOptions]) -> TwinOptions:
        """MuJoCo's twin of the robot ``truth`` with this case, on the contact ``contact`` makes of the twin's."""
        return with_effects(contact(twin_options(self.robot(truth))), self.effects)

    def counterparts(self) -> dict[str, float]:
        """Parameter of ours -> MuJoCo's value, for each effect (the effect's own parameter)."""
        library = EffectLibrary()
        return {library[name].parameter.name: value for name, value in self.effects.items()}


#: The cases, one MuJoCo effect each (see the module doc).
CASES = {
    "none": Case("none"),
    "frictionloss": Case("frictionloss 0.3 N m", {"joint_coulomb_friction": 0.3}),
    "armature_damping": Case("armature +0.03 kg m^2, damping +0.2 N m s/rad",
                             raised={"armature": 0.03, "joint_damping": 0.2}),
    "forcerange": Case("forcerange 2 N m", {"torque_saturation": 2.0}),
    "anisotropic_friction": Case("lateral/along ground friction 2", {"anisotropic_ground_friction": 2.0}),
    "command_delay": Case("commands delayed 0.04 s", {"actuator_delay": 0.04}),
    "encoder_offset": Case("encoder offset 0.03 rad", {"encoder_offset": 0.03}),
    "payload": Case("head payload 0.8 kg", {"link_mass_error": 0.8}),
}


def make_data(options: TwinOptions, truth: ModelParameters, duration_s: float, model: CobraModel,
              progress: Callable[[str], None], seed: int = 3, log_current: bool = False
              ) -> tuple[list[Run], list[Run]]:
    """9 MuJoCo runs of ``duration_s`` [s] (3 per gait): the first 6 to train, the last 3 held
    out; with ``log_current`` the same runs with their motor currents logged too."""
    rng = np.random.default_rng(seed)
    plans = [RunPlan(f"r{i}", f, duration_s, (rng.uniform(-1, 1), rng.uniform(-1, 1)), rng.uniform(0, 2 * np.pi),
                     "train") for i, f in enumerate((0.35, 0.5, 0.65) * 3)]
    runs = []
    for k, plan in enumerate(plans):
        progress(f"recording run {k + 1}/{len(plans)} ({plan.freq_hz} Hz, {duration_s:g} s) in MuJoCo")
        runs.append(record_mujoco(plan, options, rng, model, truth, log_current=log_current))
    return runs[:6], runs[6:]


def differences(a: list[Run], b: list[Run]) -> tuple[float, float]:
    """Mean over run pairs of the joint RMSE [rad] and the final head distance [m] between ``a`` and ``b``."""
    gaps = [compare_runs(x, y) for x, y in zip(a, b)]
    return float(np.mean([g.mean_joint_rmse for g in gaps])), float(np.mean([g.head.final for g in gaps]))


def effect_sizes(chosen: list[str], base: TwinOptions, contact: Callable[[TwinOptions], TwinOptions],
                 truth: ModelParameters, duration_s: float, model: CobraModel) -> None:
    """Print each case's effect size beside our simulator's difference from MuJoCo (see the module doc)."""
    progress = lambda msg: print(f"[sizes] {msg}", file=sys.stderr, flush=True)  # noqa: E731
    plain = sum(make_data(base, truth, duration_s, model, progress), [])
    ours = differences(plain, [simulate_like(r, params=truth) for r in plain])
    print("| MuJoCo effect | effect: joint RMSE [rad] | effect: final head [m] | our simulator vs MuJoCo "
          "without it: joint RMSE [rad] | ... final head [m] |")
    print("|---|---:|---:|---:|---:|", flush=True)
    for case in chosen:
        options = CASES[case].twin(truth, contact)
        runs = plain if options == base else sum(make_data(options, truth, duration_s, model, progress), [])
        q, head = differences(runs, plain)
        print(f"| {CASES[case].label} | {q:.4f} | {head:.4f} | {ours[0]:.4f} | {ours[1]:.4f} |", flush=True)


def at_mujoco_values(case: str, truth: ModelParameters, base: TwinOptions, law: str) -> ModelParameters:
    """Our parameters at MuJoCo's values under ``law`` (the soft laws at MuJoCo's ``solref``
    time constant) with ``case``'s effect in our terms (:class:`Case`)."""
    c = CASES[case]
    params = c.robot(counterpart_under(truth, base, law))
    return EffectLibrary().transform(params, c.effects) if c.effects else params


def floors(chosen: list[str], base: TwinOptions, contact: Callable[[TwinOptions], TwinOptions],
           truth: ModelParameters, args: argparse.Namespace, seeds: list[int], model: CobraModel) -> list[dict]:
    """Per case and seed: the gap our simulator leaves at MuJoCo's values (see the module doc),
    on the held-out and the training runs, each run's and their means (the diagnosis's measure)."""
    rows = []
    for seed in seeds:
        for case in chosen:
            progress = lambda msg, case=case, seed=seed: print(  # noqa: E731
                f"[floors {case} seed {seed}] {msg}", file=sys.stderr, flush=True)
            train, hold = make_data(CASES[case].twin(truth, contact), truth, args.duration, model, progress,
                                    seed=seed)
            params = at_mujoco_values(case, truth, base, args.contact_law)
            settings = contact_resolved(SimSettings(), params)
            progress(f"reproducing {len(train) + len(hold)} runs at MuJoCo's values")
            row = {"case": case, "label": CASES[case].label, "seed": seed, "dt_s": settings.dt}
            for part, runs in (("held_out", hold), ("train", train)):
                gaps = [compare_runs(r, simulate_like(r, params=params, settings=settings, model=model)) for r in runs]
                row[f"{part}_head_final_m"] = [g.head.final for g in gaps]
                row[f"{part}_joint_rmse_rad"] = [g.mean_joint_rmse for g in gaps]
            rows.append(row)
    return rows


def floors_markdown(rows: list[dict], law: str) -> str:
    """The ``--floors`` table."""
    lines = [f"Our simulator ({law} law) at MuJoCo's values with each case's effect at its MuJoCo value, "
             "against MuJoCo's runs: the gap a diagnosis that found every value would leave.", "",
             "| MuJoCo effect | seed | held-out final head [m]: mean (per run) | held-out joint RMSE [rad]: mean | "
             "training final head [m]: mean | training joint RMSE [rad]: mean |",
             "|---|---:|---|---:|---:|---:|"]
    for r in rows:
        per_run = ", ".join(f"{h:.4f}" for h in r["held_out_head_final_m"])
        lines.append(f"| {r['label']} | {r['seed']} | {np.mean(r['held_out_head_final_m']):.4f} ({per_run}) | "
                     f"{np.mean(r['held_out_joint_rmse_rad']):.4f} | {np.mean(r['train_head_final_m']):.4f} | "
                     f"{np.mean(r['train_joint_rmse_rad']):.4f} |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    truth = with_error()
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", default=",".join(CASES),
                        help=f"comma-separated subset of {', '.join(CASES)} (default: all)")
    parser.add_argument("--duration", type=float, default=6.0, help="run length [s] (default 6)")
    parser.add_argument("--seeds", default=",".join(map(str, EVAL_SEEDS)),
                        help=f"data seeds (default {','.join(map(str, EVAL_SEEDS))}; {DEV_SEEDS} was used "
                             "while developing)")
    parser.add_argument("--contact", choices=list(CONTACTS), default="default",
                        help="MuJoCo's contact: its default soft one (solref 20 ms; results mujoco_robustness.*) "
                             "or near rigid (2 ms, sysid.generators.mujoco_recording.stiff_contact; mujoco_robustness_stiff.*)")
    parser.add_argument("--contact-law", choices=CONTACT_LAWS, default="compliant",
                        help="our ground's contact law in the diagnosis (default compliant; another writes "
                             "..._<law>.*), its own ground parameters freed as `cobra diagnose --contact` does")
    parser.add_argument("--current", action="store_true",
                        help="log the motor currents in MuJoCo's runs (drive torque / r Km, with a Present Current's "
                             "noise and resolution); the diagnosis then fits them too (results *_current.*)")
    parser.add_argument("--effect-sizes", action="store_true",
                        help="print each effect's size beside our simulator's difference from MuJoCo; no diagnosis")
    parser.add_argument("--floors", action="store_true",
                        help="our simulator at MuJoCo's values with each case's effect: the held-out gap it leaves "
                             "(results ..._floors.*); no diagnosis")
    args = parser.parse_args(argv)
    chosen = [c.strip() for c in args.cases.split(",") if c.strip()]
    unknown = [c for c in chosen if c not in CASES]
    if unknown or not chosen:
        parser.error(f"--cases: unknown case(s) {unknown or chosen}; choose from {', '.join(CASES)}")
    if not args.duration > 1.0:
        parser.error(f"--duration must exceed the gait's 1 s smooth start, got {args.duration} s")
    seeds = number_list(parser, "--seeds", args.seeds)
    if any(x in DEV_SEEDS for x in seeds):
        print(f"note: seed(s) {sorted(set(seeds) & set(DEV_SEEDS))} were used while developing", file=sys.stderr)
    contact = CONTACTS[args.contact]
    base = CASES["none"].twin(truth, contact)
    name = ("mujoco_robustness" if args.contact == "default" else "mujoco_robustness_stiff") \
        + ("" if args.contact_law == "compliant" else f"_{args.contact_law}") + ("_current" if args.current else "")
    model = CobraModel.load()
    if args.effect_sizes:
        effect_sizes(chosen, base, contact, truth, args.duration, model)
        return 0
    if args.floors:
        rows = floors(chosen, base, contact, truth, args, seeds, model)
        write_results(name + "_floors", rows, meta(args, seeds, chosen, base), floors_markdown(rows, args.contact_law))
        print(floors_markdown(rows, args.contact_law))
        return 0
    start = nominal_start(args.contact_law, FREE)
    rows: list[dict] = []
    for seed in seeds:
        for case in chosen:
            t_case = time.perf_counter()
            progress = lambda msg, case=case, t_case=t_case, seed=seed: print(  # noqa: E731
                f"[{case} seed {seed} {time.perf_counter() - t_case:5.0f} s] {msg}", file=sys.stderr, flush=True)
            train, hold = make_data(CASES[case].twin(truth, contact), truth, args.duration, model, progress,
                                    seed=seed, log_current=args.current)
            t0 = time.perf_counter()
            d = diagnose(train, hold, params=start, config=DiagnoseConfig(max_effects=2), progress=progress)
            rows.append(row(case, seed, d, time.perf_counter() - t0, runs_fingerprint(train + hold)))
            write_results(name, rows, meta(args, seeds, chosen, base), markdown(rows))
    print(markdown(rows))
    return 0


def row(case: str, seed: int, d: Diagnosis, wall_s: float, data: str) -> dict:
    """One table row of a diagnosis (see the module docstring); ``effects`` holds every named effect
    as in ``diagnosis.json`` (fitted value, 95 % interval, evidence), ``round1`` the best three
    candidates of round 1, ``data_sha256`` the fingerprint ``data`` of the MuJoCo runs diagnosed
    (:func:`_results.runs_fingerprint`)."""
    out = {"case": case, "label": CASES[case].label, "seed": seed, "data_sha256": data,
           "named": [e.name for e in d.effects],
           "effects": [e.to_json() for e in d.effects], "structural": [s.to_json() for s in d.structural],
           "verdict": d.verdict, "wall_s": wall_s,
           "head_final_before_m": d.gap_before.head_final_error_m,
           "head_final_after_m": d.gap_after.head_final_error_m,
           "joint_rmse_before_rad": d.gap_before.joint_rmse_rad,
           "joint_rmse_after_rad": d.gap_after.joint_rmse_rad,
           "round1": [c.to_json() for c in d.rounds[0][:3]] if d.rounds else [],
           "counterpart": None}
    mujoco_values = CASES[case].counterparts()
    for e in d.effects:
        if e.parameter in mujoco_values:
            true = mujoco_values[e.parameter]
            lo, hi = e.ci95 or (np.nan, np.nan)
            out["counterpart"] = {"parameter": e.parameter, "mujoco": true, "value": e.value, "ci95": [lo, hi],
                                  "holds": bool(lo <= true <= hi)}
    return out


def markdown(rows: list[dict]) -> str:
    """The results table."""
    lines = ["| MuJoCo effect | seed | named | structural (not named) | best candidate, round 1 | "
             "held-out final head [m] | joint RMSE [rad] | counterpart's 95 % interval | wall [s] |",
             "|---|---:|---|---|---|---|---|---|---:|"]
    for r in rows:
        structural = "; ".join(f"{s['name']} {s['value']:.3g} {s['unit']}" for s in r["structural"]) or "-"
        best = r["round1"][0] if r["round1"] else None
        best_text = (f"{best['name']} {best['value']:.3g} {best['unit']} (held-out cost "
                     f"{-100 * best['held_out_improvement']:+.0f} %)" if best else "-")
        c = r["counterpart"]
        c_text = (f"{c['parameter']} {c['value']:.3g} [{c['ci95'][0]:.3g}, {c['ci95'][1]:.3g}] "
                  f"{'holds' if c['holds'] else 'misses'} {c['mujoco']:g}" if c else "-")
        lines.append(f"| {r['label']} | {r['seed']} | {', '.join(r['named']) or 'none'} | {structural} | {best_text} | "
                     f"{r['head_final_before_m']:.4f} -> {r['head_final_after_m']:.4f} | "
                     f"{r['joint_rmse_before_rad']:.4f} -> {r['joint_rmse_after_rad']:.4f} | {c_text} | "
                     f"{r['wall_s']:.0f} |")
    if any("data_sha256" in r for r in rows):
        lines += ["", "The MuJoCo runs each row diagnosed, by fingerprint (`_results.runs_fingerprint`; the same on "
                  "two machines when they generated the same data): "
                  + ", ".join(f"{r['case']} seed {r['seed']} `{r.get('data_sha256', '-')}`" for r in rows) + "."]
    return "\n".join(lines) + "\n"


def meta(args: argparse.Namespace, seeds: list[int], chosen: list[str], base: TwinOptions) -> dict:
    """What was run."""
    return {"cases": chosen, "seeds": seeds, "dev_seeds": list(DEV_SEEDS), "duration_s": args.duration,
            "contact": args.contact, "contact_law": args.contact_law, "motor_currents": args.current,
            "truth": PARAMETER_ERROR, "free": FREE, "twin": dataclasses.asdict(base),
            "library": list(EffectLibrary().names)}


if __name__ == "__main__":
    raise SystemExit(main())
