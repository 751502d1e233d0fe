"""The verdicts on the study's planned hypotheses (docs/study-plan.md, written before its runs),
computed from the study's cells and regimes, so the page never states one by hand. A hypothesis
whose cells are not all run yet is "open" unless the cells run already decide it.
"""

from __future__ import annotations

from nerfaug.report.document import Block, Heading, Paragraph, Table, p_value
from nerfaug.report.study import OURS, Study, regime_comparisons
from nerfaug.statistics import seed_level_comparison

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


# ---- the real-scene study (docs/study-plan.md, plan of 2026-11-25) ------------------------------

REAL_SCENES = ("mic", "maryRose", "dtu_scan24", "cow")
HELD_BACK = "moldGoldCape"
REAL_ENGINES = ("nerfacto-cpu", "nerfacto-cpu-last-sample")
# The plan's engine "if time allows, after both": judged as the others once its four scenes are
# complete, and deciding nothing before (docs/study-plan.md, entry of 2026-11-26, late night).
OPTIONAL_REAL_ENGINES = ("cpu",)
OURS_FAMILY = ("ours", "ours-paper-sum", "ours-batch-sharp")
RANKING = (("ours", "entropy-sampling"), ("entropy-sampling", "fisherrf-sampling"))


def real_engines(study: Study) -> tuple[str, ...]:
    """The engines the real-scene hypotheses are judged on: the planned two, and an optional one
    once its four planned scenes are complete."""
    return REAL_ENGINES + tuple(e for e in OPTIONAL_REAL_ENGINES if _real_cells(study, e)[1])


def _pending(study: Study) -> list[str]:
    """Evidence lines for the optional engines begun and not complete: they decide nothing yet."""
    lines = []
    for engine in OPTIONAL_REAL_ENGINES:
        cells = [c for c in study.cells if c.engine == engine and c.scene in REAL_SCENES]
        complete = sum(c.complete for c in cells)
        if cells and complete < len(REAL_SCENES):
            lines.append(f"{engine}: {complete} of {len(REAL_SCENES)} scenes complete, decides nothing yet")
    return lines


def _real_cells(study: Study, engine: str) -> tuple[list, bool]:
    """The engine's cells of the four planned real scenes that the evidence is computed on (the
    complete ones, as the page's regime tables; every one while none is), and whether all four
    are complete."""
    cells = [c for c in study.cells if c.engine == engine and c.scene in REAL_SCENES]
    done = len(cells) == len(REAL_SCENES) and all(c.complete for c in cells)
    return [c for c in cells if c.complete] or cells, done


def _says(method: str, entry: dict | None) -> str:
    if entry is None:
        return f"{method}: not run"
    return (
        f"{method} {entry['difference']:+.2f} dB ({entry['wins']}/{entry['n_seeds']} seeds, "
        f"p x {entry['n_comparisons']} = {p_value(entry['p_bonferroni'])})"
    )


def r1_winners(study: Study) -> dict[str, list[str]]:
    """engine -> the methods of this project that beat uniform per seed on the real scenes. Only
    an engine whose four scenes are complete is judged: the plan's test is the mean over the four,
    and a part of them (one scene's ten seeds) would test another hypothesis."""
    found = {}
    for engine in real_engines(study):
        cells, done = _real_cells(study, engine)
        comparisons = regime_comparisons(cells) if done else {}
        found[engine] = [m for m in OURS_FAMILY if (e := comparisons.get(m)) and e["significant"] and e["better"]]
    return found


def r1(study: Study) -> tuple[str, str]:
    """A method of this project beats uniform per seed on the real scenes, on at least one engine."""
    parts, complete = [], []
    for engine in real_engines(study):
        cells, done = _real_cells(study, engine)
        comparisons = regime_comparisons(cells)
        complete.append(done)
        parts.append(
            f"{engine} ({len(cells)} scene(s)): " + "; ".join(_says(m, comparisons.get(m)) for m in OURS_FAMILY)
        )
    evidence = " | ".join(parts + _pending(study))
    if any(r1_winners(study).values()):
        return "supported", evidence
    return ("not supported" if all(complete) else "open"), evidence


