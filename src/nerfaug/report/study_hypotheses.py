"""The verdicts on the study's planned hypotheses (docs/study-plan.md, written before its runs),
computed from the study's cells and regimes, so the page never states one by hand. A hypothesis
whose cells are not all run yet is "partial: n of m runs" unless the cells run already decide it;
beside a real-scene "not supported" stands the smallest effect its test could have seen. The GPU
study's G1-G4 are judged by `nerfaug.report.study_verdicts`, the study of rounds' Q1-Q4 by
`nerfaug.report.rounds_verdicts`.
"""

from __future__ import annotations

import math

import numpy as np

from nerfaug.report.document import Block, Heading, Paragraph, Table, p_value
from nerfaug.report.rounds_verdicts import OneShotArm, rounds_blocks
from nerfaug.report.study import OURS, REFERENCE, Study, regime_comparisons
from nerfaug.report.study_verdicts import (
    GPU_ENGINES,
    GPU_HELD_BACK,
    GPU_SCENES,
    dead_per_cell,
    dead_runs,
    detectable,
    gpu_engines,
    gpu_rows,
    min_detectable_effect,
    regime_test,
    says,
)
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


GPU_HEADERS = ["", "hypothesis", "test", "verdict", "evidence", "smallest effect it could have seen", "dead runs"]
KINDS = ("auto", "procedural", "real", "gpu", "rounds", "none")
"""Which plan's hypotheses a page judges: `auto` chooses from the table's engines and scenes."""


def _base(engine: str) -> str:
    return engine.split("+")[0]  # a variant "paper+optimiser.batch_size=64" is of its preset's study


def plan_kind(study: Study, plan: str = "auto") -> str:
    """The plan whose hypotheses the page judges: the study of rounds' when its runs added views in
    more than one round; the GPU study's when the table holds only the paper engine on that plan's
    scenes; the procedural plan's when only its three scenes; the
    real-scene plan's when only its scenes; else none (a study of a user's own scenes has no plan
    of this project's to judge). `plan` other than "auto" is taken as given."""
    if plan not in KINDS:
        raise ValueError(f"hypotheses: {plan!r} is not one of {', '.join(KINDS)}")
    if plan != "auto":
        return plan
    if int(study.plan.get("config", {}).get("rounds", 1)) > 1:
        return "rounds"
    scenes, engines = {c.scene for c in study.cells}, {_base(e) for e in study.engines}
    if engines and engines <= set(GPU_ENGINES) and scenes <= {*GPU_SCENES, GPU_HELD_BACK}:
        return "gpu"
    if scenes <= set(PLAN_SCENES):
        return "procedural"
    return "real" if scenes <= {*REAL_SCENES, HELD_BACK} else "none"


def hypotheses_of(study: Study, plan: str = "auto") -> tuple:
    """The planned hypotheses (procedural H1-H4 or real-scene R1-R4) as (name, text, judge);
    the GPU study's are rows of their own (`study_verdicts.gpu_rows`)."""
    return {"procedural": HYPOTHESES, "real": REAL_HYPOTHESES}.get(plan_kind(study, plan), ())


def _runs(study: Study, engines, scenes) -> tuple[int, int]:
    """(runs in the table, runs planned) of the plan's methods and trials on these cells."""
    methods, trials = study.plan.get("methods", []), int(study.plan.get("trials", 0))
    done = {
        (r["engine"], r["scene"], r["method"], r["trial"])
        for r in study.table["runs"]
        if r["engine"] in engines and r["scene"] in scenes and r["method"] in methods and r["trial"] < trials
    }
    return len(done), len(engines) * len(scenes) * len(methods) * trials


def _real_floor(study: Study, name: str) -> str:
    """Beside a real-scene "not supported": per engine, the smallest effect its tests could see."""
    parts = []
    for engine in real_engines(study):
        cells, _ = _real_cells(study, engine)
        if name == "R2":
            tests = [regime_test(cells, high, low, len(RANKING)) for high, low in RANKING]
        else:
            methods = OURS_FAMILY if name == "R1" else ("ours-batch-sharp",)
            if name == "R3" and engine != "nerfacto-cpu":
                continue
            comparisons = regime_comparisons(cells)
            tests = [comparisons[m] for m in methods if m in comparisons]
        tests = [t for t in tests if t["n_seeds"] > 1]
        if not tests:
            continue
        k, n = tests[0]["n_comparisons"], tests[0]["n_seeds"]
        mde = min_detectable_effect(n, k)
        spreads = [float(np.std(t["seed_means"], ddof=1)) for t in tests]
        if math.isinf(mde):
            parts.append(f"{engine}: {detectable(tests[0]['seed_means'], k)}")
        else:
            parts.append(
                f"{engine}: {n} seed pairs, x{k}: smallest attainable p x {k} = {p_value(min(1.0, 2.0 ** (1 - n) * k))}"
                "; "
                f"detectable (80 % power): {mde:.2f} per-seed SDs = {_range(mde * min(spreads), mde * max(spreads))} "
                f"dB at the observed SD{'s' if len(spreads) > 1 else ''}"
            )
    return " | ".join(parts)


