"""Experiments: the paper's protocol over (scene, method, trial), a results store that survives
crashes, local and Ray backends, and the sweep driver."""
