"""The families of view-selection methods, by name: the rows of the paper's Tables I and II, its
main comparison, the authors' code's variants, the batch-aware variants and the study's methods.
Each name is a method of the registry (`nerfaug.selection.methods.METHODS`; tests check them).

Nothing here imports torch: the protocols of `nerfaug run` and `nerfaug study`
(`nerfaug.experiment.config`) start from these families, and their `--help` loads no torch.
"""

# Method families: the one source of truth for the tables, the comparisons and the study.
# Table I (terms), as (row label, method).
TABLE_I_ROWS = (("Combined (ours)", "ours"), ("Entropy only", "entropy-sampling"), ("Distance only", "distance"))
# Table II (NBV vs sampling), as (family, variant, method), in the paper's order.
TABLE_II_ROWS = (
    ("Ours", "NBV", "ours-nbv"),
    ("Ours", "Sampling", "ours"),
    ("FisherRF", "NBV", "fisherrf"),
    ("FisherRF", "Sampling", "fisherrf-sampling"),
    ("Entropy", "NBV", "entropy"),
    ("Entropy", "Sampling", "entropy-sampling"),
)
TABLE_I = tuple(m for _, m in TABLE_I_ROWS)
TABLE_II = ("ours", "ours-nbv", "fisherrf", "fisherrf-sampling", "entropy", "entropy-sampling")
# The paper's main comparison (Sec. IV): ours first, then the three baselines.
MAIN_COMPARISON = ("ours", "uniform", "entropy", "fisherrf")
# The authors' code's variants beside the paper's definition.
AUTHORS_VARIANTS = ("ours", "ours-authors", "entropy-authors-nbv", "distance-authors-nbv")
# Beyond the paper: batch-aware sampling beside plain sampling.
BATCH_AWARE = ("ours", "ours-batch", "ours-batch-local", "ours-batch-sharp")
# The study: ours (min-max and the raw sum as written), its authors' variant, the batch-aware variant and the baselines.
STUDY_METHODS = (
    "ours",
    "ours-paper-sum",
    "ours-authors",
    "ours-batch-sharp",
    "uniform",
    "entropy",
    "fisherrf",
    "furthest",
)
FAMILIES: dict[str, tuple[str, ...]] = {
    "table-i": TABLE_I,
    "table-ii": TABLE_II,
    "main": MAIN_COMPARISON,
    "authors": AUTHORS_VARIANTS,
    "batch": BATCH_AWARE,
    "study": STUDY_METHODS,
}
