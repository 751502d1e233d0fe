"""CLI commands of the active-capture loop (train, propose, add, export); filled in by the
session module."""

COMMANDS: dict = {}
