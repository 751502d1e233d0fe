"""The verdicts on the study's planned hypotheses (docs/study-plan.md, written before its runs),
computed from the study's cells and regimes, so the page never states one by hand. A hypothesis
whose cells are not all run yet is "open" unless the cells run already decide it.
"""

from __future__ import annotations

from nerfaug.report.document import Block, Heading, Paragraph, Table, p_value
from nerfaug.report.study import OURS, Study

PAPER_REGIME = "nerfacto-cpu-last-sample"
STABLE_REGIMES = ("cpu", "nerfacto-cpu")
PLAN_SCENES = ("lego", "chair", "materials")


def _cells(study: Study, engine: str):
    return {c.scene: c for c in study.cells if c.engine == engine and c.scene in PLAN_SCENES}


def h1(study: Study) -> tuple[str, str]:
    """Ours beats uniform (per-cell paired test) on at least two of the three scenes, paper's regime."""
    cells = _cells(study, PAPER_REGIME)
    wins = [s for s, c in cells.items() if OURS in c.significant(True)]
    complete = [s for s, c in cells.items() if c.complete]
    evidence = (
        f"ours significantly better than uniform on {len(wins)} of {len(complete)} complete scene(s)"
        + (f" ({', '.join(wins)})" if wins else "")
        + "; per scene, ours - uniform (median paired PSNR, p x k): "
        + (
            "; ".join(
                f"{s}: {e['difference']:+.2f} dB, {p_value(e['p_bonferroni'])}"
                for s, c in cells.items()
                if (e := c.methods.get(OURS) and c.methods[OURS].vs_reference.get("psnr"))
            )
            or "none"
        )
    )
    if len(wins) >= 2:
        return "supported", evidence
    undecided = len(PLAN_SCENES) - len(complete)
    return ("open" if len(wins) + undecided >= 2 else "not supported"), evidence


def h2(study: Study) -> tuple[str, str]:
    """FisherRF worse than uniform in the paper's regime (seed-level), not worse on cpu."""
    paper, stable = study.regimes.get(PAPER_REGIME, {}).get("fisherrf"), study.regimes.get("cpu", {}).get("fisherrf")

    def says(entry) -> str:
        if entry is None:
            return "not run"
        return (
            f"{entry['difference']:+.2f} dB over {entry['n_cells']} scene(s), p x k = {p_value(entry['p_bonferroni'])}"
        )

    evidence = f"FisherRF - uniform, per seed: {PAPER_REGIME}: {says(paper)}; cpu: {says(stable)}"
    full = all(c.complete for c in _cells(study, PAPER_REGIME).values()) and len(_cells(study, PAPER_REGIME)) == 3
    full_cpu = all(c.complete for c in _cells(study, "cpu").values()) and len(_cells(study, "cpu")) == 3
    worse_paper = paper is not None and paper["significant"] and not paper["better"]
    worse_cpu = stable is not None and stable["significant"] and not stable["better"]
    if worse_cpu:
        return "not supported", evidence
    if worse_paper and full_cpu:
        return "supported", evidence
    if full and not worse_paper:
        return "not supported", evidence
    return "open", evidence


def h3(study: Study) -> tuple[str, str]:
    """ours-paper-sum's median unseen-half share exceeds ours's in most cells."""
    compared = []
    for c in study.cells:
        raw, normalised = c.methods.get("ours-paper-sum"), c.methods.get(OURS)
        if (
            raw
            and normalised
            and None not in (a := raw.coverage_median("unseen_share"), b := normalised.coverage_median("unseen_share"))
        ):
            compared.append((c, a, b))
    more = sum(a > b for _, a, b in compared)
    evidence = f"higher in {more} of {len(compared)} cells with both methods; " + "; ".join(
        f"{c.scene}, {c.engine}: {a:.2f} vs {b:.2f}" for c, a, b in compared
    )
    planned = 3 * (len(STABLE_REGIMES) + 1)
    if more > planned / 2:
        return "supported", evidence
    if len(compared) - more >= planned / 2:
        return "not supported", evidence
    return "open", evidence


def h4(study: Study) -> tuple[str, str]:
    """On the stable engines, no method beats uniform by more than 1 dB (median paired) in a cell."""
    found, cells = [], [c for e in STABLE_REGIMES for c in _cells(study, e).values()]
    for c in cells:
        for method, result in c.methods.items():
            entry = result.vs_reference.get("psnr")
            if entry and entry["difference"] > 1.0:
                found.append(f"{method} on {c.scene}, {c.engine} ({entry['difference']:+.2f} dB)")
    evidence = "above 1 dB: " + "; ".join(found) if found else f"none of {len(cells)} cell(s) has a method above +1 dB"
    if found:
        return "not supported", evidence
    complete = sum(c.complete for c in cells)
    return ("supported" if complete == 3 * len(STABLE_REGIMES) else "open"), evidence


HYPOTHESES = (
    ("H1", "on nerfacto-cpu-last-sample, ours beats uniform (per-cell test) on at least two of three scenes", h1),
    ("H2", "FisherRF is worse than uniform on nerfacto-cpu-last-sample (per seed) and not worse on cpu", h2),
    ("H3", "ours-paper-sum picks more views on the unseen half than ours (median share) in most cells", h3),
    ("H4", "on cpu and nerfacto-cpu no method beats uniform by more than 1 dB (median paired) in any cell", h4),
)


def hypotheses_blocks(study: Study) -> list[Block]:
    rows = []
    for name, text, judge in HYPOTHESES:
        verdict, evidence = judge(study)
        rows.append([name, text, f"**{verdict}**", evidence])
    return [
        Heading("The planned hypotheses"),
        Paragraph(
            "Stated before the runs in docs/study-plan.md, with the tests above; each verdict is computed from the "
            "table (open: the cells run so far do not decide it)."
        ),
        Table(["", "hypothesis", "verdict", "evidence"], rows),
    ]


__all__ = ["HYPOTHESES", "hypotheses_blocks"]
