"""CLEVR-Robot (placeholder until the env lands)."""
