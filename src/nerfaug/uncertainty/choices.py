"""The uncertainty measures' choices as plain values: the names each mode may take and FisherRF's
defaults, read by the measures and by `SelectionConfig` (`nerfaug.selection.config`).

Nothing here imports torch: `SelectionConfig` is part of the options of `nerfaug run`, `study` and
`propose`, whose `--help` answers without loading it.
"""

ENTROPY_MODES = ("escape", "renormalise", "raw", "authors")
"""`ray_entropy`'s modes (`nerfaug.uncertainty.entropy`)."""
NORMALISATIONS = ("minmax", "none", "authors")
"""How `combined_uncertainty` scales H and D before the sum (`nerfaug.uncertainty.combined`)."""
FISHER_METHODS = ("random-sign", "exact")
"""FisherRF's estimators of the Fisher diagonal (`nerfaug.uncertainty.fisher`)."""
DEFAULT_METHOD = "random-sign"
FISHER_LAMBDA = 1e-6
"""FisherRF's lambda: a candidate's score is sum_k H_cand[k] / (H_train[k] + lambda) (the authors' release)."""
# Default bound on the candidates' Fisher diagonals kept for the greedy selection (1 GiB).
CACHE_FLOATS = 2**28
