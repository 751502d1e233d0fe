"""The NeRF engine: encodings and fields, samplers, volume rendering, and the trainer."""