def r2(study: Study) -> tuple[str, str]:
    """Per engine, ours > entropy-sampling > fisherrf-sampling (seed-level, Bonferroni x2)."""
    verdicts, parts = [], []
    for engine in real_engines(study):
        cells, done = _real_cells(study, engine)
        tests = []
        for high, low in RANKING:
            differences = {
                c.scene: c.methods[high].differences(c.methods[low])
                for c in cells
                if high in c.methods and low in c.methods
            }
            tests.append(seed_level_comparison(differences, len(RANKING)) if any(differences.values()) else None)
        if not done:  # the plan's test is over the four scenes: a part of them decides nothing
            verdict = "open"
        elif any(t is not None and t["significant"] and not t["better"] for t in tests):
            verdict = "contradicted"
        elif all(t is not None and t["significant"] and t["better"] for t in tests):
            verdict = "holds"
        else:
            verdict = "not supported"
        verdicts.append(verdict)
        parts.append(
            f"{engine}: {verdict} (" + "; ".join(_says(f"{h} - {lo}", t) for (h, lo), t in zip(RANKING, tests)) + ")"
        )
    parts += _pending(study)
    for verdict in ("contradicted", "holds", "open"):
        if verdict in verdicts:
            return verdict, " | ".join(parts)
    return "not supported", " | ".join(parts)


def r3(study: Study) -> tuple[str, str]:
    """ours-batch-sharp beats uniform per seed on the real scenes with nerfacto-cpu."""
    cells, done = _real_cells(study, "nerfacto-cpu")
    entry = regime_comparisons(cells).get("ours-batch-sharp")
    evidence = f"nerfacto-cpu ({len(cells)} scene(s)): " + _says("ours-batch-sharp", entry)
    if not done:  # the plan's test is over the four scenes: a part of them decides nothing
        return "open", evidence
    better = entry is not None and entry["significant"] and entry["better"]
    return ("supported" if better else "not supported"), evidence


def r4(study: Study) -> tuple[str, str]:
    """Each method R1 finds better than uniform beats uniform on the held-back scene (per cell,
    two-sided Wilcoxon, Bonferroni over those methods)."""
    planned = [(engine, m) for engine, methods in r1_winners(study).items() for m in methods]
    if not planned:
        if r1(study)[0] == "not supported":
            return "not applicable", "no method passed R1: there is nothing to replicate"
        return "open", "no method has passed R1 yet"
    held = {c.engine: c for c in study.cells if c.scene == HELD_BACK}
    parts, passed, decided = [], 0, 0
    for engine, method in planned:
        cell = held.get(engine)
        entry = cell.methods[method].vs_reference.get("psnr") if cell and method in cell.methods else None
        if entry is None or not cell.complete:
            parts.append(f"{method} on {engine}: not run yet")
            continue
        decided += 1
        p = min(1.0, entry["p_value"] * len(planned))
        passed += p < 0.05 and entry["better"]
        parts.append(f"{method} on {engine}: {entry['difference']:+.2f} dB, p x {len(planned)} = {p_value(p)}")
    evidence = f"held-back {HELD_BACK}: " + "; ".join(parts)
    if decided < len(planned):
        return "open", evidence
    return ("supported" if passed == len(planned) else "not supported"), evidence


REAL_HYPOTHESES = (
    (
        "R1",
        "a method of this project (ours, ours-paper-sum, ours-batch-sharp) beats uniform per seed on the real "
        "scenes, on at least one engine",
        r1,
    ),
    ("R2", "per engine, ours > entropy-sampling > fisherrf-sampling per seed (the paper's Table II ranking)", r2),
    (
        "R3",
        "ours-batch-sharp, the procedural study's one significant method, beats uniform per seed on the real "
        "scenes with nerfacto-cpu",
        r3,
    ),
    ("R4", "each method R1 finds better than uniform also beats it on the held-back scene (moldGoldCape)", r4),
)


def hypotheses_of(study: Study) -> tuple:
    """The planned hypotheses of this study: the procedural plan's when it ran only the procedural
    three scenes, the real-scene plan's when it ran only that plan's scenes, else none (a study of
    a user's own scenes has no plan of this project's to judge)."""
    scenes = {c.scene for c in study.cells}
    if scenes <= set(PLAN_SCENES):
        return HYPOTHESES
    return REAL_HYPOTHESES if scenes <= {*REAL_SCENES, HELD_BACK} else ()


def hypotheses_blocks(study: Study) -> list[Block]:
    if not hypotheses_of(study):
        return []
    rows = []
    for name, text, judge in hypotheses_of(study):
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


__all__ = ["HYPOTHESES", "REAL_HYPOTHESES", "hypotheses_blocks", "hypotheses_of", "r1", "r2", "r3", "r4"]