def _range(low: float, high: float) -> str:
    return f"{low:.2f}" if f"{low:.2f}" == f"{high:.2f}" else f"{low:.2f}-{high:.2f}"


def _real_dead(study: Study, name: str) -> str:
    dead = dead_runs(study)
    found = [d for d in dead if d[0] in real_engines(study) and d[1] in {*REAL_SCENES, HELD_BACK}]
    if not found:
        return "none flagged (runs recorded before the health check are not checked)"
    parts = []
    for engine in real_engines(study):
        cells, _ = _real_cells(study, engine)
        pairs = RANKING if name == "R2" else [(m, REFERENCE) for m in OURS_FAMILY]
        tests = (
            [
                (f"{h} - {lo}", regime_test(cells, h, lo, cells[0].n_comparisons if name != "R2" else 2, dead))
                for h, lo in pairs
            ]
            if cells
            else []
        )
        parts.append(
            f"{engine}: {dead_per_cell(study, engine, REAL_SCENES)}; without them: "
            + "; ".join(says(t, e) for t, e in tests)
        )
    return " | ".join(parts)


def hypotheses_blocks(study: Study, plan: str = "auto", one_shot: OneShotArm | None = None) -> list[Block]:
    """The page's section on the planned hypotheses of `plan` (`KINDS`); `one_shot`: the study of
    rounds' one-shot arm from a table of its own (Q2), judged only with the study of rounds'."""
    kind = plan_kind(study, plan)
    if one_shot is not None and kind != "rounds":
        raise ValueError(
            f"--one-shot-table {one_shot.name}: read for the study of rounds' Q2 only, not the {kind} plan's"
        )
    if kind == "gpu":
        return gpu_blocks(study)
    if kind == "rounds":
        return rounds_blocks(study, one_shot)
    if kind not in ("procedural", "real"):
        return []
    if kind == "real":
        engines, scenes = list(dict.fromkeys([*REAL_ENGINES, *real_engines(study)])), REAL_SCENES
    else:
        engines, scenes = (PAPER_REGIME, *STABLE_REGIMES), PLAN_SCENES
    done, planned = _runs(study, engines, scenes)
    rows = []
    for name, text, judge in hypotheses_of(study, plan):
        verdict, evidence = judge(study)
        if verdict == "open":
            verdict = f"partial: {done} of {planned} runs"
        row = [name, text, f"**{verdict}**", evidence]
        if kind == "real":
            row += [_real_floor(study, name) if verdict == "not supported" else "", _real_dead(study, name)]
        rows.append(row)
    headers = ["", "hypothesis", "verdict", "evidence"]
    if kind == "real":
        headers += ["smallest effect it could have seen", "dead runs"]
    return [
        Heading("The planned hypotheses"),
        Paragraph(
            "Stated before the runs in docs/study-plan.md, with the tests above; each verdict is computed from the "
            'table (partial: the cells run so far do not decide it). "Not supported" says the test did not find '
            "the effect, not that there is none: beside it, the smallest effect the test could have seen (the "
            "effect it detects 4 times in 5, by the t-test's power at the Bonferroni-corrected level, in per-seed "
            "SDs and in dB at the observed spread)."
        ),
        Table(headers, rows),
    ]


def gpu_blocks(study: Study) -> list[Block]:
    """G1-G4 of the GPU study's plan, per engine of the table, with the dead runs per cell."""
    blocks: list[Block] = [
        Heading("The planned hypotheses (the GPU study)"),
        Paragraph(
            'Stated before the runs in docs/study-plan.md ("Plan of 2026-11-27: the GPU study"), with its tests: '
            f"per regime, each seed's mean over {', '.join(GPU_SCENES)} of the paired PSNR differences, the exact "
            "sign-flip test, Bonferroni x5 (G2: x2); G4 per cell on the held-back scene. Every verdict is computed "
            "from the table: a hypothesis is judged only when its cells are complete (partial: n of m runs, the "
            'numbers as they stand, deciding nothing). "Not supported" says the test did not find the effect, not '
            "that there is none: beside it, the smallest effect the test could have seen (4 times in 5, by the "
            "t-test's power at the corrected level, in per-seed SDs and in dB at the observed spread). Dead runs "
            "(the NeRF rendered background only) stay in their cells for the planned analysis; the last column "
            "gives the same tests without the pairs holding one."
        ),
    ]
    for engine in gpu_engines(study):
        rows = gpu_rows(study, engine)
        if len(gpu_engines(study)) > 1:
            rows = [[f"{r[0]} ({engine})", *r[1:]] for r in rows]
        scenes = (*GPU_SCENES, GPU_HELD_BACK)
        blocks.append(
            Table(GPU_HEADERS, rows, [f"dead runs per cell, engine {engine}: {dead_per_cell(study, engine, scenes)}"])
        )
    return blocks


__all__ = [
    "HYPOTHESES",
    "KINDS",
    "REAL_HYPOTHESES",
    "hypotheses_blocks",
    "hypotheses_of",
    "plan_kind",
    "r1",
    "r2",
    "r3",
    "r4",
]
