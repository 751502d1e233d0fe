"""`nerfaug serve`: the HTTP service over capture sessions (FastAPI; the `serve` extra)."""
