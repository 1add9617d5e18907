"""What ``cobra diagnose`` writes into its output folder: ``augmented_params.json`` (the model
with the effects named), ``diagnosis.json`` and ``report.html`` with its figures."""
from __future__ import annotations

import json
from pathlib import Path

from sysid.discrepancy.diagnose import Diagnosis
from sysid.gap.report import HtmlReport, held_out_figures
from sysid.identification.datacheck import DataCheck

#: The files :func:`write_diagnosis` writes (besides the report's figures).
OUTPUTS = ("report.html", "diagnosis.json", "augmented_params.json")


def write_diagnosis(result: Diagnosis, out: Path, data_check: DataCheck | None = None) -> dict:
    """Write :data:`OUTPUTS` into ``out`` (created if missing, files overwritten: the caller
    checks first) and return ``diagnosis.json``'s content."""
    out.mkdir(parents=True, exist_ok=True)
    result.params_after.save(out / "augmented_params.json", force=True)
    doc = result.to_json()
    doc["augmented_params"] = str(out / "augmented_params.json")
    doc["data_check"] = data_check.to_json_dict() if data_check is not None else None
    (out / "diagnosis.json").write_text(json.dumps(doc, indent=2, default=float) + "\n")
    write_diagnosis_report(result, out)
    return doc


def write_diagnosis_report(result: Diagnosis, out: Path) -> Path:
    """``out/report.html``: the verdict, the residual signature before and after, every round's
    candidates with their evidence, the augmented model and the held-out figures."""
    from sysid.gap import plots

    page = HtmlReport("cobra diagnose")
    page.heading("Verdict")
    page.paragraph(result.verdict)
    page.heading("Where the fitted model disagrees (held-out and training residuals)")
    page.paragraph(result.signature.summary())
    page.figure(plots.plot_signature([("before", result.signature), ("after", result.signature_after)],
                                     out / "signature.png", title="residual signature before and after"),
                "residual signature before and after")
    for i, round_ in enumerate(result.rounds, start=1):
        page.heading(f"Candidates, round {i}")
        page.table(["effect", "fitted value", "unit", "held-out cost reduction", "held-out runs improved", "dBIC",
                    "signature match", "refitted without it", "share its effect carries",
                    "drives' channels' cost with / without it", "physical value",
                    "resolved from none",
                    "evidence from"],
                   [[c.name, c.value, c.unit, c.held_out_improvement, c.runs_improved, c.delta_bic, c.signature_match,
                     "yes" if c.refit_without else "no", "-" if c.effect_share is None else c.effect_share,
                     "-" if c.drives_ratio is None else c.drives_ratio,
                     c.implausible or "yes", c.unresolved or "yes",
                     "whole runs (second look)" if c.whole_runs else "screening"]
                    for c in round_])
        page.paragraph("Evidence is against the best fit without a new effect: the current model refitted "
                       "alone, or a checked candidate's model refitted without its effect. The share its effect "
                       "carries: how much of the held-out cost comes back when the effect is switched off at the "
                       "candidate's own parameters (a checked candidate is named only if it is at least the "
                       "required reduction); an effect at the joints' drives (friction, backlash, delay, torque "
                       "limit, encoder offset) whose joints (and currents) fit the held-out runs worse with it than "
                       "without it is a proxy: it can move the head path only through them. A second look: when "
                       "no screened candidate passes, the one the training runs support most is refitted on the "
                       "whole runs, as naming it would, and judged there.")
    page.heading("Augmented model")
    fit = result.fits[-1]
    if fit.residual_whiteness is not None:
        page.paragraph(f"Residuals: {fit.residual_whiteness.verdict}")
    page.table(["name", "unit", "value", "95% low", "95% high", "note"],
               [[r.name, r.unit, r.value, r.ci_low, r.ci_high, r.reason] for r in fit.report])
    held_out_figures(result.held, out, ("fitted, no effect", "with effect"), page)
    return page.write(out / "report.html")
